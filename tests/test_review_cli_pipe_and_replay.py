"""Review fixes: a broken pipe that is not stdout's is an internal error, not a quiet exit 141; a
``run.json``'s recorded ``--platform`` does not stop its configuration being replayed on a session of
another format; ``--start`` shares the CLI's finite-number type."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

SESSIONS = Path(__file__).parent / "data" / "sessions"


def test_a_broken_pipe_elsewhere_than_stdout_is_an_internal_error():
    """stdout's reader is still there: the BrokenPipeError came from another pipe or socket (a worker, a
    subprocess), so it is a one-line internal error, exit 1, not a silent 141."""
    script = (
        "from curbside.cli.common import make_parser, run_cli\n"
        "def fail(_args):\n"
        "    print('working')\n"
        "    raise BrokenPipeError(32, 'Broken pipe')\n"
        "parser = make_parser('prog', 'test')\n"
        "parser.add_subparsers().add_parser('go').set_defaults(func=fail)\n"
        "raise SystemExit(run_cli('prog', parser, ['go']))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert proc.stdout == "working\n"
    assert proc.stderr.splitlines() == [
        "prog: internal error: BrokenPipeError: [Errno 32] Broken pipe (CURBSIDE_DEBUG=1 for a traceback)"
    ]


def test_a_recorded_platform_is_not_forced_on_a_session_of_another_format(tmp_path):
    """``localize run SPEC_FOLDER --config run.json`` of a Sensor Logger run made with ``--platform``:
    the replayed configuration applies; the platform, which only a Sensor Logger export takes, does not
    (it was the one-line error '--platform: applies to Sensor Logger exports only', exit 2)."""
    from curbside.cli.localize import main

    export = tmp_path / "ios"
    with zipfile.ZipFile(SESSIONS / "sensorlogger-ios.zip") as zf:
        zf.extractall(export)
    args = ["--mode", "gnss", "--particles", "50"]
    assert main(["run", str(export), *args, "--platform", "ios", "-o", str(tmp_path / "a")]) == 0
    assert json.loads((tmp_path / "a" / "run.json").read_text())["platform"] == "ios"
    assert main(["convert", str(export), str(tmp_path / "spec")]) == 0
    replay = ["run", str(tmp_path / "spec"), "--config", str(tmp_path / "a" / "run.json"),
              "-o", str(tmp_path / "b")]
    assert main(replay) == 0
    assert "platform" not in json.loads((tmp_path / "b" / "run.json").read_text())
    # given on the command line it is still refused for another format
    assert main([*replay[:-1], str(tmp_path / "c"), "--platform", "ios"]) == 2


def test_an_ipv6_scheduler_address_is_taken():
    """dask takes ``tcp://[::1]:8786``; the option refused it as not HOST:PORT."""
    import argparse

    import pytest

    from curbside.cli.localize_evaluate_args import _scheduler_address

    for address in ("tcp://[::1]:8786", "[fe80::1]:8786", "tls://sched.example:8786", "localhost:8786"):
        assert _scheduler_address(address) == address
    for address in ("localhost", "tcp://host", "[::1]", "tcp://[::1", "host:port", "a b:1"):
        with pytest.raises(argparse.ArgumentTypeError):
            _scheduler_address(address)


def test_convert_all_refuses_the_sensor_logger_options(tmp_path, capsys):
    """``--all`` converts an IPIN .h5, which takes no ``--platform`` or ``--route``: they were ignored
    without a word (exit 0), as ``read_any`` refuses them for one trial."""
    from curbside.cli.localize import main

    h5 = str(SESSIONS / "ipin2023-cut.h5")
    assert main(["convert", h5, str(tmp_path / "a"), "--all", "--platform", "ios"]) == 2
    assert capsys.readouterr().err.strip() == (
        "localize: error: --platform: applies to Sensor Logger exports only")
    route = tmp_path / "route.csv"
    route.write_text("lat,lon\n37.79,-122.40\n", encoding="utf-8")
    assert main(["convert", h5, str(tmp_path / "b"), "--all", "--route", str(route)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"localize: error: {route}: a route file applies to Sensor Logger exports only")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_file_where_the_benchmark_writes_its_report_is_refused_before_any_work(tmp_path):
    """``OUT/report`` as a file: the benchmark ran all its walks, then failed to write the report
    ('exists and is not a folder'); it is now refused up front, as a report folder of the user's is."""
    import pytest

    from curbside.errors import CurbsideInputError
    from curbside.evaluate.suite_output import check_suite_folder

    out = tmp_path / "b"
    out.mkdir()
    (out / "report").write_text("my notes", encoding="utf-8")
    with pytest.raises(CurbsideInputError, match="report: is a file, where the benchmark writes its report"):
        check_suite_folder(out, overwrite=True)
    assert (out / "report").read_text(encoding="utf-8") == "my notes"


def test_pdr_velocity_of_a_walk_that_starts_standing_is_not_called_truncated(caplog):
    """The real IPIN cut stands 11 s before its first step; PDR's velocity starts at that step by
    construction (the walker stood before it), which the warning called 'a truncated file?'."""
    from curbside.localize.pipeline import track_session
    from curbside.localize.readers import read_any

    session = read_any(f"{SESSIONS / 'ipin2023-cut.h5'}::IPIN2023_T3_TrainingTrial01_repetition01")
    with caplog.at_level("WARNING", logger="curbside.localize.input_warnings"):
        track_session(session, None, "fused", velocity_source="pdr", seed=0, particles=100)
    assert "velocity covers" not in caplog.text
