"""Review fixes (s50): ``localize evaluate --methods`` also chooses the ``--ipin`` runs; each GNSS
parameter has its own description; the ``ipin_sf`` walk of docs/filter.md can be rebuilt."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from curbside.cli.localize import main

MAP = Path(__file__).parent / "data" / "evaluate" / "sf-path3.geojson"
IPIN_CUT = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """One simulated walk of the benchmark's path 3 (the fixture map is clipped around it)."""
    folder = tmp_path_factory.mktemp("walks") / "path3-s1"
    assert main(["simulate", "--route", "path3", "--seed", "1", "--map", str(MAP), "-o", str(folder)]) == 0
    return folder


def _section(report: str, title: str) -> str:
    """The markdown table under the bold ``title`` line that starts with it."""
    start = report.index(f"**{title}")
    return report[start:report.index("\n\n", report.index("|", start))]


def test_evaluate_methods_choose_the_ipin_runs_too(tmp_path, session):
    out = tmp_path / "r"
    argv = ["evaluate", str(session), "--maps", str(MAP), "--methods", "gnss", "fused", "--jaywalk-weights",
            "0.4", "--ipin", str(IPIN_CUT), "--ipin-trials", "1", "--workers", "1", "-o", str(out)]
    assert main(argv) == 0
    report = (out / "report.md").read_text()
    table = _section(report, "IPIN 2023 Track 3")
    assert "| GNSS |" in table and "| curbside fused |" in table
    assert "RoNIN+PF" not in table and "paper PF" not in table
    sure = _section(report, "IPIN 2023: how sure")
    assert "curbside fused - GNSS" in sure and "paper PF" not in sure
    rows = json.loads((out / "metrics.json").read_text())["ipin"]
    assert {r["method"] for r in rows} == {"gnss", "fused"}


def test_ipin_table_without_gnss_or_fused_has_no_columns_of_them():
    from curbside.evaluate.benchmark import ipin_table

    tables, rows = ipin_table(IPIN_CUT, trials=1, methods=("inertial", "paper"))
    assert len(tables) == 1  # no curbside fused: no "how sure" table of it
    (table,) = tables
    assert [r[0] for r in table.rows] == ["RoNIN+PF", "paper PF"]
    assert table.header == ["method", "waypoints", "median", "p90", "mean", "accuracy_m held"]
    assert all(len(r) == len(table.header) for r in table.rows)
    assert "GNSS" not in table.note
    assert set(pd.DataFrame(rows)["method"]) == {"inertial", "paper"}


def _descriptions() -> dict[str, str]:
    from curbside.configio import parameters
    from curbside.localize.runconfig import RunConfig

    return {p.key: p.description for p in parameters(RunConfig.for_mode("fused"))}


@pytest.mark.parametrize(("key", "neighbour", "not_said"), [
    ("filter.gnss.outlier_radius_m", "filter.gnss.outlier_prob", "0: the plain Gaussian"),
    ("filter.gnss.bias_time_s", "filter.gnss.bias_sigma_factor", "(0: none)"),
    ("filter.map.crossing_angle_deg", "filter.map.crossing_weight", "`None`: the paper's single weight"),
])
def test_a_parameter_is_not_described_with_its_neighbours_text(key, neighbour, not_said):
    described = _descriptions()
    assert described[key] != described[neighbour]
    assert not_said in described[neighbour] and not_said not in described[key]


def test_outlier_radius_is_described_as_the_positive_radius_the_check_wants():
    from curbside.errors import CurbsideInputError
    from curbside.localize.runconfig import RunConfig

    text = _descriptions()["filter.gnss.outlier_radius_m"]
    assert text.startswith("Radius (m, > 0)") and "outlier_prob / (pi * outlier_radius_m**2)" in text
    with pytest.raises(CurbsideInputError, match="outlier_radius_m must be positive"):
        RunConfig.for_mode("fused").with_overrides({"filter.gnss.outlier_radius_m": 0})


def test_the_ipin_sf_walk_of_filter_md_is_rebuilt_and_tracks_as_the_doc_says(tmp_path, monkeypatch):
    """docs/filter.md, "How far the estimate is from its segment": 29 updates naming Fremont Street's
    southwest side at 0.96-0.98, 18.7 m from it at the start and 8.4 m at the end."""
    import sys

    from curbside import settings
    from curbside.localize.session import read_session
    from curbside.osmseg.build import build_map
    from curbside.osmseg.mapio import read_map, write_map
    from curbside.osmseg.places import sidewalk_places

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    import ipin_sf_session

    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    assert ipin_sf_session.main(["-o", str(tmp_path / "ipin_sf")]) == 0
    session = read_session(tmp_path / "ipin_sf")
    assert session.meta["start"]["heading_deg"] == 90.0 and session.waypoints is None
    # The blocks round the walk: its track is the same to the bit as on make demo's whole map (checked at
    # stop 50), at a quarter of the cost of rasterising the whole map.
    write_map(build_map((-122.4003, 37.7885, -122.3943, 37.7925)), tmp_path / "map.geojson")
    argv = ["run", str(tmp_path / "ipin_sf"), "--map", str(tmp_path / "map.geojson"), "--seed", "0",
            "-o", str(tmp_path / "run")]
    assert main(argv) == 0
    track = pd.read_csv(tmp_path / "run" / "track.csv")
    assert len(track) == 29 and track["sidewalk_segment_id"].nunique() == 1
    assert track["segment_prob"].between(0.955, 0.985).all()
    assert track["segment_distance_m"].iloc[0] == pytest.approx(18.7, abs=0.05)
    assert track["segment_distance_m"].iloc[-1] == pytest.approx(8.4, abs=0.05)
    places = sidewalk_places(read_map(tmp_path / "map.geojson"))
    assert places[track["sidewalk_segment_id"].iloc[0]].label == "Fremont Street, southwest side"
