"""The report figures: the paper's Figs. 1, 3, 4 and 5, and the benchmark's per-session comparison.

Every figure shows the four methods in the same colours (:data:`METHOD_COLORS`, those of the replay
pages, apart for colour-blind readers too). Map figures draw
the map classes with a legend, a scale bar and the map's attribution ("© OpenStreetMap
contributors"); figures of one configuration say which jaywalk weight and which map they show.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib import patheffects  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.text import Text  # noqa: E402
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar  # noqa: E402

from curbside import settings  # noqa: E402
from curbside.evaluate.runner import METHOD_LABELS, METHODS  # noqa: E402
from curbside.localize.filter.calibration import TAIL_DOF  # noqa: E402
from curbside.osmseg.mapio import MapLayers  # noqa: E402
from curbside.osmseg.style import GNSS_FIX_COLOUR, METHOD_COLOURS  # noqa: E402

#: One colour per method, in every figure (:data:`curbside.osmseg.style.METHOD_COLOURS`).
METHOD_COLORS = METHOD_COLOURS
#: Light fills of the map classes under the tracks (drawn bottom to top in this order).
CLASS_COLORS = {"street": "#a9adb8", "crosswalk": "#f2e394", "sidewalk": "#bfe3b4", "building": "#c9a0a0"}
CLASS_LABELS = {
    "street": "street (jaywalking)",
    "crosswalk": "crosswalk",
    "sidewalk": "sidewalk segment",
    "building": "building",
}


def attribution(layers: MapLayers | None) -> str:
    """The map's attribution line (OSM's by default)."""
    meta = layers.meta if layers is not None else {}
    return str(meta.get("attribution") or settings.osm_attribution)


#: Room (pixels at the figure's dpi) kept between a title wrapped to fit and the figure's side.
TITLE_MARGIN_PX = 8.0


def _wrap_to_width(text: Text, width_px: float) -> bool:
    """Break ``text`` at spaces into the fewest lines no wider than ``width_px`` (a word wider than that
    stays whole); whether it was wider."""
    renderer = text.figure.canvas.get_renderer()
    if text.get_window_extent(renderer).width <= width_px:
        return False
    lines = text.get_text().splitlines()
    longest_word = max(len(word) for line in lines for word in line.split() or [""])
    for chars in range(max(map(len, lines)) - 1, max(longest_word, 1) - 1, -1):
        text.set_text("\n".join(textwrap.fill(line, chars, break_long_words=False) for line in lines))
        if text.get_window_extent(renderer).width <= width_px:
            break
    return True


def _suptitle(fig: plt.Figure, title: str, **kwargs: Any) -> None:
    """``fig.suptitle(title, **kwargs)``, wrapped to the figure's width (a long map name no longer cuts
    the title off at both sides)."""
    _wrap_to_width(fig.suptitle(title, **kwargs), fig.bbox.width - 2 * TITLE_MARGIN_PX)


def _fit_axes_titles(fig: plt.Figure) -> bool:
    """Wrap every axes title that runs past a side of the figure, where the axes are now; whether one
    was wrapped."""
    width = fig.bbox.width
    wrapped = False
    for ax in fig.axes:
        if not (ax.get_visible() and ax.title.get_text()):
            continue
        centre = (ax.get_position().x0 + ax.get_position().x1) / 2 * width
        wrapped |= _wrap_to_width(ax.title, 2 * min(centre, width - centre) - 2 * TITLE_MARGIN_PX)
    return wrapped


def _tight_layout_fitted(fig: plt.Figure, **kwargs: Any) -> None:
    """``fig.tight_layout(**kwargs)`` with the axes titles wrapped to fit where it puts the axes (laid out
    again when one was wrapped, for the height it gained)."""
    fig.tight_layout(**kwargs)
    if _fit_axes_titles(fig):
        fig.tight_layout(**kwargs)


def _nice_length(max_m: float) -> float:
    """The largest 1, 2 or 5 x 10^k metres not above ``max_m``."""
    power = 10.0 ** math.floor(math.log10(max_m))
    return max(m * power for m in (1, 2, 5) if m * power <= max_m)


def draw_map(ax: plt.Axes, layers: MapLayers | None, bounds: tuple[float, float, float, float]) -> None:
    """Map classes inside ``bounds`` (local metres), a scale bar and the attribution on ``ax``."""
    x0, y0, x1, y1 = bounds
    if layers is not None:
        sub = layers.gdf.cx[x0:x1, y0:y1]
        for cls, color in CLASS_COLORS.items():
            part = sub[sub["class"] == cls]
            if len(part):
                part.plot(ax=ax, color=color, edgecolor="white", linewidth=0.2, zorder=0)
        ax.text(
            0.99,
            0.005,
            attribution(layers),
            transform=ax.transAxes,
            ha="right",
            va="bottom",
            fontsize=6,
            color="0.25",
            bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none", "pad": 1},
            zorder=11,
        )
    length = _nice_length((x1 - x0) / 5)
    label = f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m"
    bar = AnchoredSizeBar(
        ax.transData,
        length,
        label,
        "lower left",
        pad=0.4,
        borderpad=0.6,
        sep=3,
        frameon=True,
        size_vertical=(y1 - y0) / 150,
        fontproperties={"size": 7},
    )
    bar.patch.set_alpha(0.75)
    ax.add_artist(bar)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlabel("")
    ax.set_ylabel("")


def class_handles(layers: MapLayers | None) -> list[Patch]:
    """Legend patches of the map classes present in ``layers``."""
    if layers is None:
        return []
    present = set(layers.gdf["class"].unique())
    return [Patch(facecolor=CLASS_COLORS[c], label=CLASS_LABELS[c]) for c in CLASS_COLORS if c in present]


def _method_handles(methods: list[str], marker_size: float = 6.0) -> list:
    return [
        plt.Line2D([], [], ls="", marker="o", ms=marker_size, color=METHOD_COLORS[m], label=METHOD_LABELS[m])
        for m in methods
    ]


def config_label(base: dict[str, Any]) -> str:
    """``jaywalk weight w = 0.4, map 'osm'``: which configuration a figure shows (``w`` as in the
    report's tables)."""
    return f"jaywalk weight w = {base['jaywalk_weight']:g}, map '{base['map']}'"


def is_base(result: dict, base: dict[str, Any]) -> bool:
    """Whether a run is at the base configuration (GNSS: only the map matters).

    ``base["particles"]`` is one particle count for every method, or a mapping from method to its count
    (the benchmark suite runs curbside fused with more particles than the paper's method).
    """
    spec = result["spec"]
    if spec["method"] == "gnss":
        return spec["map_name"] == base["map"]
    particles = base["particles"]
    if isinstance(particles, dict):
        particles = particles.get(spec["method"])
    return (
        spec["map_name"] == base["map"]
        and spec["jaywalk_weight"] == base["jaywalk_weight"]
        and spec["particles"] == particles
        and spec["gnss_sigma_factor"] == base["gnss_sigma_factor"]
    )


def fig_tracks(
    results: list[dict],
    layers: MapLayers | None,
    base: dict[str, Any],
    title: str = "Fig. 1  Tracks per path",
    max_panels: int = 9,
) -> plt.Figure:
    """Fig. 1: ground truth and every method's footsteps over the map, one panel per path.

    The first session of each path is drawn (at most ``max_panels`` paths).
    """
    first: dict[str, str] = {}
    for r in results:
        first.setdefault(r["path"], r["session"])
    paths = list(first)[:max_panels]
    cols = min(3, len(paths))
    rows = math.ceil(len(paths) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.5 * cols, 5.2 * rows + 0.8), squeeze=False)
    shown: list[str] = []
    for ax, path in zip(axes.ravel(), paths, strict=False):
        runs = [r for r in results if r["session"] == first[path] and is_base(r, base)]
        tracks = {r["spec"]["method"]: r["track"] for r in runs}
        gt = next(iter(tracks.values()))
        # a square around the walk, 40 m beyond it: every panel the same shape
        cx = (gt["gt_x_m"].min() + gt["gt_x_m"].max()) / 2
        cy = (gt["gt_y_m"].min() + gt["gt_y_m"].max()) / 2
        half = max(np.ptp(gt["gt_x_m"]), np.ptp(gt["gt_y_m"])) / 2 + 40
        bounds = (cx - half, cy - half, cx + half, cy + half)
        draw_map(ax, layers, bounds)
        ax.plot(gt["gt_x_m"], gt["gt_y_m"], color="0.3", lw=2, zorder=2)
        for m in METHODS:
            if m in tracks:
                tr = tracks[m]
                ax.scatter(tr["x_m"], tr["y_m"], s=3, color=METHOD_COLORS[m], zorder=3)
                shown.append(m)
        ax.set_title(f"{path} ({first[path]})", fontsize=10)
    for ax in axes.ravel()[len(paths) :]:
        ax.axis("off")
    handles = [plt.Line2D([], [], color="0.3", lw=2, label="ground truth")]
    handles += _method_handles([m for m in METHODS if m in shown]) + class_handles(layers)
    ncol = min(len(handles), 3 if cols == 1 else 5)
    fig.legend(handles=handles, loc="lower center", ncol=ncol, fontsize=8, frameon=False)
    _suptitle(fig, f"{title} ({config_label(base)})")
    legend_in = 0.22 * math.ceil(len(handles) / ncol) + 0.15
    # h_pad: room between a panel and the title of the one below, so that each title reads as its own
    _tight_layout_fitted(fig, rect=(0, legend_in / fig.get_figheight(), 1, 1), h_pad=2.0)
    return fig


