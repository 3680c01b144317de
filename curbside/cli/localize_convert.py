"""``localize convert``: write any supported recording as a SPEC session folder.

::

    localize convert SRC DST [--route ROUTE.csv] [--platform P] [--steps] [--pdr] [--overwrite]
    localize convert FILE.h5 DSTDIR --all [--steps] [--pdr] [--overwrite]
    localize convert FILE.h5 --list          # also a zip or folder of Sensor Logger recordings

``SRC`` is anything :func:`curbside.localize.readers.read_any` reads (``SRC::RECORDING`` picks one
recording of a zip or folder holding several). ``--all`` writes one folder per trial of an IPIN
``.h5`` under ``DSTDIR`` (named after the trial); ``DSTDIR`` appears complete or not at all.
``--steps`` adds ``steps.csv`` (detected footsteps), ``--pdr`` adds ``velocity.csv`` from the PDR
baseline. ``DST`` must be new, empty or a previous curbside output; ``--overwrite`` allows any other
folder, where only the session files are replaced (see :mod:`curbside.io`). The summary (rows and
duration per file) goes to stdout.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from curbside.errors import CurbsideInputError
from curbside.localize.platforms import PLATFORM_OPTIONS

if TYPE_CHECKING:
    from curbside.localize.session import Session

#: What a recording of each format needs for the orientation quaternion, said when ``--pdr`` has none.
_ORIENTATION_HINTS = {
    "sensorlogger": " (a Sensor Logger export needs Orientation.csv)",
    "gnsslogger": " (a GnssLogger or GPSTest log needs OrientationDeg rows)",
    "getsensordata-txt": " (a GetSensorData logfile needs AHRS rows)",
}


def add_derived(session: Session, steps: bool, pdr: bool) -> Session:
    """Add ``steps`` (detected footsteps) and/or ``velocity`` (PDR) tables computed from ``imu``.

    Parameters
    ----------
    session
        The session; errors name its ``source`` (the recording as the user named it).
    steps, pdr
        Which tables to add.

    Raises
    ------
    CurbsideInputError
        Steps or PDR asked for a session without ``imu``, or PDR for one without the quaternion.
    """
    if not (steps or pdr):
        return session
    import pandas as pd

    from curbside.localize.pdr import pdr_velocity
    from curbside.localize.steps import detect_steps

    source = session.source
    if session.imu is None:
        raise CurbsideInputError(source, "--steps/--pdr need IMU data, and this source has none")
    if pdr and not {"qx", "qy", "qz", "qw"} <= set(session.imu.columns):
        kind = session.meta.get("source", {}).get("format")
        hint = _ORIENTATION_HINTS.get(kind, "")
        raise CurbsideInputError(
            source, f"--pdr needs the orientation quaternion (qx,qy,qz,qw); this source has none{hint}"
        )
    try:
        times = detect_steps(session.imu) if session.steps is None else session.steps["t"].to_numpy()
        if steps:
            session.steps = pd.DataFrame({"t": times})
        if pdr:
            session.velocity = pdr_velocity(session.imu, times)
    except CurbsideInputError as exc:  # the table has no file of its own here: name the recording
        raise CurbsideInputError(source, exc.problem) from None
    return session


def summary_lines(session: Session, folder: Path) -> list[str]:
    """One line per written file: rows and time span."""
    lines = [f"{folder}:"]
    for kind, table in session.tables().items():
        span = table["t"].iat[-1] - table["t"].iat[0] if len(table) else 0.0
        lines.append(f"  {kind + '.csv':<15} {len(table):>7} rows  {span:8.1f} s")
    if session.meta:
        lines.append(f"  {'meta.json':<15} {', '.join(sorted(session.meta))}")
    return lines


def _command(args: argparse.Namespace) -> str:
    """What writes the destination, as its marker records it."""
    return "localize convert --all" if args.all else "localize convert"


def _check_arguments(args: argparse.Namespace) -> None:
    """Refuse, before the heavy imports, what needs no reading: a missing or misnamed source, a missing or
    unusable destination, and what ``--all`` does not take.

    Raises
    ------
    CurbsideInputError
        Any of these.
    """
    from curbside.io import check_output_folder
    from curbside.localize.paths import check_source_path, split_trial

    path, trial = split_trial(args.src)
    if args.list:
        check_source_path(path)
        return
    if args.dst is None:
        raise CurbsideInputError("DST", "missing destination folder")
    check_output_folder(Path(args.dst), args.overwrite, _command(args))
    if not args.all:
        check_source_path(args.src)
        return
    if check_source_path(path) != "ipin":
        raise CurbsideInputError(args.src, "--all converts every trial of an IPIN .h5 file")
    if trial is not None:
        raise CurbsideInputError(args.src, "--all converts every trial; drop the ::TRIAL part")
    if args.platform is not None:
        raise CurbsideInputError("--platform", "applies to Sensor Logger exports only")
    if args.route is not None:
        raise CurbsideInputError(args.route, "a route file applies to Sensor Logger exports only")


def _convert(args: argparse.Namespace) -> int:
    _check_arguments(args)
    # the heavy imports, once the cheap checks passed
    from tqdm import tqdm

    from curbside.io import output_folder
    from curbside.localize.readers import detect_format, ipin, read_any, split_trial
    from curbside.localize.readers._export import require_recordings
    from curbside.localize.session import write_session

    if args.list:
        path, _ = split_trial(args.src)
        kind = detect_format(path)
        if kind == "sensorlogger":
            names = sorted(require_recordings(path))
        elif kind == "ipin":
            names = ipin.list_trials(path)
        else:
            raise CurbsideInputError(args.src, "--list needs an IPIN .h5 file or Sensor Logger exports")
        print("\n".join(names))
        return 0
    dst = Path(args.dst)
    if args.all:
        path, _ = split_trial(args.src)
        trials = ipin.list_trials(path)
        lines: list[str] = []
        with output_folder(dst, _command(args), overwrite=args.overwrite) as tmp:
            for name in tqdm(trials, desc="convert", unit="trial", disable=not sys.stderr.isatty()):
                session = ipin.read_trial(path, name)
                session.source = f"{path}::{name}"
                session = add_derived(session, args.steps, args.pdr)
                write_session(session, tmp / session.name, command="localize convert")
                lines += summary_lines(session, dst / session.name)
        print("\n".join(lines))
        return 0
    session = add_derived(read_any(args.src, route=args.route, platform=args.platform), args.steps, args.pdr)
    write_session(session, dst, overwrite=args.overwrite, command="localize convert")
    print("\n".join(summary_lines(session, dst)))
    return 0


def add_platform_option(parser: argparse.ArgumentParser) -> None:
    """``--platform``: the phone platform of a Sensor Logger export, over ``Metadata.csv``."""
    parser.add_argument(
        "--platform", choices=PLATFORM_OPTIONS, default=None,
        help="Sensor Logger: read the export as this platform's, whatever Metadata.csv says or when it is "
        "missing (ios-standardised: 'Standardise Units & Frames' on; android also fits a standardised iOS "
        "export whose orientation is East-North-Up)",
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``convert`` to the ``localize`` sub-commands."""
    parser = subparsers.add_parser(
        "convert",
        help="write a recording (Sensor Logger, IPIN .h5 or .txt, GPX, session) as a SPEC session folder",
        description="Write any supported recording (a Sensor Logger export, a trial of an IPIN 2023 "
        ".h5 or a GetSensorData .txt logfile of the IPIN competitions, a GPX track, a GnssLogger .txt log, "
        "a session folder) as a SPEC session folder of plain CSV "
        "files; --all writes every trial of an .h5, --steps adds detected footsteps and --pdr a PDR "
        "velocity.csv.",
    )
    parser.add_argument(
        "src", help="session folder, Sensor Logger .zip/folder[::RECORDING], FILE.h5[::TRIAL], .gpx, "
        "GnssLogger .txt or GetSensorData .txt (IPIN logfile)"
    )
    parser.add_argument("dst", nargs="?", help="destination folder: new, empty or a previous curbside output")
    parser.add_argument("--all", action="store_true", help="every trial of an .h5, one folder each under DST")
    parser.add_argument("--list", action="store_true",
                        help="list the trials of an .h5 (or the recordings of a zip or folder) and exit")
    parser.add_argument("--route", help="Sensor Logger: CSV lat,lon of the annotation taps, in tap order")
    add_platform_option(parser)
    parser.add_argument("--steps", action="store_true", help="add steps.csv (detected footsteps)")
    parser.add_argument("--pdr", action="store_true", help="add velocity.csv from the PDR baseline")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into a non-empty folder curbside did not write (other files are kept)")
    parser.set_defaults(func=_convert)
