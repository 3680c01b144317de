"""The shared skeleton: session schema validation, atomic writes, projections, exit statuses."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curbside.cli.common import make_parser, run_cli
from curbside.errors import CurbsideInputError
from curbside.io import atomic_path
from curbside.localize.session import Session, read_session, write_session
from curbside.projection import LocalFrame, utm_crs_for


def _gnss(n: int = 5) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "t": np.arange(n, dtype=float),
            "lat": 37.79 + 1e-5 * np.arange(n),
            "lon": -122.40 + np.zeros(n),
            "accuracy_m": [5.0, -1.0, np.nan, 8.0, 12.0][:n],
        }
    )


def test_session_round_trip_keeps_values(tmp_path):
    start = {"lat": 37.79, "lon": -122.4, "heading_deg": 90}
    session = Session(name="s", gnss=_gnss(), meta={"start": start})
    write_session(session, tmp_path / "s")
    back = read_session(tmp_path / "s")
    np.testing.assert_allclose(back.gnss[["t", "lat", "lon"]], session.gnss[["t", "lat", "lon"]], atol=1e-9)
    # invalid accuracies survive as data: they are invalid fixes, not bad files
    assert back.gnss["accuracy_m"].isna().sum() == 1
    assert back.start_pose["heading_deg"] == 90


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.assign(t=[0.0, 1.0, 1.0, 3.0, 4.0]), "duplicated timestamp"),
        (lambda d: d.assign(t=[0.0, 2.0, 1.0, 3.0, 4.0]), "out-of-order timestamp"),
        (lambda d: d.assign(lat=[37.79, np.nan, 37.79, 37.79, 37.79]), "NaN or infinite 'lat'"),
        (lambda d: d.drop(columns=["lon"]), "missing column"),
        (lambda d: d.assign(lat=[370.0] * 5), "outside WGS84"),
        (lambda d: d.assign(lat=["x"] * 5), "non-numeric"),
        (lambda d: d.iloc[:0], "no rows"),
    ],
)
def test_bad_gnss_file_is_named_in_one_line(tmp_path, mutate, message):
    folder = tmp_path / "bad"
    folder.mkdir()
    mutate(_gnss()).to_csv(folder / "gnss.csv", index=False)
    with pytest.raises(CurbsideInputError) as info:
        read_session(folder)
    assert message in str(info.value)
    assert "gnss.csv" in str(info.value)
    assert "\n" not in str(info.value)


def test_malformed_meta_and_empty_folder(tmp_path):
    with pytest.raises(CurbsideInputError, match="not a session folder"):
        read_session(tmp_path)
    _gnss().to_csv(tmp_path / "gnss.csv", index=False)
    (tmp_path / "meta.json").write_text("{not json")
    with pytest.raises(CurbsideInputError, match="meta.json: malformed JSON"):
        read_session(tmp_path)
    (tmp_path / "meta.json").write_text(json.dumps({"start": {"lat": 1}}))
    with pytest.raises(CurbsideInputError, match="'start' must be"):
        read_session(tmp_path)


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    dst = tmp_path / "out.txt"
    with pytest.raises(RuntimeError), atomic_path(dst) as tmp:
        tmp.write_text("half")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with atomic_path(dst) as tmp:
        tmp.write_text("whole")
    assert dst.read_text() == "whole"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_atomic_path_replaces_its_own_directory_but_never_a_users(tmp_path):
    dst = tmp_path / "d"
    for name in ("old", "new"):  # the second write replaces the first (a previous curbside output)
        with atomic_path(dst) as tmp:
            tmp.mkdir()
            (tmp / name).write_text("y")
    assert sorted(p.name for p in dst.iterdir()) == [".curbside-output", "new"]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "old").write_text("x")
    with pytest.raises(CurbsideInputError, match="not written by curbside"), atomic_path(mine) as tmp:
        tmp.mkdir()
    assert [p.name for p in mine.iterdir()] == ["old"]


def test_utm_zone_of_san_francisco():
    assert utm_crs_for(-122.4, 37.79).to_epsg() == 32610
    assert utm_crs_for(11.07, 49.45).to_epsg() == 32632  # Nuremberg


@settings(max_examples=50, deadline=None)
@given(
    st.floats(min_value=-122.5, max_value=-122.3), st.floats(min_value=37.7, max_value=37.85)
)
def test_local_frame_round_trip(lon, lat):
    frame = LocalFrame.around(-122.4, 37.79)
    x, y = frame.to_xy(np.array([lon]), np.array([lat]))
    lon2, lat2 = frame.to_lonlat(x, y)
    assert abs(lon2[0] - lon) < 1e-9 and abs(lat2[0] - lat) < 1e-9


def _parser_raising(exc: Exception):
    parser = make_parser("prog", "test")
    sub = parser.add_subparsers()
    cmd = sub.add_parser("go")

    def func(_args):
        raise exc

    cmd.set_defaults(func=func)
    return parser


def test_exit_status_contract(capsys):
    assert run_cli("prog", _parser_raising(CurbsideInputError("f.csv", "broken")), ["go"]) == 2
    err = capsys.readouterr().err
    assert err == "prog: error: f.csv: broken\n"
    assert run_cli("prog", _parser_raising(ValueError("bug")), ["go"]) == 1
    assert "Traceback" not in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        run_cli("prog", _parser_raising(ValueError()), ["--bogus"])
    assert info.value.code == 2


def test_a_closed_pipe_ends_quietly():
    """``command | head``: the reader goes away; no internal error and no traceback."""
    script = (
        "from curbside.cli.common import make_parser, run_cli\n"
        "def talk(_args):\n"
        "    for i in range(200_000):\n"
        "        print('line', i)\n"
        "parser = make_parser('prog', 'test')\n"
        "parser.add_subparsers().add_parser('go').set_defaults(func=talk)\n"
        "raise SystemExit(run_cli('prog', parser, ['go']))\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.read(100)
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141
    assert err == ""
