"""The checks of localize's input paths that need no heavy import: a recording's path and name, a run
folder, session folders, RoNIN weights and their config.

The console commands call them before they import numpy, pandas or torch, so a missing or misnamed input
is refused in a fraction of a second; :func:`~curbside.localize.readers.detect_format` and
:func:`~curbside.localize.view.load_run` call the same functions, so each message has one source.
"""

from __future__ import annotations

from pathlib import Path

from curbside.errors import CurbsideInputError

#: Separator between an HDF5 file and a trial (group) name: ``file.h5::TrialName``.
TRIAL_SEPARATOR = "::"

_H5_SUFFIXES = (".h5", ".hdf5")

#: Header lines a GnssLogger (or GPSTest) log starts with: ``# Header Description:``, ``# Fix,...``.
_GNSSLOGGER_HEADERS = ("# Header Description", "# Raw,", "# Fix,", "# UncalAccel,", "# Accel,", "# Status,")


def _head(path: Path, n_bytes: int) -> str:
    """The first ``n_bytes`` of ``path`` as text ('' when it cannot be read)."""
    try:
        with path.open("rb") as f:
            return f.read(n_bytes).decode("utf-8", errors="replace")
    except OSError:
        return ""


def _starts_like_gnsslogger(path: Path) -> bool:
    """Whether ``path`` begins with GnssLogger's ``#`` header lines (its first 64 KiB are read)."""
    lines = [line.strip() for line in _head(path, 65536).splitlines() if line.strip()]
    return bool(lines) and lines[0].startswith("#") and any(
        " ".join(line.split()).startswith(_GNSSLOGGER_HEADERS) for line in lines if line.startswith("#"))


#: What a GetSensorData logfile (IPIN competitions) starts with.
_GETSENSORDATA_HEADER = "% LogFile created by the 'GetSensorData' App"


def _starts_like_getsensordata(path: Path) -> bool:
    """Whether the first line of ``path`` is GetSensorData's ``% LogFile created by...`` line."""
    return _head(path, 4096).lstrip("\ufeff \t\r\n").startswith(_GETSENSORDATA_HEADER)


def split_trial(src: str | Path) -> tuple[Path, str | None]:
    """Split ``FILE.h5::TRIAL`` (or ``SRC::RECORDING``) into the path and the name (``None`` if no ``::``)."""
    text = str(src)
    if TRIAL_SEPARATOR in text:
        path, trial = text.rsplit(TRIAL_SEPARATOR, 1)
        return Path(path), trial
    return Path(text), None


def check_source_path(src: str | Path) -> str | None:
    """Check a recording's path by its name and kind alone, and name the format they tell.

    Parameters
    ----------
    src
        What :func:`~curbside.localize.readers.read_any` reads: a folder, ``.zip``, ``FILE.h5[::TRIAL]``,
        ``.gpx``, a GnssLogger or GetSensorData ``.txt``, ``SRC::RECORDING``.

    Returns
    -------
    str or None
        ``ipin``, ``sensorlogger`` (a ``.zip``), ``gpx``, ``gnsslogger`` (a ``.txt`` that starts with
        GnssLogger's header lines) or ``getsensordata`` (a ``.txt`` that starts with GetSensorData's
        ``% LogFile created by...`` line); ``None`` for a folder, whose files tell
        (:func:`~curbside.localize.readers.detect_format`).

    Raises
    ------
    CurbsideInputError
        ``src`` does not exist, is a single CSV, a ``.txt`` of neither log or a file of no
        known format, or names a recording (``::NAME``) inside a file that holds none.
    """
    path, name = split_trial(src)
    if not path.exists():
        raise CurbsideInputError(path, "no such file or folder")
    if path.suffix.lower() in _H5_SUFFIXES:
        return "ipin"
    if path.is_dir():
        return None
    suffix = path.suffix.lower()
    if suffix == ".zip":
        return "sensorlogger"
    if name is not None:
        raise CurbsideInputError(src, f"'{TRIAL_SEPARATOR}NAME' applies to an .h5 file, a .zip or a folder")
    if suffix == ".gpx":
        return "gpx"
    if suffix == ".txt":
        if _starts_like_gnsslogger(path):
            return "gnsslogger"
        if _starts_like_getsensordata(path):
            return "getsensordata"
        raise CurbsideInputError(path, "unknown format: a .txt that does not start with GnssLogger's header "
                                       "lines ('# Raw,...', '# Fix,...': GnssLogger, GPSTest) nor with "
                                       f"\"{_GETSENSORDATA_HEADER}\" (GetSensorData, IPIN logfiles)")
    if suffix == ".csv":
        raise CurbsideInputError(
            path, "a single CSV is not a recording: give the Sensor Logger .zip (not the 'Combined CSV' "
            "export) or its folder, or a session folder"
        )
    raise CurbsideInputError(path, "unknown format (expected a folder, .zip, .h5[::TRIAL], .gpx or a "
                                   "GnssLogger or GetSensorData .txt)")


