"""Reports: ``metrics.json``, ``report.md`` and a self-contained ``report.html`` with the paper's tables.

Tables 2-4 of the paper are printed side by side with the paper's own numbers; figures follow the
paper's Fig. 1 (tracks over the map per path), Fig. 3 (particle clouds), Fig. 4 (error CDFs) and
Fig. 5 (mean error per path per method). The HTML embeds every figure as a base64 PNG, so the one
file can be mailed or archived; the Markdown links the same PNGs under ``figures/``.
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

import curbside  # noqa: E402
from curbside import settings  # noqa: E402
from curbside.evaluate.metrics import METRIC_NAMES  # noqa: E402
from curbside.evaluate.runner import METHOD_LABELS, METHODS, MODE_SUFFIX, pool  # noqa: E402
from curbside.io import atomic_path  # noqa: E402
from curbside.osmseg.mapio import MapLayers  # noqa: E402

#: The paper's Tables 2-4 (Dubiner, Ren, Manduchi), per method.
PAPER: dict[str, Any] = {
    "csa": {
        0.0: {"gnss": 0.47, "inertial": 0.21, "fused": 0.30},
        0.4: {"gnss": 0.47, "inertial": 0.71, "fused": 0.80},
        1.0: {"gnss": 0.47, "inertial": 0.41, "fused": 0.72},
    },
    "euclid_mean_m": {"gnss": 20.9, "inertial": 23.7, "fused": 11.7},
    "euclid_median_m": {"gnss": 13.6, "inertial": 16.1, "fused": 11.3},
    "euclid_p90_m": {"gnss": 48.2, "inertial": 47.4, "fused": 20.5},
    "along_median_m": {"gnss": 6.2, "inertial": 11.3, "fused": 9.0},
    "across_median_m": {"gnss": 8.1, "inertial": 4.7, "fused": 3.1},
}
METHOD_COLORS = {"gnss": "#d62728", "inertial": "#2ca02c", "fused": "#9467bd"}
CLASS_COLORS = {"building": "#c9a0a0", "street": "#a9adb8", "crosswalk": "#f2e394", "sidewalk": "#bfe3b4"}


def _fmt(value: Any, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _json_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_ready(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _records(frame: pd.DataFrame) -> list[dict[str, Any]]:
    return [_json_ready(dict(r)) for r in frame.astype(object).where(frame.notna(), None).to_dict("records")]


class Table:
    """A small table rendered both as Markdown and HTML."""

    def __init__(self, title: str, header: list[str], rows: list[list[str]], note: str = "") -> None:
        self.title, self.header, self.rows, self.note = title, header, rows, note

    def markdown(self) -> str:
        """GitHub-flavoured Markdown."""
        lines = [f"**{self.title}**", "", "| " + " | ".join(self.header) + " |"]
        lines.append("|" + "|".join("---" for _ in self.header) + "|")
        lines += ["| " + " | ".join(r) + " |" for r in self.rows]
        if self.note:
            lines += ["", self.note]
        return "\n".join(lines) + "\n"

    def html(self) -> str:
        """An HTML table."""
        head = "".join(f"<th>{html.escape(h)}</th>" for h in self.header)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in self.rows)
        note = f"<p class='note'>{html.escape(self.note)}</p>" if self.note else ""
        return f"<h3>{html.escape(self.title)}</h3><table><tr>{head}</tr>{body}</table>{note}"


def _lookup(pooled: pd.DataFrame, method: str, **where: Any) -> pd.Series | None:
    sel = pooled["method"] == method
    for col, value in where.items():
        if method == "gnss" and col in ("jaywalk_weight", "particles", "gnss_sigma_factor"):
            continue
        if value is None:
            sel &= pooled[col].isna()
        else:
            sel &= pooled[col] == value
    rows = pooled[sel]
    return rows.iloc[0] if len(rows) else None


def paper_tables(pooled: pd.DataFrame, map_name: str, base: dict[str, Any]) -> list[Table]:
    """Tables 2, 3 and 4 of the paper for one map source, beside the paper's numbers."""
    methods = [m for m in METHODS if (pooled["method"] == m).any()]
    header = [""] + [f"{METHOD_LABELS[m]} (paper)" for m in methods]
    where = {"map": map_name, "particles": base["particles"], "gnss_sigma_factor": base["gnss_sigma_factor"]}
    rows2 = []
    for w in sorted(pooled.loc[pooled["method"] != "gnss", "jaywalk_weight"].unique()):
        row = [f"w = {w:g}"]
        for m in methods:
            r = _lookup(pooled, m, jaywalk_weight=w, **where)
            paper = PAPER["csa"].get(round(float(w), 2), {}).get(m)
            row.append(f"{_fmt(None if r is None else r['csa'])} ({_fmt(paper)})")
        rows2.append(row)
    tables = [
        Table(
            f"Table 2. Correct Sidewalk Assignment, map '{map_name}'",
            header,
            rows2,
            "Pooled over all footsteps; GNSS does not depend on w.",
        )
    ]
    w0 = base["jaywalk_weight"]
    if f"csa{MODE_SUFFIX}" in pooled:
        tables += mode_tables(pooled, map_name, methods, where, w0)
    for title, names in (
        ("Table 3. Euclidean error (m)", ("euclid_mean_m", "euclid_median_m", "euclid_p90_m")),
        ("Table 4. Along- and across-street median error (m)", ("along_median_m", "across_median_m")),
    ):
        rows = []
        for name in names:
            row = [name]
            for m in methods:
                r = _lookup(pooled, m, jaywalk_weight=w0, **where)
                row.append(f"{_fmt(None if r is None else r[name], 1)} ({_fmt(PAPER[name][m], 1)})")
            rows.append(row)
        tables.append(Table(f"{title}, w = {w0:g}, map '{map_name}'", header, rows))
    rows = []
    for name in ("ate_m", "rte_m"):
        row = [name]
        for m in methods:
            r = _lookup(pooled, m, jaywalk_weight=w0, **where)
            row.append(_fmt(None if r is None else r[name], 1))
        rows.append(row)
    tables.append(
        Table(
            f"Trajectory errors (RoNIN's ATE / RTE, 60 s windows), w = {w0:g}, map '{map_name}'",
            [""] + [METHOD_LABELS[m] for m in methods],
            rows,
            "Means over runs; the paper reports neither.",
        )
    )
    return tables


