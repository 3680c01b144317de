"""osmseg show: PNG and HTML rendering, the class summary, and the command's bad-input handling."""

from __future__ import annotations

import json
import re

import geopandas as gpd
import numpy as np
import pytest
import shapely
from matplotlib.colors import to_rgb
from matplotlib.image import imread

from curbside.cli.osmseg import main
from curbside.errors import CurbsideInputError
from curbside.osmseg import plot
from curbside.osmseg.mapio import CLASSES, MapLayers, read_map, write_map
from curbside.osmseg.plot import CLASS_STYLE, clip_to_bbox, render_map
from curbside.osmseg.style import CONFLICT_COLOUR
from curbside.osmseg.summary import class_summary, format_summary

UTM10 = "EPSG:32610"
X0, Y0 = 552_000.0, 4_183_000.0  # downtown San Francisco, UTM zone 10N


def _layers(rows: list[tuple[str, shapely.Geometry, str | None]]) -> MapLayers:
    """A map from (class, polygon in metres from (X0, Y0), street) rows."""
    gdf = gpd.GeoDataFrame(
        {
            "class": [r[0] for r in rows],
            "segment_id": [f"s{i}" if r[0] == "sidewalk" else None for i, r in enumerate(rows)],
            "street": [r[2] for r in rows],
            "side": ["left" if r[0] == "sidewalk" else None for r in rows],
        },
        geometry=[shapely.affinity.translate(r[1], X0, Y0) for r in rows],
        crs=UTM10,
    )
    return MapLayers(gdf, {"source": "test"})


@pytest.fixture
def crossroads(test_data):
    return test_data / "maps" / "crossroads.geojson"


@pytest.fixture
def buildings_only(tmp_path, crossroads):
    """A 'hand-labelled' map with buildings only (no sidewalk segments), as SPEC allows."""
    doc = json.loads(crossroads.read_text())
    doc["features"] = [f for f in doc["features"] if f["properties"]["class"] == "building"]
    del doc["curbside"]
    path = tmp_path / "hand.geojson"
    path.write_text(json.dumps(doc))
    return path


def test_class_summary_counts_union_areas_and_named_sidewalks():
    a, b = shapely.box(0, 0, 10, 10), shapely.box(5, 0, 15, 10)  # overlap 50 m^2
    walk = [shapely.box(0, 12, 10, 14), shapely.box(10, 12, 20, 14), shapely.box(20, 12, 30, 14)]
    layers = _layers(
        [("building", a, None), ("building", b, None)]
        + [("sidewalk", w, name) for w, name in zip(walk, ["Main St", None, "Main St"], strict=True)]
    )
    summary = class_summary(layers)
    assert list(summary.index) == list(CLASSES)
    assert summary.loc["building", "count"] == 2
    assert summary.loc["building", "area_m2"] == pytest.approx(shapely.union(a, b).area)
    assert summary.loc["sidewalk", "area_m2"] == pytest.approx(sum(w.area for w in walk))
    assert summary.loc["sidewalk", "named"] == 2
    assert summary.loc["street", "count"] == 0 and summary.loc["street", "area_m2"] == 0
    text = format_summary(summary)
    assert re.search(r"^building\s+2\s+150\s", text, re.M)
    assert re.search(r"^all\s+5\s+210\s", text, re.M)


def _colour_fraction(png, colour: str, tol: float = 0.02) -> float:
    image = imread(png)[..., :3]
    return float((np.abs(image - np.array(to_rgb(colour))).max(axis=-1) < tol).mean())


def test_png_draws_each_class_present_and_only_those(tmp_path, crossroads, buildings_only):
    full, hand = tmp_path / "full.png", tmp_path / "hand.png"
    assert main(["show", str(crossroads), "-o", str(full)]) == 0
    assert main(["show", str(buildings_only), "-o", str(hand)]) == 0
    assert full.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    sidewalk = CLASS_STYLE["sidewalk"]["facecolor"]
    building = CLASS_STYLE["building"]["facecolor"]
    street = CLASS_STYLE["street"]["facecolor"]
    assert _colour_fraction(full, sidewalk) > 0.02
    assert _colour_fraction(full, street) > 0.05
    assert _colour_fraction(hand, building) > 0.3
    # the legend patch is tiny; without sidewalk polygons almost no pixel has their colour
    assert _colour_fraction(hand, sidewalk) < 0.001
    assert _colour_fraction(hand, street) < 0.001