def check_whole_file(path: str | Path, option: str) -> None:
    """Refuse ``FILE::NAME`` for an option that takes a whole dataset file (``train-ronin --ipin``).

    Parameters
    ----------
    path
        The option's value.
    option
        The option, for the message.

    Raises
    ------
    CurbsideInputError
        ``path`` names one recording of a file (``FILE::NAME``) where the whole file is wanted (a file
        whose own name holds ``::`` passes).
    """
    file, name = split_trial(path)
    if name is not None and not Path(path).exists():
        picked = f"{TRIAL_SEPARATOR}{name}"
        raise CurbsideInputError(path, f"{option} takes the whole file, not one recording of it ('{picked}' "
                                       f"is not supported here): give {option} {file}")


def check_run_folder(folder: str | Path) -> tuple[Path, Path]:
    """Check that ``folder`` is a run folder of ``localize run -o`` (it holds ``track.csv``).

    Returns
    -------
    (pathlib.Path, pathlib.Path)
        Its ``track.csv`` and ``run.json`` (which may be missing).

    Raises
    ------
    CurbsideInputError
        ``folder`` does not exist or holds no ``track.csv``.
    """
    folder = Path(folder)
    if not folder.exists():
        raise CurbsideInputError(folder, "no such run folder")
    track_csv = folder / "track.csv"
    if not track_csv.is_file():
        raise CurbsideInputError(folder, "not a run folder (no track.csv; write one with `localize run -o`)")
    return track_csv, folder / "run.json"


def config_path_for(weights: str | Path) -> Path:
    """The JSON config stored beside a RoNIN weights file (``x.pt`` -> ``x.json``)."""
    return Path(weights).with_suffix(".json")


def check_ronin_weights_path(weights: str | Path) -> tuple[Path, Path]:
    """Check that ``weights`` is a RoNIN weights file with its config beside it, by their paths alone.

    Returns
    -------
    (pathlib.Path, pathlib.Path)
        The weights file and its config (:func:`config_path_for`).

    Raises
    ------
    CurbsideInputError
        ``weights`` is the config itself, a folder or missing, or its config is missing.
    """
    weights = Path(weights)
    cfg_path = config_path_for(weights)
    if cfg_path == weights:
        raise CurbsideInputError(
            weights, "not a curbside RoNIN weights file (a .json is the config beside one: give the .pt)"
        )
    if weights.is_dir():
        raise CurbsideInputError(weights, "is a folder; give the RoNIN weights file (.pt)")
    if not weights.is_file():
        raise CurbsideInputError(weights, "no such RoNIN weights file")
    if not cfg_path.is_file():
        raise CurbsideInputError(cfg_path, f"no such file: the config of {weights.name} must sit beside it "
                                           "(train-ronin writes both)")
    return weights, cfg_path


def expand_sessions(paths: list[str | Path]) -> list[Path]:
    """Session folders from arguments that are sessions or folders of sessions (sorted).

    Raises
    ------
    CurbsideInputError
        A path does not exist or holds no session.
    """
    out: list[Path] = []
    for p in map(Path, paths):
        if not p.is_dir():
            raise CurbsideInputError(p, "no such session folder")
        if any(p.glob("*.csv")):
            out.append(p)
            continue
        subs = sorted(d for d in p.iterdir() if d.is_dir() and any(d.glob("*.csv")))
        if not subs:
            raise CurbsideInputError(p, "neither a session folder nor a folder of sessions")
        out += subs
    return out