def mode_tables(
    pooled: pd.DataFrame, map_name: str, methods: list[str], where: dict[str, Any], w0: float
) -> list[Table]:
    """CSA and errors of the posterior-mode estimate beside the paper's weighted-mean estimate."""
    rows = []
    for w in sorted(pooled.loc[pooled["method"] != "gnss", "jaywalk_weight"].unique()):
        row = [f"w = {w:g}"]
        for m in methods:
            r = _lookup(pooled, m, jaywalk_weight=w, **where)
            row.append("-" if r is None else f"{_fmt(r['csa'])} / {_fmt(r[f'csa{MODE_SUFFIX}'])}")
        rows.append(row)
    header = [""] + [METHOD_LABELS[m] for m in methods]
    errors = []
    for name in ("euclid_mean_m", "euclid_median_m", "euclid_p90_m", "along_median_m", "across_median_m"):
        row = [name]
        for m in methods:
            r = _lookup(pooled, m, jaywalk_weight=w0, **where)
            row.append("-" if r is None else f"{_fmt(r[name], 1)} / {_fmt(r[f'{name}{MODE_SUFFIX}'], 1)}")
        errors.append(row)
    return [
        Table(
            f"Correct Sidewalk Assignment, mean / posterior-mode estimate, map '{map_name}'",
            header,
            rows,
            "Mean: the paper's weighted mean of the particles. Mode: the weighted mean of the particles on "
            "the sidewalk segment of largest posterior probability. GNSS has no particles: both equal.",
        ),
        Table(f"Errors (m), mean / posterior-mode estimate, w = {w0:g}, map '{map_name}'", header, errors),
    ]


def map_table(pooled: pd.DataFrame, base: dict[str, Any]) -> Table:
    """Map-source comparison: the same sessions tracked on each map, at the base parameters."""
    names = ("csa", "euclid_mean_m", "euclid_median_m", "euclid_p90_m", "along_median_m", "across_median_m")
    rows = []
    for map_name in pooled["map"].unique():
        for m in METHODS:
            r = _lookup(
                pooled,
                m,
                map=map_name,
                jaywalk_weight=base["jaywalk_weight"],
                particles=base["particles"],
                gnss_sigma_factor=base["gnss_sigma_factor"],
            )
            if r is not None:
                rows.append(
                    [map_name, METHOD_LABELS[m]] + [_fmt(r[n], 2 if n == "csa" else 1) for n in names]
                )
    return Table(
        "Map sources compared",
        ["map", "method", *names],
        rows,
        "Every map is scored against the same reference sidewalk segments.",
    )


