"""The interactive HTML map: self-contained (vendored Leaflet inlined, nothing remote), one layer per
class with the map's polygons and sidewalk fields, safe against markup in the data, written atomically."""

from __future__ import annotations

import fnmatch
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import geopandas as gpd
import numpy as np
import pytest
import shapely

from curbside.osmseg import plot
from curbside.osmseg.mapio import CLASSES, MapLayers, read_map
from curbside.osmseg.plot import html_page, save_html
from curbside.osmseg.webmap import COORDINATE_DECIMALS, WEB_ASSETS

REPO = Path(__file__).resolve().parents[1]
REMOTE = re.compile(r"^\s*(https?:)?//", re.IGNORECASE)


class _Page(HTMLParser):
    """Every start tag with its attributes, and the text of each ``<script>`` and ``<style>``."""

    def __init__(self, text: str):
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.blocks: dict[str, list[str]] = {"script": [], "style": []}
        self._open: str | None = None
        self.feed(text)
        self.close()

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        if tag in self.blocks:
            self._open = tag
            self.blocks[tag].append("")

    def handle_endtag(self, tag):
        self._open = None

    def handle_data(self, data):
        if self._open:
            self.blocks[self._open][-1] += data


def _overlays(page: str) -> list[dict]:
    """The FeatureCollection passed to each ``L.geoJson(...)`` call, in page order."""
    decoder = json.JSONDecoder()
    return [decoder.raw_decode(page, m.end())[0] for m in re.finditer(r"L\.geoJson\(", page)]


@pytest.fixture
def crossroads(test_data) -> MapLayers:
    return read_map(test_data / "maps" / "crossroads.geojson")


def test_page_references_nothing_outside_itself(crossroads):
    page = _Page(html_page(crossroads))
    assert len(page.blocks["script"]) == 2 and len(page.blocks["style"]) >= 1
    # every asset is inline: no element points at a file, remote or local
    assert not [(t, a) for t, a in page.tags if "src" in a or t in ("link", "img", "iframe", "object")]
    assert not [a for _, a in page.tags for k, v in a.items() if k in ("href", "data") and REMOTE.match(v)]
    css = "\n".join(page.blocks["style"])
    assert "@import" not in css
    assert not [u for u in re.findall(r"url\(\s*['\"]?([^'\")]*)", css) if REMOTE.match(u)]
    # no tile server: no tile layer is created and no tile URL template exists
    assert "L.tileLayer" not in page.rawdata and "{z}" not in page.rawdata
    assert "sourceMappingURL" not in page.rawdata


def test_the_vendored_leaflet_is_inlined_and_shipped_as_package_data(crossroads):
    page = _Page(html_page(crossroads))
    leaflet_js = (WEB_ASSETS / "leaflet.js").read_text(encoding="utf-8")
    assert leaflet_js.startswith("/* @preserve\n * Leaflet 1.9.4")
    without_map = leaflet_js.replace("//# sourceMappingURL=leaflet.js.map", "")
    assert page.blocks["script"][0].strip() == without_map.strip()
    assert page.blocks["style"][0].strip() == (WEB_ASSETS / "leaflet.css").read_text(encoding="utf-8").strip()
    assert "BSD 2-Clause" in (WEB_ASSETS / "LICENSE").read_text()
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    patterns = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    for name in ("leaflet.js", "leaflet.css", "LICENSE"):
        relative = (WEB_ASSETS / name).relative_to(REPO / "curbside").as_posix()
        assert any(fnmatch.fnmatch(relative, p) for p in patterns["curbside"]), relative


