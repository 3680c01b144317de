"""benchmarks/diagnose_fusion.py: the along-track sign and the episode runs it reports."""

from __future__ import annotations

import sys
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
from diagnose_fusion import episodes, map_class_at, segment_left, signed_along_m, wrong_kinds  # noqa: E402


def test_episodes_are_the_runs_of_wrong_footsteps():
    wrong = np.array([True, True, False, False, True, False, True, True, True])
    assert episodes(wrong) == [(0, 2), (4, 5), (6, 9)]
    assert episodes(np.zeros(4, bool)) == []


def test_along_is_negative_behind_the_walker_and_undefined_while_standing():
    t = np.arange(0.0, 20.0, 0.5)
    gx = np.where(t < 10, 1.3 * t, 13.0)  # walks east, then stands
    track = pd.DataFrame({"t": t, "gt_x_m": gx, "gt_y_m": 0.0, "x_m": gx - 2.0, "y_m": 3.0})
    along = signed_along_m(track)
    np.testing.assert_allclose(along[1:18], -2.0)  # 2 m behind; the 3 m across does not count
    assert np.isnan(along[22:]).all()


def test_map_class_is_the_polygon_under_each_point_and_free_elsewhere():
    classes = gpd.GeoDataFrame(
        {"class": ["sidewalk", "street", "building"]},
        geometry=[shapely.box(0, 0, 10, 3), shapely.box(0, 3, 10, 15), shapely.box(0, -10, 10, 0)],
    )
    x = np.array([5.0, 5.0, 5.0, 20.0])
    y = np.array([1.5, 9.0, -5.0, 1.0])
    assert map_class_at(classes, x, y).tolist() == ["sidewalk", "street", "building", "free"]
    assert map_class_at(classes, np.empty(0), np.empty(0)).tolist() == []


def test_wrong_footsteps_left_behind_at_a_change_and_flickers_are_told_apart():
    # The walker goes A -> B at footstep 4; the estimate stays on A for two footsteps (left behind),
    # then flickers to C for two footsteps while the walker stays on B.
    gt = ["A", "A", "A", "A", "B", "B", "B", "B", "B", "B", "B"]
    est = ["A", "A", "A", "A", "A", "A", "B", "C", "C", "B", "B"]
    errors = pd.DataFrame({"gt_segment": gt, "est_segment": est,
                           "correct": [g == e for g, e in zip(gt, est, strict=True)], "missing": False})
    left = segment_left(errors["gt_segment"])
    assert left.iloc[:4].isna().all() and (left.iloc[4:] == "A").all()
    left_behind, flicker = wrong_kinds(errors)
    assert np.flatnonzero(left_behind).tolist() == [4, 5]
    assert np.flatnonzero(flicker).tolist() == [7, 8]
    # The lag spans the change, so it is not a flicker; a missing footstep is neither.
    errors.loc[7, "missing"] = True
    left_behind, flicker = wrong_kinds(errors)
    assert np.flatnonzero(flicker).tolist() == [8]
