"""The README's Python example runs as written (on a small fixture map instead of ``out/map.geojson``)."""

from __future__ import annotations

import re

import geopandas as gpd
from conftest import REPO, TEST_DATA


def _python_blocks(markdown: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", markdown, flags=re.S)


def test_readme_streaming_example_runs_and_names_a_sidewalk():
    (example,) = _python_blocks((REPO / "README.md").read_text(encoding="utf-8"))
    map_path = TEST_DATA / "maps" / "crossroads.geojson"
    assert '"out/map.geojson"' in example
    sidewalks = gpd.read_file(map_path)
    sidewalks = sidewalks[sidewalks["class"] == "sidewalk"]
    # start on a sidewalk segment's centre, one footstep east at 1 m/s, a fix 2 m off reporting 5 m
    centre = sidewalks.to_crs(32610).geometry.iloc[0].representative_point()
    start = gpd.GeoSeries([centre], crs=32610).to_crs(4326).iloc[0]
    fix = gpd.GeoSeries([centre.__class__(centre.x + 2.0, centre.y)], crs=32610).to_crs(4326).iloc[0]
    scope = {"t0": 0.0, "lat0": start.y, "lon0": start.x, "t": 0.55, "ve": 1.0, "vn": 0.0,
             "lat": fix.y, "lon": fix.x, "acc": 5.0}
    exec(example.replace('"out/map.geojson"', repr(str(map_path))), scope)  # noqa: S102 - our own README
    estimate = scope["estimate"]
    assert estimate.segment_id in set(sidewalks["segment_id"])
    assert 0.0 < estimate.segment_prob <= 1.0
    assert 0.0 < estimate.accuracy_m < 10.0  # a cloud started on the spot, one footstep and a fix later
    assert estimate.n_eff > 0