#: Colour of the GNSS fix and its accuracy circle in Fig. 3.
FIX_COLOR = GNSS_FIX_COLOUR
#: Half the side of a Fig. 3 panel (m), around the ground truth.
PARTICLE_PANEL_HALF_M = 45.0


def _fix_marker(ax: plt.Axes, fix: tuple[float, float, float], bounds: tuple[float, ...]) -> None:
    """A GNSS fix, its accuracy circle and its label beside the circle (left of it near the right edge;
    beside the dot when the circle is wider than a third of the panel), with a white halo."""
    x, y, r = fix
    x0, _, x1, _ = bounds
    ax.add_patch(plt.Circle((x, y), r, color=FIX_COLOR, alpha=0.15, zorder=1))
    ax.plot(x, y, "o", color=FIX_COLOR, ms=8, zorder=4)
    gap = (r if r < (x1 - x0) / 3 else 0.0) + 0.02 * (x1 - x0)
    right = x + gap + 0.22 * (x1 - x0) <= x1
    ax.text(
        x + gap if right else x - gap, y, f"GNSS fix\n\u00b1{r:.0f} m", fontsize=7, color="#0d3d66",
        ha="left" if right else "right", va="center", zorder=6, clip_on=True,
        path_effects=[patheffects.withStroke(linewidth=3, foreground="white")],
    )


