"""osmseg tag rules, one table at a time: widths, street level, buildings, sidewalk sides."""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely

from curbside.osmseg.buildings import footprint_mask
from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.reader import TAG_KEYS
from curbside.osmseg.sidewalks import extend_shared_ends, split_at_junctions
from curbside.osmseg.streets import carriageway_width, ground_level, sidewalk_sides
from curbside.osmseg.tags import first_number, metres


def table(*rows: dict[str, str]) -> pd.DataFrame:
    """A tag table with every TAG_KEYS column, as the readers produce."""
    return pd.DataFrame([{k: row.get(k) for k in TAG_KEYS} for row in rows], dtype=object)


def test_metres_understands_units_and_rejects_junk():
    values = pd.Series(["7", "7.5 m", "24'", "10 ft", "wide", None, "0", "-3"])
    out = metres(values)
    assert out[:4] == pytest.approx([7.0, 7.5, 24 * 0.3048, 3.048])
    assert np.isnan(out[4:]).all()


def test_first_number_takes_lowest_level():
    out = first_number(pd.Series(["0;1;2", "2.5;3", "-1", None, "roof"]))
    assert out[:3] == pytest.approx([0.0, 2.5, -1.0])
    assert np.isnan(out[3:]).all()


def test_carriageway_width_precedence():
    ways = table(
        {"highway": "residential", "width": "11", "lanes": "4"},
        {"highway": "residential", "lanes": "2", "parking:lane:both": "parallel"},
        {"highway": "residential", "lanes": "2", "parking:lane:both": "no", "cycleway:right": "lane"},
        {"highway": "residential", "lanes:forward": "2", "lanes:backward": "1", "parking:right": "lane"},
        {"highway": "residential", "lanes": "2"},
        {"highway": "service"},
        {"highway": "footway"},
    )
    config = SegmentationConfig()
    width, tagged = carriageway_width(ways, config)
    lane, park = config.lane_width_m, config.parking_width_m["parallel"]
    cycle = config.cycle_lane_width_m
    assert width[0] == 11.0 and tagged[0]
    assert width[1] == pytest.approx(2 * lane + 2 * park)
    assert width[2] == pytest.approx(2 * lane + cycle)
    assert width[3] == pytest.approx(3 * lane + config.parking_width_m["lane"])
    # No parking tag on a street with sidewalks: curbside parking is assumed on both sides.
    assert width[4] == pytest.approx(2 * lane + 2 * config.assumed_parking_width_m)
    assert width[5] == config.default_carriageway_width_m["service"]
    assert np.isnan(width[6])
    assert not tagged[1:].any()
    wider = SegmentationConfig(lane_width_m=3.5, default_carriageway_width_m={"service": 6.0})
    width, _ = carriageway_width(ways, wider)
    assert width[4] == pytest.approx(2 * 3.5 + 2 * wider.assumed_parking_width_m)
    assert width[5] == 6.0
    assert np.isnan(width[6])


@pytest.mark.parametrize(
    "bad",
    [
        {"lane_width_m": 0.0},
        {"crosswalk_overlap_m": -1.0},
        {"parking_width_m": {"parallel": 2.2}},
        {"default_carriageway_width_m": {"residential": "8"}},
        {"sidewalk_highways": "residential"},
        {"unmarked_crossing_as": "footway"},
    ],
)
def test_segmentation_config_rejects_bad_values(bad):
    with pytest.raises(ValueError):
        SegmentationConfig(**bad)


def test_ground_level():
    ways = table(
        {"highway": "footway"},
        {"highway": "footway", "tunnel": "building_passage", "level": "0"},
        {"highway": "footway", "bridge": "yes"},
        {"highway": "footway", "layer": "4", "level": "3"},
        {"highway": "primary", "tunnel": "yes", "layer": "-1"},
        {"highway": "steps", "level": "2;3"},
        {"highway": "busway", "layer": "0", "level": "1"},
    )
    assert ground_level(ways).tolist() == [True, True, False, False, False, False, True]


def test_footprint_rules():
    square = shapely.box(0, 0, 10, 10)
    areas = gpd.GeoDataFrame(
        table(
            {"building": "yes"},
            {"building": "roof"},
            {"building": "carport"},
            {"building": "yes", "location": "underground"},
            {"building": "yes", "layer": "-1"},
            {"building": "transportation", "layer": "-1", "height": "30"},
            {"building": "construction"},
            {"building": "yes", "building:part": "yes"},
        ),
        geometry=[square] * 8,
    )
    assert footprint_mask(areas).tolist() == [True, False, False, False, False, True, True, False]


def test_sidewalk_sides():
    roads = table(
        {"highway": "residential"},
        {"highway": "residential", "sidewalk": "left"},
        {"highway": "residential", "sidewalk": "no"},
        {"highway": "residential", "sidewalk:right": "no"},
        {"highway": "residential", "sidewalk": "separate"},
    )
    left, right = sidewalk_sides(roads)
    assert left.tolist() == [True, True, False, True, True]
    assert right.tolist() == [True, False, False, False, True]


def test_split_at_junctions_and_extend_shared_ends():
    main = shapely.LineString([(0, 0), (50, 0), (100, 0)])
    side = shapely.LineString([(50, 0), (50, 40)])
    roads = gpd.GeoDataFrame({"name": ["main", "side"]}, geometry=[main, side])
    pieces = split_at_junctions(roads, roads.geometry.values)
    assert pieces["road"].tolist() == [0, 0, 1]
    assert pieces["k"].tolist() == [0, 1, 0]
    assert shapely.length(pieces.geometry.values) == pytest.approx([50, 50, 40])
    longer = extend_shared_ends(pieces.geometry.values, np.full(3, 5.0))
    # Only the ends at the junction (50, 0) are prolonged, 5 m straight on.
    assert shapely.length(longer) == pytest.approx([55, 55, 45])
    assert shapely.get_coordinates(longer[0])[-1] == pytest.approx([55, 0])
    assert shapely.get_coordinates(longer[2])[0] == pytest.approx([50, -5])
