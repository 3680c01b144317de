"""``localize convert``: write any supported recording as a SPEC session folder.

::

    localize convert SRC DST [--route ROUTE.csv] [--steps] [--pdr] [--overwrite]
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

import pandas as pd
from tqdm import tqdm

from curbside.errors import CurbsideInputError
from curbside.io import check_output_folder, output_folder
from curbside.localize.pdr import pdr_velocity
from curbside.localize.readers import detect_format, ipin, read_any, split_trial
from curbside.localize.readers._export import find_recordings
from curbside.localize.session import Session, write_session
from curbside.localize.steps import detect_steps


def add_derived(session: Session, steps: bool, pdr: bool) -> Session:
    """Add ``steps`` (detected footsteps) and/or ``velocity`` (PDR) tables computed from ``imu``.

    Raises
    ------
    CurbsideInputError
        Steps or PDR asked for a session without ``imu``.
    """
    if not (steps or pdr):
        return session
    if session.imu is None:
        raise CurbsideInputError(session.name, "--steps/--pdr need IMU data, and this source has none")
    times = detect_steps(session.imu) if session.steps is None else session.steps["t"].to_numpy()
    if steps:
        session.steps = pd.DataFrame({"t": times})
    if pdr:
        session.velocity = pdr_velocity(session.imu, times)
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


def _convert(args: argparse.Namespace) -> int:
    if args.list:
        path, _ = split_trial(args.src)
        kind = detect_format(path)
        if kind == "sensorlogger":
            names = sorted(find_recordings(path))
        elif kind == "ipin":
            names = ipin.list_trials(path)
        else:
            raise CurbsideInputError(args.src, "--list needs an IPIN .h5 file or Sensor Logger exports")
        print("\n".join(names))
        return 0
    if args.dst is None:
        raise CurbsideInputError("DST", "missing destination folder")
    dst = Path(args.dst)
    command = "localize convert --all" if args.all else "localize convert"
    check_output_folder(dst, args.overwrite, command)  # before reading: fail fast on an unusable destination
    if args.all:
        path, trial = split_trial(args.src)
        if detect_format(path) != "ipin":
            raise CurbsideInputError(args.src, "--all converts every trial of an IPIN .h5 file")
        if trial is not None:
            raise CurbsideInputError(args.src, "--all converts every trial; drop the ::TRIAL part")
        trials = ipin.list_trials(path)
        lines: list[str] = []
        with output_folder(dst, command, overwrite=args.overwrite) as tmp:
            for name in tqdm(trials, desc="convert", unit="trial", disable=not sys.stderr.isatty()):
                session = add_derived(ipin.read_trial(path, name), args.steps, args.pdr)
                write_session(session, tmp / session.name, command="localize convert")
                lines += summary_lines(session, dst / session.name)
        print("\n".join(lines))
        return 0
    session = add_derived(read_any(args.src, route=args.route), args.steps, args.pdr)
    write_session(session, dst, overwrite=args.overwrite, command="localize convert")
    print("\n".join(summary_lines(session, dst)))
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``convert`` to the ``localize`` sub-commands."""
    parser = subparsers.add_parser(
        "convert",
        help="write a recording (Sensor Logger, IPIN .h5, GPX, session) as a SPEC session folder",
        description="Write any supported recording (a Sensor Logger export, a trial of an IPIN 2023 "
        ".h5, a GPX track, a session folder) as a SPEC session folder of plain CSV files; --all writes "
        "every trial of an .h5, --steps adds detected footsteps and --pdr a PDR velocity.csv.",
    )
    parser.add_argument(
        "src", help="session folder, Sensor Logger .zip/folder[::RECORDING], FILE.h5[::TRIAL] or .gpx"
    )
    parser.add_argument("dst", nargs="?", help="destination folder: new, empty or a previous curbside output")
    parser.add_argument("--all", action="store_true", help="every trial of an .h5, one folder each under DST")
    parser.add_argument("--list", action="store_true",
                        help="list the trials of an .h5 (or the recordings of a zip or folder) and exit")
    parser.add_argument("--route", help="Sensor Logger: CSV lat,lon of the annotation taps, in tap order")
    parser.add_argument("--steps", action="store_true", help="add steps.csv (detected footsteps)")
    parser.add_argument("--pdr", action="store_true", help="add velocity.csv from the PDR baseline")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into a non-empty folder curbside did not write (other files are kept)")
    parser.set_defaults(func=_convert)