def _cloud_off_panel(
    ax: plt.Axes, x: np.ndarray, y: np.ndarray, truth: tuple[float, float], bounds: tuple[float, ...],
    color: str,
) -> None:
    """When no particle of a cloud lies in the panel, say so in it, and how far its mean is from the
    ground truth: an empty panel would read as a missing run."""
    x0, y0, x1, y1 = bounds
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) == 0 or np.any((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)):
        return
    away_m = float(np.hypot(np.mean(x) - truth[0], np.mean(y) - truth[1]))
    ax.text(
        0.5, 0.82, f"cloud {away_m:.0f} m away,\noff the panel", transform=ax.transAxes, fontsize=8,
        color=color, fontweight="bold", ha="center", va="center", zorder=6,
        path_effects=[patheffects.withStroke(linewidth=3, foreground="white")],
    )


def fig_particles(results: list[dict], layers: MapLayers | None, base: dict[str, Any]) -> plt.Figure | None:
    """Fig. 3: particle clouds of every particle-filter method at the chosen moments of one session.

    One row per moment, one column per method, every panel of a row the same square around the ground
    truth: no cloud hides another. The GNSS fix of the moment is in every panel of its row; a cloud with
    no particle in its panel is named there, with its distance.
    """
    runs = [r for r in results if r["snapshots"]]
    if not runs:
        return None
    session = runs[0]["session"]
    by_method = {}
    for r in runs:
        if r["session"] == session:
            by_method.setdefault(r["spec"]["method"], r)
    methods = [m for m in METHODS if m in by_method]
    first = by_method[methods[0]]
    n = len(first["snapshots"])
    half = PARTICLE_PANEL_HALF_M
    # at least two panels wide: room for the title and the legend's four columns over one method's panel
    fig, axes = plt.subplots(n, len(methods), figsize=(4.0 * max(len(methods), 2), 4.1 * n + 0.95),
                             squeeze=False)
    gt_track = first["track"]
    for k in range(n):
        snap0 = first["snapshots"][k]
        i = int(np.argmin(np.abs(gt_track["t"].to_numpy() - snap0["t"])))
        cx, cy = gt_track["gt_x_m"].iat[i], gt_track["gt_y_m"].iat[i]
        bounds = (cx - half, cy - half, cx + half, cy + half)
        fix = snap0.get("fix")
        for ax, m in zip(axes[k], methods, strict=True):
            draw_map(ax, layers, bounds)
            snap = by_method[m]["snapshots"][k]
            ax.scatter(snap["x"], snap["y"], s=3, alpha=0.6, color=METHOD_COLORS[m], linewidths=0, zorder=3)
            _cloud_off_panel(ax, snap["x"], snap["y"], (cx, cy), bounds, METHOD_COLORS[m])
            if fix is not None:
                _fix_marker(ax, fix, bounds)
            ax.plot(cx, cy, "k*", ms=11, zorder=5)
            if k == 0:
                ax.set_title(METHOD_LABELS[m], fontsize=10, color=METHOD_COLORS[m], fontweight="bold")
        row = f"t = {snap0['t']:.0f} s"
        if fix is not None and max(abs(fix[0] - cx), abs(fix[1] - cy)) > half:
            row += f"\nGNSS fix {np.hypot(fix[0] - cx, fix[1] - cy):.0f} m away, off the panel"
        axes[k][0].set_ylabel(row, fontsize=9)
    fix_handle = plt.Line2D([], [], ls="", marker="o", ms=9, color=FIX_COLOR,
                            label="GNSS fix (circle: reported accuracy)")
    truth = plt.Line2D([], [], ls="", marker="*", ms=12, color="k", label="ground truth")
    handles = [*_method_handles(methods), fix_handle, truth, *class_handles(layers)]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, frameon=False)
    _suptitle(fig, f"Fig. 3  Particle clouds, {session} ({config_label(base)})")
    _tight_layout_fitted(fig, rect=(0, 0.75 / fig.get_figheight(), 1, 1))
    return fig


