"""The report figures: every particle cloud visible, the GNSS fix labelled beside its circle, the share
of errors beyond the CDF's axis, and the reliability figure's labels and room at probability 1."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from matplotlib.collections import PathCollection

from curbside.evaluate.figures import (
    CDF_MAX_M,
    FIX_COLOR,
    METHOD_COLORS,
    fig_cdf,
    fig_particles,
    fig_reliability,
)
from curbside.evaluate.runner import METHOD_LABELS

BASE = {"map": "osm", "jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}
FILTERS = ("inertial", "paper", "fused")


def _spec(method: str) -> dict:
    return {"method": method, "map_name": "osm", "jaywalk_weight": 0.4, "particles": 500,
            "gnss_sigma_factor": None}


def _particle_runs() -> list[dict]:
    rng = np.random.default_rng(0)
    track = pd.DataFrame({"t": [0.0, 10.0, 20.0], "gt_x_m": [0.0, 5.0, 10.0], "gt_y_m": [0.0, 0.0, 0.0]})
    runs = []
    for method in FILTERS:  # every cloud on the same spot: drawn together, the last would hide the others
        snaps = [{"t": t, "x": rng.normal(x, 3, 200), "y": rng.normal(0, 3, 200), "fix": (x + 2, 1.0, 8.0)}
                 for t, x in ((0.0, 0.0), (20.0, 10.0))]
        runs.append({"session": "s1", "spec": _spec(method), "track": track, "snapshots": snaps})
    return runs


def test_particles_each_method_in_its_own_panel_on_the_same_window():
    fig = fig_particles(_particle_runs(), None, BASE)
    axes = np.array(fig.axes).reshape(2, 3)
    for row in axes:
        assert len({ax.get_xlim() for ax in row}) == 1  # a row shares its window
        for ax, method in zip(row, FILTERS, strict=True):
            clouds = [c for c in ax.collections if isinstance(c, PathCollection)]
            assert len(clouds) == 1 and len(clouds[0].get_offsets()) == 200
            assert np.allclose(clouds[0].get_facecolor()[0][:3], _rgb(METHOD_COLORS[method]))
    assert [ax.get_title() for ax in axes[0]] == [METHOD_LABELS[m] for m in FILTERS]


def test_the_fix_label_sits_beside_its_circle_with_a_halo():
    fig = fig_particles(_particle_runs(), None, BASE)
    ax = fig.axes[0]
    circle = next(p for p in ax.patches if hasattr(p, "radius"))
    label = next(t for t in ax.texts if t.get_text().startswith("GNSS fix"))
    x, y = label.get_position()
    assert label.get_text() == "GNSS fix\n\u00b18 m"
    assert abs(x - circle.center[0]) >= circle.radius and y == pytest.approx(circle.center[1])
    assert label.get_path_effects() and label.get_zorder() > 3  # above the particles, haloed
    assert np.allclose(circle.get_facecolor()[:3], _rgb(FIX_COLOR))


def _rgb(colour: str) -> np.ndarray:
    from matplotlib.colors import to_rgb

    return np.array(to_rgb(colour))


def test_cdf_says_how_much_of_each_curve_lies_beyond_the_axis():
    errors = {"gnss": np.r_[np.full(9, 5.0), 80.0], "fused": np.full(10, 3.0)}
    runs = [{"spec": _spec(m), "errors": pd.DataFrame({"euclid_m": e, "missing": False})}
            for m, e in errors.items()]
    ax = fig_cdf(runs, BASE).axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == [f"GNSS (10 % > {CDF_MAX_M:g} m)", f"curbside fused (0 % > {CDF_MAX_M:g} m)"]
    assert ax.get_xlim()[1] == CDF_MAX_M and f"cut at {CDF_MAX_M:g} m" in ax.get_xlabel()


def test_reliability_names_the_calibration_error_the_068_line_and_keeps_markers_at_1():
    curve = [{"claimed": c, "held": h} for c, h in ((0.5, 0.6), (0.68, 0.8), (0.95, 1.0))]
    rows = [{"subset": None, "method": "fused", "footsteps": 100, "calibration_error": 0.282,
             "bins": [{"mean_prob": 0.5, "share_right": 0.4, "footsteps": 10},
                      {"mean_prob": 1.0, "share_right": 1.0, "footsteps": 90}],
             "accuracy_curve": curve, "accuracy_coverage": 0.8, "accuracy_median_m": 4.0}]
    top, bottom = fig_reliability(rows, BASE).axes
    labels = [t.get_text() for t in top.get_legend().get_texts()]
    assert "curbside fused (calibration error 0.282)" in labels
    assert top.get_xlim()[1] > 1.02 and top.get_ylim()[1] > 1.02  # room for the largest marker at 1
    assert not next(c for c in top.collections if isinstance(c, PathCollection)).get_clip_on()
    line = next(x for x in bottom.lines if list(x.get_xdata()) == [0.68, 0.68])
    assert "0.68" in line.get_label() and line.get_label() in [
        t.get_text() for t in bottom.get_legend().get_texts()]