def sweep_tables(pooled: pd.DataFrame, base: dict[str, Any]) -> list[Table]:
    """One table per swept parameter with two or more values (the others held at their base values)."""
    tables = []
    params = ("jaywalk_weight", "particles", "gnss_sigma_factor")
    labels = {
        "jaywalk_weight": "jaywalk weight w",
        "particles": "particles N",
        "gnss_sigma_factor": "GNSS sigma factor",
    }
    for param in params:
        sub = pooled[pooled["method"] != "gnss"]
        for other in params:
            if other != param:
                sub = sub[sub[other].isna()] if base[other] is None else sub[sub[other] == base[other]]
        if sub[param].nunique(dropna=False) < 2:
            continue
        rows = [
            [
                str(r["map"]),
                METHOD_LABELS[r["method"]],
                "default" if pd.isna(r[param]) else f"{r[param]:g}",
                _fmt(r["csa"]),
                _fmt(r["euclid_median_m"], 1),
                _fmt(r["euclid_p90_m"], 1),
                _fmt(r["across_median_m"], 1),
            ]
            for _, r in sub.iterrows()
        ]
        header = ["map", "method", labels[param], "csa", "euclid_median_m", "euclid_p90_m", "across_median_m"]
        tables.append(Table(f"Sweep: {labels[param]}", header, rows))
    return tables


# -- figures ------------------------------------------------------------------------------------------------


def _draw_map(ax, layers: MapLayers | None, bounds: tuple[float, float, float, float]) -> None:
    if layers is None:
        return
    x0, y0, x1, y1 = bounds
    sub = layers.gdf.cx[x0:x1, y0:y1]
    for cls, color in CLASS_COLORS.items():
        part = sub[sub["class"] == cls]
        if len(part):
            part.plot(ax=ax, color=color, edgecolor="white", linewidth=0.2, zorder=0)


def fig_tracks(results: list[dict], layers: MapLayers | None, base: dict[str, Any]) -> plt.Figure:
    """Fig. 1: ground truth, waypoints and the three methods' footsteps, one panel per path."""
    first: dict[str, str] = {}
    for r in results:
        first.setdefault(r["path"], r["session"])
    paths = list(first)
    cols = min(3, len(paths))
    rows = math.ceil(len(paths) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.5 * cols, 5.2 * rows), squeeze=False)
    for ax, path in zip(axes.ravel(), paths, strict=False):
        runs = [r for r in results if r["session"] == first[path] and _is_base(r, base)]
        tracks = {r["spec"]["method"]: r["track"] for r in runs}
        gt = next(iter(tracks.values()))
        x0, x1 = gt["gt_x_m"].min() - 40, gt["gt_x_m"].max() + 40
        y0, y1 = gt["gt_y_m"].min() - 40, gt["gt_y_m"].max() + 40
        _draw_map(ax, layers, (x0, y0, x1, y1))
        ax.plot(gt["gt_x_m"], gt["gt_y_m"], color="0.4", lw=2, label="ground truth", zorder=2)
        for m in METHODS:
            if m in tracks:
                tr = tracks[m]
                ax.scatter(
                    tr["x_m"], tr["y_m"], s=3, color=METHOD_COLORS[m], label=METHOD_LABELS[m], zorder=3
                )
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.set_title(f"{path} ({first[path]})")
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in axes.ravel()[len(paths) :]:
        ax.axis("off")
    axes.ravel()[0].legend(loc="lower left", fontsize=7, markerscale=3)
    fig.suptitle("Fig. 1  Tracks per path (map " + str(base.get("map", "")) + ")")
    fig.tight_layout()
    return fig


def fig_particles(results: list[dict], layers: MapLayers | None, base: dict[str, Any]) -> plt.Figure | None:
    """Fig. 3: particle clouds of RoNIN+PF and GNSS+RoNIN+PF at the chosen moments."""
    runs = [r for r in results if r["snapshots"]]
    if not runs:
        return None
    session = runs[0]["session"]
    runs = [r for r in runs if r["session"] == session]
    n = len(runs[0]["snapshots"])
    fig, axes = plt.subplots(1, n, figsize=(6 * n, 6), squeeze=False)
    for k, ax in enumerate(axes.ravel()):
        gt_track = runs[0]["track"]
        t = runs[0]["snapshots"][k]["t"]
        i = int(np.argmin(np.abs(gt_track["t"].to_numpy() - t)))
        cx, cy = gt_track["gt_x_m"].iat[i], gt_track["gt_y_m"].iat[i]
        bounds = (cx - 45, cy - 45, cx + 45, cy + 45)
        _draw_map(ax, layers, bounds)
        for r in runs:
            snap = r["snapshots"][k]
            m = r["spec"]["method"]
            ax.scatter(snap["x"], snap["y"], s=2, alpha=0.5, color=METHOD_COLORS[m], label=METHOD_LABELS[m])
        fix = runs[0]["snapshots"][k].get("fix")
        if fix is not None:
            ax.add_patch(plt.Circle(fix[:2], fix[2], color="#1f77b4", alpha=0.15, zorder=1))
            ax.plot(*fix[:2], "o", color="#1f77b4", ms=9, label=f"GNSS fix (accuracy {fix[2]:.0f} m)")
        ax.plot(cx, cy, "k*", ms=12, label="ground truth")
        ax.set_xlim(bounds[0], bounds[2])
        ax.set_ylim(bounds[1], bounds[3])
        ax.set_aspect("equal")
        ax.set_title(f"{session}, t = {t:.0f} s")
        ax.set_xticks([])
        ax.set_yticks([])
        handles, labels = ax.get_legend_handles_labels()
        legend = ax.legend(handles, labels, loc="lower left", fontsize=7)
        for handle in legend.legend_handles[: len(runs)]:
            handle.set_sizes([20])
    fig.suptitle("Fig. 3  Particle clouds")
    fig.tight_layout()
    return fig