#: Fig. 4's error axis ends here (m); the share of each method's footsteps beyond it is in the legend.
CDF_MAX_M = 60.0


def _beyond(errors_m: np.ndarray, limit_m: float) -> str:
    """``"10 % > 60 m"``: the share of ``errors_m`` beyond the axis (``"<1 %"`` for a few)."""
    share = 100 * float(np.mean(errors_m > limit_m)) if len(errors_m) else 0.0
    return f"{'<1' if 0 < share < 0.5 else f'{share:.0f}'} % > {limit_m:g} m"


def _cdf_axes(ax, results: list[dict], base: dict[str, Any], title: str) -> None:
    for m in METHODS:
        errs = [r["errors"] for r in results if r["spec"]["method"] == m and is_base(r, base)]
        if not errs:
            continue
        e = pd.concat(errs)
        e = np.sort(e.loc[~e["missing"], "euclid_m"].to_numpy())
        label = f"{METHOD_LABELS[m]} ({_beyond(e, CDF_MAX_M)})"
        ax.plot(e, np.arange(1, len(e) + 1) / len(e), color=METHOD_COLORS[m], label=label)
    ax.set_xlabel(f"Euclidean error (m; axis cut at {CDF_MAX_M:g} m)")
    ax.set_ylabel("CDF")
    ax.set_xlim(0, CDF_MAX_M)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right", title=f"method (share beyond {CDF_MAX_M:g} m)",
              title_fontsize=8)
    ax.set_title(title, fontsize=10)


def fig_cdf(
    results: list[dict], base: dict[str, Any], groups: dict[str, list[dict]] | None = None
) -> plt.Figure:
    """Fig. 4: CDF of the Euclidean error over all footsteps, per method (one panel per group)."""
    groups = groups or {"all sessions": results}
    fig, axes = plt.subplots(1, len(groups), figsize=(6.0 * len(groups), 4.6), squeeze=False)
    for ax, (name, group) in zip(axes.ravel(), groups.items(), strict=True):
        _cdf_axes(ax, group, base, name)
    _suptitle(fig, f"Fig. 4  Euclidean error CDF ({config_label(base)})")
    _tight_layout_fitted(fig)
    return fig