def test_png_shows_where_buildings_stand_on_sidewalks(tmp_path, crossroads):
    clean = read_map(crossroads)
    assert len(plot.sidewalk_under_buildings(clean)) == 0  # osmseg's classes are disjoint
    conflicted = _layers([
        ("street", shapely.box(0, 0, 100, 12), None),
        ("sidewalk", shapely.box(0, 12, 100, 16), "Main St"),
        ("building", shapely.box(0, 14, 100, 40), None),  # drawn 2 m over the sidewalk
    ])
    pieces = plot.sidewalk_under_buildings(conflicted)
    assert shapely.area(pieces.values).sum() == pytest.approx(200.0)
    png_clean, png_conflicted = tmp_path / "clean.png", tmp_path / "conflicted.png"
    assert main(["show", str(crossroads), "-o", str(png_clean)]) == 0
    assert main(["show", str(write_map(conflicted, tmp_path / "c.geojson")), "-o", str(png_conflicted)]) == 0
    assert _colour_fraction(png_conflicted, CONFLICT_COLOUR) > 0.01
    assert _colour_fraction(png_clean, CONFLICT_COLOUR) < 0.0005
    html_clean, html_conflicted = tmp_path / "clean.html", tmp_path / "conflicted.html"
    assert main(["show", str(crossroads), "-o", str(html_clean)]) == 0
    assert main(["show", str(tmp_path / "c.geojson"), "-o", str(html_conflicted)]) == 0
    assert "building over sidewalk (200 m²)" in html_conflicted.read_text(encoding="utf-8")
    assert "building over sidewalk" not in html_clean.read_text(encoding="utf-8")


def test_html_has_one_layer_per_class_tooltips_attribution_and_no_tiles(tmp_path, crossroads):
    out = tmp_path / "map.html"
    assert main(["show", str(crossroads), "-o", str(out)]) == 0
    page = out.read_text(encoding="utf-8")
    assert page.count("L.geoJson(") == 4
    assert "L.control.layers" in page
    assert "L.tileLayer" not in page and "tile.openstreetmap" not in page  # leaflet.js defines tileLayer
    assert '"segment_id"' in page and "Market Street" in page
    assert "OpenStreetMap contributors" in page


def test_html_of_a_map_without_sidewalks_has_no_sidewalk_layer(tmp_path, buildings_only):
    out = tmp_path / "hand.html"
    assert main(["show", str(buildings_only), "-o", str(out)]) == 0
    page = out.read_text(encoding="utf-8")
    assert page.count("L.geoJson(") == 1
    assert "sidewalk segment" not in page


def test_bbox_clips_the_map_to_the_window(crossroads):
    layers = read_map(crossroads)
    lon, lat = gpd.GeoSeries(layers.gdf.geometry, crs=layers.crs).to_crs(4326).union_all().centroid.xy
    window = (lon[0], lat[0], lon[0] + 0.001, lat[0] + 0.001)  # the north-east quarter
    clipped = clip_to_bbox(layers, window)
    box_utm = gpd.GeoSeries([shapely.box(*window)], crs=4326).to_crs(layers.crs).iloc[0]
    assert shapely.covers(box_utm.buffer(1e-6), clipped.gdf.geometry.values).all()
    assert class_summary(clipped).loc["building", "count"] == 1
    assert class_summary(clipped).loc["sidewalk", "count"] == 2


