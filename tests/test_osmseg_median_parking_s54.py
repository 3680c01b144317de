"""A dual carriageway whose halves' widths come from ``lanes`` gives up the parking assumed on the
sides that face its median, but only where the median that opens is a real refuge
(``min_refuge_width_m``).

Scenes are small OSM files written here: a road 200 m long drawn as two one-way ``secondary`` halves
of one name with ``lanes=2`` (6 m of lanes plus 2.2 m of assumed parking each side: 5.2 m half-width,
3.0 m without the parking), a two-way cross street at each end and a crossing way across both halves
at mid-block.
"""

from __future__ import annotations

from pathlib import Path

import geopandas as gpd
import numpy as np
import pytest
import shapely

from curbside.osmseg.build import build_map
from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.mapio import MapLayers

LON0, LAT0 = -122.4000, 37.7900
M_PER_DEG_LAT = 111_320.0
M_PER_DEG_LON = 111_320.0 * np.cos(np.radians(LAT0))
#: The rule off: no median is this wide.
RULE_OFF = SegmentationConfig(min_refuge_width_m=99.0)


def _lonlat(x_m: float, y_m: float) -> tuple[float, float]:
    return LON0 + x_m / M_PER_DEG_LON, LAT0 + y_m / M_PER_DEG_LAT


def divided_road(path: Path, centres_apart_m: float) -> Path:
    """Halves at x = +-centres_apart_m / 2 (east northbound, west southbound), cross streets at
    y = +-100 m, a crossing way along y = 0 from 12 m west of the west half to 12 m east of the east."""
    x = centres_apart_m / 2
    points = {1: (-x, -100), 2: (-x, 100), 3: (x, -100), 4: (x, 100), 5: (-x - 120, -100),
              6: (x + 120, -100), 7: (-x - 120, 100), 8: (x + 120, 100), 9: (-x - 12, 0),
              10: (x + 12, 0)}  # fmt: skip
    nodes = "".join(
        f'<node id="{i}" version="1" lat="{lat:.8f}" lon="{lon:.8f}"/>'
        for i, (lon, lat) in ((i, _lonlat(*xy)) for i, xy in points.items())
    )
    half = {"highway": "secondary", "name": "Divided Road", "oneway": "yes", "lanes": "2"}
    cross = {"highway": "residential", "name": "Cross Street"}
    crossing = {"highway": "footway", "footway": "crossing"}

    def way(way_id: int, refs: list[int], tags: dict[str, str]) -> str:
        nds = "".join(f'<nd ref="{r}"/>' for r in refs)
        tag_xml = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        return f'<way id="{way_id}" version="1">{nds}{tag_xml}</way>'

    ways = [way(20, [3, 4], half), way(21, [2, 1], half), way(22, [5, 1, 3, 6], cross),
            way(23, [7, 2, 4, 8], cross), way(24, [9, 10], crossing)]  # fmt: skip
    path.write_text(f'<?xml version="1.0"?><osm version="0.6">{nodes}{"".join(ways)}</osm>')
    return path


def _point(layers: MapLayers, x_m: float, y_m: float) -> shapely.Point:
    return gpd.GeoSeries([shapely.Point(_lonlat(x_m, y_m))], crs="EPSG:4326").to_crs(layers.crs).values[0]


def _class_at(layers: MapLayers, x_m: float, y_m: float) -> str | None:
    gdf = layers.gdf
    hit = shapely.covers(gdf.geometry.values, _point(layers, x_m, y_m))
    return str(gdf["class"].to_numpy()[hit][0]) if hit.any() else None


def _geoms(layers: MapLayers, cls: str) -> np.ndarray:
    return layers.gdf.geometry.values[layers.gdf["class"].to_numpy() == cls]