def fig_per_path(
    pooled_path: pd.DataFrame, base: dict[str, Any], title: str = "Fig. 5  Mean error per path"
) -> plt.Figure:
    """Fig. 5: mean Euclidean error per path per method, at the base configuration."""
    paths = list(pooled_path["path"].unique())
    methods = [m for m in METHODS if (pooled_path["method"] == m).any()]
    fig, ax = plt.subplots(figsize=(max(6.5, 1.2 * len(paths) + 2), 4.6))
    width = 0.8 / max(1, len(methods))
    for j, m in enumerate(methods):
        sub = pooled_path[pooled_path["method"] == m].set_index("path")
        vals = [sub["euclid_mean_m"].get(p, np.nan) for p in paths]
        offset = (j - (len(methods) - 1) / 2) * width
        ax.bar(np.arange(len(paths)) + offset, vals, width, color=METHOD_COLORS[m], label=METHOD_LABELS[m])
    ax.set_xticks(
        np.arange(len(paths)),
        paths,
        rotation=30 if len(paths) > 8 else 0,
        ha="right" if len(paths) > 8 else "center",
    )
    ax.set_xlabel("route")
    ax.set_ylabel("mean Euclidean error (m)")
    ax.legend(fontsize=8)
    ax.set_title(f"{title} ({config_label(base)})")
    _tight_layout_fitted(fig)
    return fig


def fig_session_medians(per_session: pd.DataFrame, base: dict[str, Any], ratio_limit: float) -> plt.Figure:
    """Each session's median error, paper PF and curbside fused against GNSS, coloured by subset.

    ``per_session`` has ``subset, session, gnss, paper, fused`` (median metres). The dashed line is
    ``ratio_limit`` x the GNSS median (the done-when bound), the dotted one equality.
    """
    fig, axes = plt.subplots(1, 2, figsize=(11.5, 5.2), sharex=True, sharey=True)
    top = (
        float(np.nanmax(per_session[["gnss", "paper", "fused"]].to_numpy())) * 1.1
        if len(per_session)
        else 10.0
    )
    markers = dict(zip(sorted(per_session["subset"].unique()), "osD^v", strict=False))
    for ax, method in zip(axes, ("paper", "fused"), strict=True):
        for subset, rows in per_session.groupby("subset"):
            ax.scatter(
                rows["gnss"],
                rows[method],
                s=28,
                marker=markers[subset],
                color=METHOD_COLORS[method],
                edgecolor="k",
                linewidth=0.4,
                alpha=0.8,
                label=subset,
            )
        line = np.array([0.0, top])
        ax.plot(line, line, ":", color="0.4", lw=1, label="equal to GNSS")
        ax.plot(line, ratio_limit * line, "--", color="0.2", lw=1, label=f"{ratio_limit:g} x GNSS")
        ax.set_xlim(0, top)
        ax.set_ylim(0, top)
        ax.set_aspect("equal")
        ax.set_xlabel("GNSS median error per session (m)")
        ax.set_ylabel(f"{METHOD_LABELS[method]} median error (m)")
        ax.set_title(METHOD_LABELS[method])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")  # above the 1.5x line: the empty corner
    _suptitle(fig, f"Per-session median error against GNSS ({config_label(base)})")
    _tight_layout_fitted(fig)
    return fig


def save_png(fig: plt.Figure, path: Path, dpi: int = 110) -> bytes:
    """Save and close a figure; return the PNG bytes."""
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path.read_bytes()


