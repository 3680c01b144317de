"""The demo (``make demo``): its stages, what it writes and prints."""

from __future__ import annotations

import json
import re

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
    assert set(written) == {"map_geojson", "map_png", "map_html"}
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
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["map.geojson", "map.html", "map.png"]


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
