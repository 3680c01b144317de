"""Checks shared by the tests of ``localize convert``'s readers."""

from __future__ import annotations

from collections.abc import Callable
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


def assert_spoiled_log_refused(
    tmp_path: Path, capsys, write_log: Callable[[Path], object], spoil: Callable[[Path], None], message: str
) -> None:
    """A log written by ``write_log`` and then spoiled is refused by ``localize convert`` as
    :func:`assert_convert_refused` says."""
    src = tmp_path / "log.txt"
    write_log(src)
    spoil(src)
    assert_convert_refused(capsys, src, tmp_path / "out", message)