def test_each_class_is_one_overlay_with_the_maps_polygons(crossroads):
    page = html_page(crossroads)
    overlays = _overlays(page)
    present = [c for c in plot.CLASS_STYLE if len(crossroads.layer(c))]
    assert len(overlays) == len(present) == len(CLASSES)
    wgs84 = crossroads.gdf.to_crs(4326)
    for cls, overlay in zip(present, overlays, strict=True):
        expected = wgs84[wgs84["class"] == cls]
        shapes = shapely.from_geojson([json.dumps(f["geometry"]) for f in overlay["features"]])
        assert len(shapes) == len(expected)
        # the same polygons, up to the display rounding (1e-6 degrees: at most 0.08 m here)
        drawn = gpd.GeoSeries(shapes, crs=4326).to_crs(crossroads.crs).union_all()
        source = expected.geometry.to_crs(crossroads.crs).union_all()
        assert shapely.hausdorff_distance(drawn, source) < 0.1
        assert drawn.area == pytest.approx(source.area, rel=0.01)
        assert f"{plot.CLASS_STYLE[cls]['label']} ({len(expected):,})" in page
    sidewalks = overlays[present.index("sidewalk")]["features"]
    fields = [(p["segment_id"], p["street"], p["side"]) for p in (f["properties"] for f in sidewalks)]
    rows = crossroads.layer("sidewalk")[["segment_id", "street", "side"]]
    rows = rows.astype(object).where(rows.notna(), None).itertuples(index=False)  # a missing name is null
    assert sorted(fields) == sorted(map(tuple, rows))
    assert "describeSegment" in page and "bindTooltip(segmentTable" in page


def test_coordinates_are_rounded_for_display(crossroads):
    overlays = _overlays(html_page(crossroads))
    coords = np.concatenate(
        [shapely.get_coordinates(shapely.from_geojson(json.dumps(f["geometry"])))
         for o in overlays for f in o["features"]]
    )
    scale = 10.0**COORDINATE_DECIMALS
    np.testing.assert_allclose(coords * scale, np.round(coords * scale), atol=1e-6)
    assert (np.abs(coords - np.round(coords, 5)) > 1e-9).any()  # ... but not coarser than asked


def test_markup_in_the_data_stays_text(crossroads):
    gdf = crossroads.gdf.copy()
    hostile = '</script><img src="https://evil.example/x.png">'
    gdf.loc[gdf["class"] == "sidewalk", "street"] = hostile
    meta = {"source": "<b>bold</b> & co", "attribution": "A & B <i>x</i>"}
    page = html_page(MapLayers(gdf, meta))
    parsed = _Page(page)
    assert len(parsed.blocks["script"]) == 2
    assert not [t for t, _ in parsed.tags if t == "img"]
    assert "<title>curbside map layers: &lt;b&gt;bold&lt;/b&gt; &amp; co</title>" in page
    assert json.dumps("A &amp; B &lt;i&gt;x&lt;/i&gt;") in page
    sidewalks = _overlays(page)[list(plot.CLASS_STYLE).index("sidewalk")]["features"]
    assert {f["properties"]["street"] for f in sidewalks} == {hostile}


def test_html_is_written_atomically(tmp_path, crossroads, monkeypatch):
    out = tmp_path / "map.html"
    out.write_text("previous map")
    original = Path.write_text

    def half_then_fail(self, text, *args, **kwargs):
        original(self, text[: len(text) // 2], *args, **kwargs)
        raise OSError("disk full")

    monkeypatch.setattr(Path, "write_text", half_then_fail)
    with pytest.raises(OSError, match="disk full"):
        save_html(crossroads, out)
    monkeypatch.undo()
    assert out.read_text() == "previous map"
    assert [p.name for p in tmp_path.iterdir()] == ["map.html"]
    save_html(crossroads, out)
    assert out.read_text(encoding="utf-8") == html_page(crossroads)


def test_tooltip_names_the_street_and_its_compass_side(crossroads):
    from curbside.osmseg.places import sidewalk_places

    page = html_page(crossroads)
    sidewalks = _overlays(page)[list(plot.CLASS_STYLE).index("sidewalk")]["features"]
    shown = {f["properties"]["segment_id"]: f["properties"]["place"] for f in sidewalks}
    expected = {k: place.label for k, place in sidewalk_places(crossroads).items()}
    assert shown == expected  # the same words as the service and the replay page
    assert {"Market Street, north side", "Market Street, south side", "unnamed street, west side"} <= set(
        shown.values()
    )
    assert '["segment", "segment_id"], ["OSM side", "side"]' in page  # left/right kept, second
    assert "of the way as drawn" in page and "props.place" in page


def test_the_background_has_an_honest_legend_line(crossroads):
    page = html_page(crossroads)
    assert "free space (no building in this map)" in page  # a hand-drawn map: not OSM's buildings
    assert 'querySelector(".leaflet-control-layers-list").append(background)' in page
