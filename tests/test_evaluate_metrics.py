"""Ground truth and the paper's metrics on hand-drawn maps with hand-computed answers."""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely

from curbside.errors import CurbsideInputError
from curbside.evaluate import metrics
from curbside.evaluate.groundtruth import groundtruth_at
from curbside.osmseg.mapio import MapLayers
from curbside.projection import LocalFrame

FRAME = LocalFrame.around(-122.4, 37.79)


def _layers(rows: list[tuple[str, str | None, shapely.Geometry]]) -> MapLayers:
    gdf = gpd.GeoDataFrame(
        {
            "class": [r[0] for r in rows],
            "segment_id": [r[1] for r in rows],
            "street": [None] * len(rows),
            "side": [None] * len(rows),
        },
        geometry=[r[2] for r in rows],
        crs=FRAME.crs,
    )
    return MapLayers(gdf, {"source": "test"})


def _straight_street() -> MapLayers:
    """A street along x (y in [-5, 5]) with a sidewalk each side, and a crosswalk at x in [48, 52]."""
    return _layers(
        [
            ("street", None, shapely.box(0, -5, 100, 5)),
            ("crosswalk", None, shapely.box(48, -5, 52, 5)),
            ("sidewalk", "N", shapely.box(0, 5, 100, 8)),
            ("sidewalk", "S", shapely.box(0, -8, 100, -5)),
            ("sidewalk", "N2", shapely.box(120, 5, 200, 8)),
        ]
    )


def _corner() -> MapLayers:
    """An L-shaped corner: segment A along x, segment B along y."""
    return _layers(
        [
            ("sidewalk", "A", shapely.box(0, 0, 47, 3)),
            ("sidewalk", "B", shapely.box(47, 3, 50, 50)),
        ]
    )


def test_groundtruth_interpolates_at_constant_speed_and_clamps():
    lon, lat = FRAME.to_lonlat(np.array([0.0, 10.0, 10.0]), np.array([0.0, 0.0, 10.0]))
    x0, y0 = FRAME.to_xy(lon[:1], lat[:1])
    wp = pd.DataFrame({"t": [0.0, 10.0, 20.0], "lat": lat, "lon": lon})
    x, y = groundtruth_at(wp, np.array([-1.0, 5.0, 15.0, 25.0]), FRAME)
    np.testing.assert_allclose(x - x0, [0, 5, 10, 10], atol=1e-6)
    np.testing.assert_allclose(y - y0, [0, 0, 5, 10], atol=1e-6)


def test_groundtruth_needs_two_waypoints():
    with pytest.raises(CurbsideInputError, match="two waypoints"):
        groundtruth_at(pd.DataFrame({"t": [0.0], "lat": [37.79], "lon": [-122.4]}), np.array([0.0]), FRAME)


def test_long_axes_follow_the_segment():
    index = metrics.SidewalkIndex.from_layers(_corner())
    np.testing.assert_allclose(np.abs(index.axis), [[1, 0], [0, 1]], atol=1e-9)


def test_a_short_corner_piece_takes_its_street_from_facing_deg_not_its_long_axis():
    # A piece 3 m along its street (x) and 6 m deep: its long axis is the cross street's (y).
    layers = _layers([("sidewalk", "P", shapely.box(0, 5, 3, 11)),
                      ("sidewalk", "Q", shapely.box(10, 5, 13, 11))])
    layers.gdf["facing_deg"] = [0.0, np.nan]  # P north of its street; Q drawn by hand, no bearing
    index = metrics.SidewalkIndex.from_layers(layers)
    np.testing.assert_allclose(np.abs(index.axis), [[1, 0], [0, 1]], atol=1e-9)
    errs = metrics.step_errors(np.array([[1.5, 6.0]]), np.array([[1.5, 9.0]]), index)
    assert errs["across_m"].tolist() == pytest.approx([3.0])
    assert errs["along_m"].tolist() == pytest.approx([0.0])