def fig_cdf(results: list[dict], base: dict[str, Any]) -> plt.Figure:
    """Fig. 4: CDF of the Euclidean error over all footsteps, per method."""
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for m in METHODS:
        errs = [r["errors"] for r in results if r["spec"]["method"] == m and _is_base(r, base)]
        if not errs:
            continue
        e = pd.concat(errs)
        e = np.sort(e.loc[~e["missing"], "euclid_m"].to_numpy())
        ax.plot(e, np.arange(1, len(e) + 1) / len(e), color=METHOD_COLORS[m], label=METHOD_LABELS[m])
    ax.set_xlabel("Euclidean error (m)")
    ax.set_ylabel("CDF")
    ax.set_xlim(0, 60)
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title("Fig. 4  Euclidean error CDF")
    fig.tight_layout()
    return fig


def fig_per_path(pooled_path: pd.DataFrame) -> plt.Figure:
    """Fig. 5: mean Euclidean error per path per method."""
    paths = list(pooled_path["path"].unique())
    fig, ax = plt.subplots(figsize=(max(6, 1.3 * len(paths)), 4.5))
    width = 0.27
    for j, m in enumerate(METHODS):
        sub = pooled_path[pooled_path["method"] == m].set_index("path")
        vals = [sub["euclid_mean_m"].get(p, np.nan) for p in paths]
        ax.bar(
            np.arange(len(paths)) + (j - 1) * width,
            vals,
            width,
            color=METHOD_COLORS[m],
            label=METHOD_LABELS[m],
        )
    ax.set_xticks(np.arange(len(paths)), paths)
    ax.set_ylabel("mean Euclidean error (m)")
    ax.legend()
    ax.set_title("Fig. 5  Mean error per path")
    fig.tight_layout()
    return fig


def _is_base(result: dict, base: dict[str, Any]) -> bool:
    spec = result["spec"]
    if spec["method"] == "gnss":
        return spec["map_name"] == base["map"]
    return (
        spec["map_name"] == base["map"]
        and spec["jaywalk_weight"] == base["jaywalk_weight"]
        and spec["particles"] == base["particles"]
        and spec["gnss_sigma_factor"] == base["gnss_sigma_factor"]
    )


def _png(fig: plt.Figure, path: Path) -> bytes:
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.read_bytes()


# -- the report ---------------------------------------------------------------------------------------------


