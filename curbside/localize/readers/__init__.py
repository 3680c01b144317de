"""Readers: every supported recording format converted into a :class:`~curbside.localize.session.Session`.

:func:`read_any` recognises the format from the path:

- a folder with ``imu.csv``, ``gnss.csv``...: the SPEC session folder
  (:func:`~curbside.localize.session.read_session`);
- a ``.zip`` or a folder of Sensor Logger CSVs (``Accelerometer.csv``...), ``SRC::RECORDING`` when
  it holds several recordings: :func:`curbside.localize.readers.sensorlogger.read_sensorlogger`;
- ``FILE.h5::TRIAL``: one IPIN/GetSensorData trial (:func:`curbside.localize.readers.ipin.read_trial`);
  ``FILE.h5`` alone when it holds a single trial;
- a ``.gpx`` file: a GNSS-only session (:func:`curbside.localize.readers.gpx.read_gpx`);
- a ``.txt`` that starts with GnssLogger's header lines: a Google GnssLogger or GPSTest log
  (:func:`curbside.localize.readers.gnsslogger.read_gnsslogger`);
- a ``.txt`` that starts with ``% LogFile created by the 'GetSensorData' App``: a GetSensorData logfile of
  the IPIN competitions (:func:`curbside.localize.readers.getsensordata.read_getsensordata`).

The trial (or recording) separator is ``::`` (not ``#``: ``#`` starts a comment in shells and is legal in file
names, while ``::`` in an HDF5 file name is vanishingly rare). ``docs/sessions.md`` has the details.
"""

from __future__ import annotations

from pathlib import Path

from curbside.errors import CurbsideInputError
from curbside.localize.paths import TRIAL_SEPARATOR, check_source_path, split_trial
from curbside.localize.readers import getsensordata, gnsslogger, gpx, ipin, sensorlogger
from curbside.localize.session import COLUMNS, Session, read_session, validate_table


def detect_format(src: str | Path) -> str:
    """Name the format of ``src``: ``spec``, ``sensorlogger``, ``ipin``, ``gpx``, ``gnsslogger`` or
    ``getsensordata``.

    A file's name tells its format (:func:`~curbside.localize.paths.check_source_path`, which also
    refuses a missing path); a folder's files tell a folder's.

    Raises
    ------
    CurbsideInputError
        ``src`` does not exist or is of no known format.
    """
    kind = check_source_path(src)
    if kind is not None:
        return kind
    path, name = split_trial(src)
    if name is None and any((path / f"{table}.csv").is_file() for table in COLUMNS):
        return "spec"
    if sensorlogger.looks_like_export(path):
        return "sensorlogger"
    raise CurbsideInputError(
        path, "folder is neither a session folder (imu.csv, gnss.csv...) nor a Sensor Logger export"
    )


def read_any(src: str | Path, *, route: str | Path | None = None, platform: str | None = None) -> Session:
    """Read any supported recording as a session.

    Parameters
    ----------
    src
        A SPEC session folder, a Sensor Logger ``.zip`` or folder (``SRC::RECORDING`` to pick one of
        several), ``FILE.h5::TRIAL`` (or a single-trial ``FILE.h5``), a ``.gpx`` file, a GnssLogger
        (GPSTest) ``.txt`` log, or a GetSensorData ``.txt`` logfile (IPIN competitions).
    route, platform
        Sensor Logger only: see :func:`~curbside.localize.readers.sensorlogger.read_sensorlogger`.

    Returns
    -------
    Session
        Its ``source`` is ``src`` as given, for messages.

    Raises
    ------
    CurbsideInputError
        Missing source, unknown format, an ``.h5`` with several trials and none named, a route or
        platform for another format than Sensor Logger's, or any problem the format's reader reports.
    """
    kind = detect_format(src)
    if route is not None and kind != "sensorlogger":
        raise CurbsideInputError(route, "a route file applies to Sensor Logger exports only")
    if platform is not None and kind != "sensorlogger":
        raise CurbsideInputError("--platform", "applies to Sensor Logger exports only")
    if kind == "spec":
        return read_session(src)
    if kind == "sensorlogger":
        session = sensorlogger.read_sensorlogger(src, route=route, platform=platform)
    elif kind == "gpx":
        session = gpx.read_gpx(src)
    elif kind == "gnsslogger":
        session = gnsslogger.read_gnsslogger(src)
    elif kind == "getsensordata":
        session = getsensordata.read_getsensordata(src)
    else:
        session = _read_h5(src)
    session.source = str(src)
    # Foreign readers repair what they can; the session schema (e.g. lat/lon ranges) is checked here.
    for stem, table in session.tables().items():
        setattr(session, stem, validate_table(stem, table, f"{src} ({stem})"))
    return session


def _read_h5(src: str | Path) -> Session:
    path, trial = split_trial(src)
    if trial is None:
        trials = ipin.list_trials(path)
        if len(trials) != 1:
            raise CurbsideInputError(
                path, f"holds {len(trials)} trials; name one as {path}{TRIAL_SEPARATOR}TRIAL"
            )
        trial = trials[0]
    return ipin.read_trial(path, trial)


__all__ = ["TRIAL_SEPARATOR", "detect_format", "read_any", "split_trial"]