def test_a_wide_median_opens_and_its_crosswalk_stays_whole(tmp_path):
    # Centrelines 10 m apart: the halves (5.2 m each) overlap by 0.4 m; without the median-side
    # parking their curbs are 4 m apart.
    path = divided_road(tmp_path / "wide.osm", 10.0)
    layers = build_map(osm_file=path)
    off = build_map(osm_file=path, config=RULE_OFF)
    assert _class_at(off, 0.0, 50.0) == "street"
    # Mid-block, between the curbs 1.9 m either side of the middle, is free space now.
    for x_m in (-1.8, 0.0, 1.8):
        assert _class_at(layers, x_m, 50.0) is None
    assert _class_at(layers, 2.2, 50.0) == "street" and _class_at(layers, -2.2, 50.0) == "street"
    freed_m2 = shapely.area(_geoms(off, "street")).sum() - shapely.area(_geoms(layers, "street")).sum()
    # About 4 m x 200 m, less the crosswalk and the junctions at the ends.
    assert 0.8 * 4 * 200 < freed_m2 < 4 * 200
    # The crosswalk across both halves is one polygon that spans the refuge, as it was.
    walks = _geoms(layers, "crosswalk")
    assert len(walks) == 1 and _class_at(layers, 0.0, 0.0) == "crosswalk"
    assert shapely.equals_exact(walks[0], _geoms(off, "crosswalk")[0], 1e-6)
    # No sidewalk enters the median, and the sidewalks are those of the rule off.
    sidewalks, sidewalks_off = _geoms(layers, "sidewalk"), _geoms(off, "sidewalk")
    assert len(sidewalks) == len(sidewalks_off)
    assert shapely.area(sidewalks).sum() == pytest.approx(shapely.area(sidewalks_off).sum(), abs=0.01)
    assert _class_at(layers, 0.0, 20.0) is None


def test_a_narrow_median_keeps_the_parking(tmp_path):
    # Centrelines 7 m apart: without the median-side parking the curbs would be 1 m apart, no refuge.
    path = divided_road(tmp_path / "narrow.osm", 7.0)
    layers = build_map(osm_file=path)
    off = build_map(osm_file=path, config=RULE_OFF)
    assert _class_at(layers, 0.0, 50.0) == "street"
    for cls in ("street", "crosswalk", "sidewalk"):
        assert shapely.area(_geoms(layers, cls)).sum() == pytest.approx(shapely.area(_geoms(off, cls)).sum())
    assert len(_geoms(layers, "crosswalk")) == 1


def test_a_tagged_width_keeps_its_median_side(tmp_path):
    # A measured width is the curb-to-curb width: nothing of it is assumed parking.
    path = divided_road(tmp_path / "tagged.osm", 10.0)
    path.write_text(path.read_text().replace('<tag k="lanes" v="2"/>', '<tag k="width" v="10.4"/>'))
    assert _class_at(build_map(osm_file=path), 0.0, 50.0) == "street"


def test_min_refuge_width_must_not_be_negative():
    with pytest.raises(ValueError, match="min_refuge_width_m"):
        SegmentationConfig(min_refuge_width_m=-1.0)


def test_celler_strasse_opens_no_median():
    # Braunschweig's Celler Straße: one-way `lanes=2` halves 6.5 m apart (centrelines); without the
    # median-side parking they would open a median under 1 m wide, so nothing changes.
    path = Path(__file__).parent / "data" / "osm" / "world" / "braunschweig-celler-strasse.osm"
    layers, off = build_map(osm_file=path), build_map(osm_file=path, config=RULE_OFF)
    for cls in ("street", "crosswalk", "sidewalk"):
        assert shapely.area(_geoms(layers, cls)).sum() == pytest.approx(shapely.area(_geoms(off, cls)).sum())


def test_the_embarcadero_in_the_bundled_extract_opens_its_median_and_nothing_else_moves():
    # By Mission and Howard Streets the Embarcadero's halves run either side of the streetcar median.
    bbox = (-122.3935, 37.7925, -122.3905, 37.7945)
    on, off = build_map(bbox=bbox).gdf, build_map(bbox=bbox, config=RULE_OFF).gdf
    for cls in ("crosswalk", "sidewalk", "building"):
        a, b = on[on["class"] == cls].geometry.values, off[off["class"] == cls].geometry.values
        assert len(a) == len(b) and shapely.union_all(a).equals(shapely.union_all(b))
    opened = shapely.difference(
        shapely.union_all(off[off["class"] == "street"].geometry.values),
        shapely.union_all(on[on["class"] == "street"].geometry.values),
    )
    assert opened.area > 300.0  # m^2 of median become free space, and nothing else:
    assert shapely.intersection(opened, shapely.union_all(on.geometry.values)).area < 0.01