def fig_reliability(rows: list[dict[str, Any]], base: dict[str, Any]) -> plt.Figure | None:
    """``segment_prob`` against the share of footsteps on the correct sidewalk, bin by bin: one panel per
    group (a benchmark subset), one line per filter, marker area by the bin's share of the footsteps.
    Below, where the rows carry ``accuracy_curve``, the same for the position: the share of footsteps
    that ``accuracy_m``, scaled with its heavy tail (``calibration.radius_at_share_m``), held against
    the share it claims.

    ``rows`` are :func:`curbside.evaluate.confidence.reliability_rows` (``None`` without any). On the
    diagonal the claim is a frequency; below it the filter is over-confident.
    """
    if not rows:
        return None
    groups = list(dict.fromkeys(r["subset"] for r in rows))
    radius = any(r.get("accuracy_curve") for r in rows)
    width = max(6.0, 4.3 * len(groups) + 0.4)
    # constrained layout: it leaves room for the legends under the square top panels (tight_layout let
    # them run over the titles below once there were two groups)
    fig, axes = plt.subplots(1 + radius, len(groups), figsize=(width, 6.1 + 5.4 * radius), squeeze=False,
                             layout="constrained")
    for k, group in enumerate(groups):
        in_group = [r for r in rows if r["subset"] == group]
        _segment_reliability_axes(axes[0][k], in_group, group)
        if radius:
            _radius_reliability_axes(axes[1][k], in_group)
    axes[0][0].set_ylabel("share of those footsteps on the correct sidewalk")
    if radius:
        axes[1][0].set_ylabel("share of footsteps the radius held")
    title = "How far to trust segment_prob" + (" and accuracy_m" if radius else "")
    note = "marker area (top): the bin's share of the footsteps"
    # the configuration on a line of its own: a long map name wraps there, not mid-sentence
    _suptitle(fig, f"{title}\n({config_label(base)})\n{note}", fontsize=11)
    fig.get_layout_engine().set(hspace=0.05)
    fig.get_layout_engine().execute(fig)
    _fit_axes_titles(fig)
    return fig


#: Room beyond 0 and 1 on the reliability axes (a share of the unit), for the markers at 0 and 1.
RELIABILITY_MARGIN = 0.06


def _legend_below(ax: plt.Axes) -> None:
    """The axes' legend under its x label, where it hides no marker."""
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), frameon=False)


def _segment_reliability_axes(ax, rows: list[dict[str, Any]], group: str | None) -> None:
    for r in rows:
        bins = pd.DataFrame(r["bins"])
        color = METHOD_COLORS[r["method"]]
        ax.plot(bins["mean_prob"], bins["share_right"], "-", color=color, lw=1.2, alpha=0.8)
        area = 15 + 400 * bins["footsteps"] / r["footsteps"]
        ax.scatter(bins["mean_prob"], bins["share_right"], s=area, color=color,
                   edgecolor="k", linewidth=0.4, alpha=0.85, zorder=3, clip_on=False,
                   label=f"{METHOD_LABELS[r['method']]} (calibration error {r['calibration_error']:.3f})")
    ax.plot([0, 1], [0, 1], ":", color="0.4", lw=1, label="probability = share correct")
    # room for the largest marker at probability and share 1 (they are not clipped either)
    ax.set_xlim(-RELIABILITY_MARGIN, 1 + RELIABILITY_MARGIN)
    ax.set_ylim(-RELIABILITY_MARGIN, 1 + RELIABILITY_MARGIN)
    ax.set_xticks(np.linspace(0, 1, 6))
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_aspect("equal")
    ax.set_xlabel("segment_prob (mean over the bin)")
    ax.set_title(group if group is not None else "all walks")
    ax.grid(alpha=0.3)
    _legend_below(ax)


def _radius_reliability_axes(ax, rows: list[dict[str, Any]]) -> None:
    for r in rows:
        curve = pd.DataFrame(r.get("accuracy_curve") or [])
        if curve.empty:
            continue
        ax.plot(curve["claimed"], curve["held"], "o-", color=METHOD_COLORS[r["method"]], lw=1.2, ms=5,
                clip_on=False, label=f"{METHOD_LABELS[r['method']]} (68 %: {r['accuracy_coverage']:.2f}, "
                f"median {r['accuracy_median_m']:.1f} m)")
    ax.plot([0, 1], [0, 1], ":", color="0.4", lw=1, label="claimed = held")
    ax.axvline(0.68, color="0.6", lw=0.8, label="0.68: the share accuracy_m claims")
    ax.set_title(f"accuracy_m (0.68), scaled with a t tail (\u03bd = {TAIL_DOF:g})", fontsize=10)
    ax.set_xlim(0.4, 1.0)
    ax.set_ylim(0, 1 + RELIABILITY_MARGIN / 2)
    ax.set_xlabel("share the radius claims")
    ax.grid(alpha=0.3)
    _legend_below(ax)