def test_straight_street_wrong_sidewalk():
    index = metrics.SidewalkIndex.from_layers(_straight_street())
    gt = np.array([[50.0, 6.5], [20.0, 6.5]])
    est = np.array([[53.0, -6.5], [24.0, 7.5]])
    errs = metrics.step_errors(est, gt, index)
    # step 1: error (3, -13) -> euclid sqrt(178), along 3, across 13, opposite sidewalk
    # step 2: error (4, 1) -> euclid sqrt(17), along 4, across 1, same sidewalk
    np.testing.assert_allclose(errs["euclid_m"], [np.sqrt(178), np.sqrt(17)])
    np.testing.assert_allclose(errs["along_m"], [3, 4])
    np.testing.assert_allclose(errs["across_m"], [13, 1])
    assert errs["correct"].tolist() == [False, True]
    summary = metrics.summarize(errs)
    assert summary["csa"] == 0.5
    assert summary["euclid_mean_m"] == pytest.approx((np.sqrt(178) + np.sqrt(17)) / 2)
    assert summary["along_median_m"] == pytest.approx(3.5)
    assert summary["across_median_m"] == pytest.approx(7.0)
    assert summary["across_p90_m"] == pytest.approx(1 + 0.9 * 12)
    assert list(summary)[: len(metrics.METRIC_NAMES)] == list(metrics.METRIC_NAMES)


def test_corner_decomposes_against_the_street_at_the_ground_truth():
    index = metrics.SidewalkIndex.from_layers(_corner())
    gt = np.array([[48.5, 20.0], [48.5, 20.0]])
    est = np.array([[30.0, 1.5], [48.5, 10.0]])
    errs = metrics.step_errors(est, gt, index)
    # GT on B (a north-south segment): along = |dy|, across = |dx|
    np.testing.assert_allclose(errs["along_m"], [18.5, 10.0])
    np.testing.assert_allclose(errs["across_m"], [18.5, 0.0], atol=1e-9)
    assert errs["est_segment"].tolist() == ["A", "B"]
    assert errs["correct"].tolist() == [False, True]


def test_crossing_counts_the_segments_it_joins():
    index = metrics.SidewalkIndex.from_layers(_straight_street())
    gt = np.array([[50.0, 0.0]] * 3)  # mid-crosswalk, 5 m from both kerbs
    est = np.array([[50.0, -6.0], [50.0, 6.0], [150.0, 6.0]])
    errs = metrics.step_errors(est, gt, index)
    assert errs["on_crossing"].all()
    assert errs["correct"].tolist() == [True, True, False]
    assert metrics.summarize(errs)["n_crossing_steps"] == 3


def test_crossing_rule_distances_come_from_the_config():
    index = metrics.SidewalkIndex.from_layers(_straight_street())
    gt = np.array([[50.0, 2.0]] * 2)  # on the crosswalk, 3 m from the north kerb and 7 m from the south one
    est = np.array([[50.0, -6.5], [50.0, 6.5]])
    assert metrics.step_errors(est, gt, index)["correct"].tolist() == [True, True]
    tight = metrics.step_errors(est, gt, index, metrics.MetricsConfig(crossing_slack_m=2.0))
    assert tight["correct"].tolist() == [False, True]  # the south kerb is 4 m farther than the north one
    near = metrics.step_errors(est, gt, index, metrics.MetricsConfig(on_sidewalk_m=3.5))
    assert not near["on_crossing"].any() and near["correct"].tolist() == [False, True]
    with pytest.raises(ValueError, match="rte_window_s"):
        metrics.MetricsConfig(rte_window_s=0.0)


def test_missing_estimates_count_as_wrong_and_are_left_out_of_distances():
    index = metrics.SidewalkIndex.from_layers(_straight_street())
    gt = np.array([[50.0, 6.5], [60.0, 6.5]])
    est = np.array([[np.nan, np.nan], [62.0, 6.5]])
    summary = metrics.summarize(metrics.step_errors(est, gt, index))
    assert summary["csa"] == 0.5
    assert summary["euclid_mean_m"] == pytest.approx(2.0)
    assert summary["n_missing"] == 1


def test_map_without_sidewalks_is_refused():
    layers = _layers([("building", None, shapely.box(0, 0, 10, 10))])
    with pytest.raises(CurbsideInputError, match="no sidewalk"):
        metrics.SidewalkIndex.from_layers(layers)


def test_ate_and_rte_hand_computed():
    t = np.arange(0.0, 121.0)
    gt = np.column_stack([t * 1.2, np.zeros_like(t)])
    shifted = gt + [3.0, 4.0]
    assert metrics.ate_m(shifted, gt) == pytest.approx(5.0)
    assert metrics.rte_m(t, shifted, gt) == pytest.approx(0.0)
    drifting = gt + np.column_stack([0.1 * t, np.zeros_like(t)])
    assert metrics.rte_m(t, drifting, gt, window_s=60.0) == pytest.approx(6.0)
    # shorter than the window: the end-point error scaled to the window
    assert metrics.rte_m(t[:31], drifting[:31], gt[:31], window_s=60.0) == pytest.approx(6.0)
