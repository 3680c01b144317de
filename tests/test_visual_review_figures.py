"""What a reader sees in the report figures: method colours that stay apart for colour-blind readers, a
particle cloud off its panel named there, panel titles clear of the panel above, the reliability
figure's legends clear of the titles below, and the jaywalk weight named in the titles."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import to_rgb

from curbside.evaluate import figures
from curbside.evaluate.figures import config_label, fig_particles, fig_reliability, fig_tracks
from curbside.localize import view
from curbside.osmseg.style import GNSS_FIX_COLOUR, METHOD_COLOURS

BASE = {"map": "osm", "jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}

# Machado, Oliveira and Fernandes (2009), severity 1: linear-RGB simulation of dichromacy.
DICHROMACY = {
    "deuteranopia": np.array([[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413],
                              [-0.011820, 0.042940, 0.968881]]),
    "protanopia": np.array([[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216],
                            [-0.003882, -0.048116, 1.051998]]),
}
#: CIE76 colour difference below which two thin lines or small dots are hard to tell apart.
MIN_DELTA_E = 20.0


def _lab(linear_rgb: np.ndarray) -> np.ndarray:
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    x = xyz @ np.clip(linear_rgb, 0, 1) / np.array([0.95047, 1.0, 1.08883])
    f = np.where(x > 0.008856, np.cbrt(x), 7.787 * x + 16 / 116)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def _seen(colour: str, matrix: np.ndarray) -> np.ndarray:
    srgb = np.array(to_rgb(colour))
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    return _lab(matrix @ linear)


@pytest.mark.parametrize("kind", sorted(DICHROMACY))
def test_method_colours_stay_apart_for_colour_blind_readers(kind):
    colours = {**METHOD_COLOURS, "GNSS fixes": GNSS_FIX_COLOUR}
    seen = {name: _seen(c, DICHROMACY[kind]) for name, c in colours.items()}
    for a, b in itertools.combinations(colours, 2):
        assert np.linalg.norm(seen[a] - seen[b]) >= MIN_DELTA_E, (kind, a, b)


def test_figures_and_replay_pages_share_one_palette():
    assert figures.METHOD_COLORS is METHOD_COLOURS and figures.FIX_COLOR == GNSS_FIX_COLOUR
    assert view.METHOD_COLOURS is METHOD_COLOURS
    assert not set(view.EXTRA_COLOURS) & {*METHOD_COLOURS.values(), GNSS_FIX_COLOUR}


def _spec(method: str) -> dict:
    return {"method": method, "map_name": "osm", "jaywalk_weight": 0.4, "particles": 500,
            "gnss_sigma_factor": None}


def test_a_cloud_off_its_panel_is_named_in_it():
    rng = np.random.default_rng(0)
    track = pd.DataFrame({"t": [0.0, 10.0], "gt_x_m": [0.0, 5.0], "gt_y_m": [0.0, 0.0]})
    offsets = {"inertial": 120.0, "fused": 0.0}  # RoNIN+PF's cloud 120 m east: off a 90 m panel
    runs = [{"session": "s1", "spec": _spec(m), "track": track,
             "snapshots": [{"t": 0.0, "x": rng.normal(dx, 2, 100), "y": rng.normal(0, 2, 100)}]}
            for m, dx in offsets.items()]
    off, on = fig_particles(runs, None, BASE).axes
    notes = [t.get_text() for t in off.texts]
    assert any(n.startswith("cloud 120 m away") and "off the panel" in n for n in notes), notes
    assert not [t for t in on.texts if t.get_text().startswith("cloud")]


def test_panel_titles_keep_clear_of_the_panel_above():
    t = np.linspace(0, 100, 20)
    track = pd.DataFrame({"t": t, "gt_x_m": t, "gt_y_m": 0.5 * t, "x_m": t, "y_m": 0.5 * t})
    runs = [{"path": f"path{k}", "session": f"path{k}-s1", "track": track, "spec": _spec("gnss")}
            for k in range(1, 7)]
    fig = fig_tracks(runs, None, BASE)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    axes = np.array(fig.axes).reshape(2, 3)
    for upper, lower in zip(axes[0], axes[1], strict=True):
        gap_px = upper.get_window_extent(renderer).y0 - lower.title.get_window_extent(renderer).y1
        assert gap_px >= 4.0


def test_reliability_legends_keep_clear_of_the_titles_below():
    curve = [{"claimed": c, "held": h} for c, h in ((0.5, 0.6), (0.68, 0.8), (0.95, 1.0))]
    rows = [{"subset": subset, "method": m, "footsteps": 100, "calibration_error": 0.1,
             "bins": [{"mean_prob": 0.5, "share_right": 0.4, "footsteps": 10},
                      {"mean_prob": 1.0, "share_right": 1.0, "footsteps": 90}],
             "accuracy_curve": curve, "accuracy_coverage": 0.8, "accuracy_median_m": 4.0}
            for subset in ("paper6", "downtown", "open") for m in ("inertial", "paper", "fused")]
    fig = fig_reliability(rows, BASE)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    axes = np.array(fig.axes).reshape(2, 3)
    for upper, lower in zip(axes[0], axes[1], strict=True):
        legend = upper.get_legend().get_window_extent(renderer)
        assert legend.y0 > lower.title.get_window_extent(renderer).y1


def test_figure_titles_name_the_jaywalk_weight():
    assert config_label(BASE) == "jaywalk weight w = 0.4, map 'osm'"