def write_report(
    results: list[dict],
    out_dir: str | Path,
    base: dict[str, Any],
    layers: MapLayers | None = None,
    extra_tables: list[Table] | None = None,
    lead_tables: list[Table] | None = None,
    extra_json: dict[str, Any] | None = None,
    intro: str = "",
) -> dict[str, Path]:
    """Write ``metrics.json``, ``report.md``, ``report.html``, ``figures/`` and ``view/`` (a replay page per
    session, linked from the report) atomically, as one folder.

    Parameters
    ----------
    results
        :func:`curbside.evaluate.runner.run_one` outputs.
    out_dir
        Report folder (replaced).
    base
        Base parameters: ``map``, ``jaywalk_weight``, ``particles``, ``gnss_sigma_factor``.
    layers
        Map drawn under the figures.
    extra_tables
        Tables after the paper's (IPIN results...).
    lead_tables
        Tables before the paper's (Table 1, the routes).
    extra_json
        More members for ``metrics.json``.
    intro
        Markdown paragraph at the top.

    Returns
    -------
    dict
        Paths written, by name.
    """
    out_dir = Path(out_dir)
    by_run = ("map", "method", "jaywalk_weight", "particles", "gnss_sigma_factor")
    pooled = pool(results, by_run)
    per_path = pool(results, (*by_run, "path"))
    per_session = pool(results, (*by_run, "session"))
    base_path = per_path
    for col in ("jaywalk_weight", "particles", "gnss_sigma_factor"):
        val = base[col]
        keep = (base_path["method"] == "gnss") | (
            base_path[col].isna() if val is None else base_path[col] == val
        )
        base_path = base_path[keep]
    base_path = base_path[base_path["map"] == base["map"]]

    tables = list(lead_tables or [])
    for map_name in pooled["map"].unique():
        tables += paper_tables(pooled, map_name, base)
    if pooled["map"].nunique() > 1:
        tables.append(map_table(pooled, base))
    tables += sweep_tables(pooled, base)
    tables += extra_tables or []

    doc = {
        "generator": f"curbside {curbside.__version__}",
        "metric_names": list(METRIC_NAMES),
        "base": base,
        "paper": {
            k: ({str(w): v for w, v in val.items()} if k == "csa" else val) for k, val in PAPER.items()
        },
        "pooled": _records(pooled),
        "per_path": _records(per_path),
        "per_session": _records(per_session),
        "definitions": {
            "csa_on_crossing": (
                f"ground truth > {settings.evaluate_on_sidewalk_m} m from every sidewalk: correct when the "
                f"estimate's segment is within {settings.evaluate_crossing_slack_m} m of the nearest "
                "one's distance"
            ),
            "street_direction": "long axis of the sidewalk segment nearest to the ground truth",
            "rte_window_s": settings.evaluate_rte_window_s,
        },
    }
    doc.update(extra_json or {})
    with atomic_path(out_dir) as tmp:
        figdir = tmp / "figures"
        figdir.mkdir(parents=True)
        figures: list[tuple[str, str, bytes]] = []
        figures.append(
            (
                "fig1_tracks.png",
                "Fig. 1 tracks",
                _png(fig_tracks(results, layers, base), figdir / "fig1_tracks.png"),
            )
        )
        fig3 = fig_particles(results, layers, base)
        if fig3 is not None:
            figures.append(
                ("fig3_particles.png", "Fig. 3 particles", _png(fig3, figdir / "fig3_particles.png"))
            )
        figures.append(("fig4_cdf.png", "Fig. 4 CDF", _png(fig_cdf(results, base), figdir / "fig4_cdf.png")))
        figures.append(
            (
                "fig5_per_path.png",
                "Fig. 5 per path",
                _png(fig_per_path(base_path), figdir / "fig5_per_path.png"),
            )
        )
        (tmp / "metrics.json").write_text(json.dumps(_json_ready(doc), indent=1), encoding="utf-8")
        # -- the replay viewer: one page per session (curbside.localize.view) --------------------------
        from curbside.localize.view import write_session_views

        views = {name: f"view/{name}.html" for name in write_session_views(results, base, tmp / "view")}
        views_md = "## Replay each session\n\n" + "".join(
            f"- [{name}]({href})\n" for name, href in sorted(views.items())
        )
        views_html = "<h2>Replay each session</h2><ul>" + "".join(
            f"<li><a href='{html.escape(href)}'>{html.escape(name)}</a></li>"
            for name, href in sorted(views.items())
        ) + "</ul>"
        # -- end of the replay viewer's links ------------------------------------------------------------
        md = ["# curbside evaluation report", "", intro, ""]
        md += [t.markdown() for t in tables]
        md += [f"![{alt}](figures/{name})\n" for name, alt, _ in figures]
        md += [views_md]
        (tmp / "report.md").write_text("\n".join(md), encoding="utf-8")
        imgs = "".join(
            f"<figure><img alt='{alt}' "
            f"src='data:image/png;base64,{base64.b64encode(data).decode()}'/></figure>"
            for _, alt, data in figures
        )
        style = (
            "body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}"
            "table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;"
            "text-align:right}th{background:#eee}.note{color:#555;font-size:90%}img{max-width:100%}"
        )
        page = (
            f"<!doctype html><html><head><meta charset='utf-8'><title>curbside report</title>"
            f"<style>{style}</style></head><body><h1>curbside evaluation report</h1>"
            f"<p>{html.escape(intro)}</p>{''.join(t.html() for t in tables)}{imgs}{views_html}"
            f"<p class='note'>{html.escape(settings.osm_attribution)}</p></body></html>"
        )
        (tmp / "report.html").write_text(page, encoding="utf-8")
    return {name: out_dir / name for name in ("metrics.json", "report.md", "report.html")}
