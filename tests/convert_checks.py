"""Checks shared by the tests of ``localize convert``'s readers."""

from __future__ import annotations

from pathlib import Path

from curbside.cli.localize import main


def assert_convert_refused(capsys, src: Path, dst: Path, message: str) -> None:
    """``localize convert SRC DST`` exits 2 with one line naming ``src`` and saying ``message``, no
    traceback, and writes nothing."""
    assert main(["convert", str(src), str(dst)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and str(src) in err, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not dst.exists()
