"""The demo (``make demo``): its stages, what it writes and prints."""

from __future__ import annotations

import json
import re
import time

import pytest

from curbside import demo
from curbside.osmseg.mapio import CLASSES, read_map
from curbside.osmseg.summary import class_summary


@pytest.fixture
def small_build(monkeypatch, test_data):
    """Replace the default-area build by the hand-drawn crossroads, to test the demo's plumbing fast."""
    path = test_data / "maps" / "crossroads.geojson"
    monkeypatch.setattr(demo, "build_map", lambda: read_map(path))
    return path


def test_demo_writes_geojson_png_html_and_prints_the_summary(tmp_path, small_build, capsys):
    written = demo.run_demo(tmp_path / "out", demo.MAP_STAGES)
    assert set(written) == {"map_geojson", "map_png", "map_html", "map_editor"}
    assert all(p.is_file() and p.parent == tmp_path / "out" for p in written.values())
    assert written["map_png"].read_bytes()[:4] == b"\x89PNG"
    assert "L.geoJson(" in written["map_html"].read_text(encoding="utf-8")
    expected = class_summary(read_map(small_build))
    assert class_summary(read_map(written["map_geojson"]))["count"].tolist() == expected["count"].tolist()
    out = capsys.readouterr().out
    for cls in CLASSES:
        assert re.search(rf"^{cls}\s+{expected.loc[cls, 'count']}\s", out, re.M)


def test_later_stages_append_and_see_earlier_results(tmp_path, small_build):
    seen = {}

    def extra(ctx: demo.DemoContext):
        seen["classes"] = sorted(set(ctx.results["map"].gdf["class"]))
        path = ctx.out_dir / "extra.json"
        path.write_text(json.dumps(seen))
        return {"extra": path}

    written = demo.run_demo(tmp_path, [*demo.MAP_STAGES, demo.Stage("extra", extra)])
    assert seen["classes"] == sorted(CLASSES)
    assert list(written)[-1] == "extra" and written["extra"].is_file()


def test_demo_command_line(tmp_path, small_build, capsys):
    assert demo.main(["--out", str(tmp_path / "o"), "--map-only"]) == 0
    assert "map_html" in capsys.readouterr().out
    names = sorted(p.name for p in (tmp_path / "o").iterdir())
    assert names == ["edit.html", "map.geojson", "map.html", "map.png"]


@pytest.mark.slow
def test_demo_end_to_end_on_the_bundled_default_area(tmp_path, capsys):
    written = demo.run_demo(tmp_path)
    layers = read_map(written["map_geojson"])
    summary = class_summary(layers)
    assert (summary["count"] > 100).all()  # every class is there, in numbers, for downtown SF
    assert layers.meta["source"].endswith(".osm.bz2")
    out = capsys.readouterr().out
    assert "sidewalk" in out
    metrics = json.loads((tmp_path / "benchmark" / "report" / "metrics.json").read_text())
    assert metrics, "the benchmark report has metrics"
    html = (tmp_path / "benchmark" / "report" / "report.html").read_text(encoding="utf-8")
    assert "Correct Sidewalk Assignment" in html or "CSA" in html
    assert "How sure: 95 % intervals" in html and metrics["intervals_95"]
    assert "How far to trust segment_prob" in html and metrics["segment_prob_reliability"]
    named = r"curbside fused on \d+ % of footsteps, right \d+ % of the time; paper PF on \d+ % "
    assert re.search(rf"^  a side named at segment_prob >= 0.9: {named}", out, re.M)
    held = r"curbside fused \d+ %, paper PF \d+ % of footsteps"
    assert re.search(rf"^  accuracy_m \(68 % claimed\) held the walker: {held}", out, re.M)
    # a short summary, not the report; each file listed once; the replay of one walk with its clouds
    assert "# curbside evaluation report" not in out and "Table 2" not in out
    assert re.search(r"^  curbside fused +CSA \d\.\d\d +error median", out, re.M)
    signed = r"[+-]\d\.\d\d"
    assert re.search(rf"^  curbside fused - paper PF: CSA {signed} \[{signed}, {signed}\], p90 ", out, re.M)
    assert len(set(written.values())) == len(written)
    page = written["replay_viewer"].read_text(encoding="utf-8")
    assert page.count('"cloud":{') == 2  # inertial and fused keep their particle clouds


def test_each_output_is_listed_once(tmp_path, small_build):
    again = demo.Stage("again", lambda ctx: {"same_map": ctx.out_dir / "map.geojson"})
    written = demo.run_demo(tmp_path, [*demo.MAP_STAGES, again])
    assert "same_map" not in written and list(written.values()).count(tmp_path / "map.geojson") == 1


def test_long_stages_log_progress_when_stderr_is_not_a_terminal(tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(demo, "HEARTBEAT_S", 0.05)
    slow = demo.Stage("slow stage", lambda ctx: time.sleep(0.3) or {})
    with caplog.at_level("INFO", logger="curbside.demo"):
        demo.run_demo(tmp_path, [slow])  # pytest captures stderr: not a terminal
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == "stage 1/1: slow stage"
    assert sum("slow stage: still running" in line for line in lines) >= 3
    assert re.fullmatch(r"stage 1/1: slow stage done in 0\.\d s", lines[-1])


def test_the_headline_is_a_few_lines_from_the_reports_metrics(tmp_path):
    pooled = [
        {"map": "osm", "method": "gnss", "jaywalk_weight": 0.4, "particles": 500, "csa": 0.5,
         "euclid_median_m": 9.0, "euclid_p90_m": 20.0},
        {"map": "osm", "method": "fused", "jaywalk_weight": 0.4, "particles": 500, "csa": 0.81,
         "euclid_median_m": 3.25, "euclid_p90_m": 7.0},
        {"map": "osm", "method": "fused", "jaywalk_weight": 0.0, "particles": 500, "csa": 0.7,
         "euclid_median_m": 4.0, "euclid_p90_m": 9.0},
    ]
    base = {"map": "osm", "jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}
    (tmp_path / "metrics.json").write_text(json.dumps({"base": base, "pooled": pooled}))
    lines = demo.benchmark_headline(tmp_path).splitlines()
    assert len(lines) == 4
    assert lines[1] == "  GNSS           CSA 0.50   error median 9.0 m, p90 20.0 m"
    assert lines[2] == "  curbside fused CSA 0.81   error median 3.2 m, p90 7.0 m"