def test_render_leaves_nothing_when_drawing_fails(tmp_path, crossroads, monkeypatch):
    def broken(*_args, **_kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(plot.Figure, "savefig", broken)
    with pytest.raises(RuntimeError):
        render_map(read_map(crossroads), tmp_path / "map.png")
    assert list(tmp_path.iterdir()) == []


def _bad_map(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text)
    return path


def _projected_map(tmp_path, crossroads):
    layers = read_map(crossroads)
    doc = json.loads(layers.gdf.to_json())
    return _bad_map(tmp_path, "utm.geojson", json.dumps(doc))


@pytest.mark.parametrize(
    ("make_input", "extra", "message"),
    [
        (lambda tmp, cr: tmp / "missing.geojson", [], "no such map file"),
        (lambda tmp, cr: _bad_map(tmp, "bad.geojson", '{"type": "FeatureColl'), [], "not readable"),
        (lambda tmp, cr: _bad_map(tmp, "fc.geojson", '{"type": "Feature"}'), [], "not a GeoJSON Feature"),
        (
            lambda tmp, cr: _bad_map(tmp, "cls.geojson", cr.read_text().replace('"crosswalk"', '"zebra"')),
            [],
            "unknown feature class",
        ),
        (_projected_map, [], "not WGS84 lon/lat"),
        (lambda tmp, cr: cr, ["--bbox", "-122.39", "37.79", "-122.40", "37.80"], "west"),
        (lambda tmp, cr: cr, ["--bbox", "-122.5", "37.5", "-122.49", "37.51"], "contains no polygon"),
    ],
    ids=["missing", "malformed-json", "not-featurecollection", "unknown-class", "projected", "bbox-order",
         "bbox-empty"],
)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(
    tmp_path, crossroads, capsys, make_input, extra, message
):
    source = make_input(tmp_path, crossroads)
    before = set(tmp_path.iterdir())
    out = tmp_path / "out.png"
    assert main(["show", str(source), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert set(tmp_path.iterdir()) == before


@pytest.mark.parametrize("name", ["map.jpg", "map.svg", "map"])
def test_unsupported_output_extension_exits_2(tmp_path, crossroads, capsys, name):
    assert main(["show", str(crossroads), "-o", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unsupported output format" in err
    assert list(tmp_path.iterdir()) == []


def test_written_map_renders_after_round_trip(tmp_path, crossroads):
    layers = read_map(crossroads)
    again = read_map(write_map(layers, tmp_path / "again.geojson"))
    assert class_summary(again)["count"].tolist() == class_summary(layers)["count"].tolist()
    np.testing.assert_allclose(class_summary(again)["area_m2"], class_summary(layers)["area_m2"], rtol=1e-4)
    with pytest.raises(CurbsideInputError, match="unsupported output format"):
        render_map(again, tmp_path / "again.pdf")


def test_png_legend_names_the_background_honestly_and_sits_outside_the_map(crossroads):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 6))
    ax = plot.plot_map(read_map(crossroads), fig.add_axes((0.05, 0.05, 0.6, 0.85)))
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "free space (no building in this map)" in labels and "free space" not in labels  # hand-drawn
    renderer = FigureCanvasAgg(fig).get_renderer()
    legend, frame = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    assert legend.x0 >= frame.x1  # beside the map, covering none of it


def test_bbox_is_named_in_the_title(tmp_path, crossroads, monkeypatch):
    layers = read_map(crossroads)
    assert plot.map_title(layers) == "curbside map layers: hand-drawn test crossroads"
    window = (-122.40512, 37.788, -122.399, 37.7921)
    assert plot.map_title(layers, window) == (
        "curbside map layers: hand-drawn test crossroads, bbox -122.40512, 37.788, -122.399, 37.7921"
    )
    lon, lat = layers.gdf.to_crs(4326).union_all().centroid.xy
    window = (lon[0] - 0.001, lat[0] - 0.001, lon[0] + 0.001, lat[0] + 0.001)
    titles = []
    monkeypatch.setattr(plot, "plot_map", lambda _layers, ax, title=None: titles.append(title))
    render_map(layers, tmp_path / "window.png", bbox=window)
    assert titles == [plot.map_title(layers, window)] and "bbox" in titles[0]
    assert "bbox" in render_map(layers, tmp_path / "w.html", bbox=window).read_text(encoding="utf-8")


def test_a_window_keeps_the_compass_sides_found_on_the_whole_map(tmp_path):
    layers = _layers([
        ("street", shapely.box(0, 0, 100, 12), None),
        ("sidewalk", shapely.box(0, 12, 100, 16), "Main St"),  # north of its street
        ("building", shapely.box(0, 20, 100, 40), None),
    ])
    window = gpd.GeoSeries([shapely.box(X0 + 10, Y0 + 13, X0 + 90, Y0 + 30)], crs=UTM10).to_crs(4326)
    out = render_map(layers, tmp_path / "window.html", bbox=tuple(window.total_bounds))
    page = out.read_text(encoding="utf-8")
    assert '"place":"Main St, north side"' in page  # its street is outside the window
    assert '"class":"street"' not in page
