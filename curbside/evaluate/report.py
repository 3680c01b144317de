"""Reports: ``metrics.json``, ``report.md`` and a self-contained ``report.html`` with the paper's tables.

Tables 2-4 of the paper are printed side by side with the paper's own numbers
(:mod:`curbside.evaluate.report_tables`); the "how sure" and segment_prob tables are built here; figures
follow the paper's Fig. 1 (tracks over the map per path), Fig. 3 (particle clouds), Fig. 4 (error CDFs)
and Fig. 5 (mean error per path per method). The HTML embeds every figure as a base64 PNG, so the one
file can be mailed or archived; the Markdown links the same PNGs under ``figures/``.
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from typing import Any

import pandas as pd

import curbside
from curbside import settings
from curbside.evaluate.confidence import THRESHOLDS, reliability_rows
from curbside.evaluate.figures import (
    fig_cdf,
    fig_particles,
    fig_per_path,
    fig_reliability,
    fig_tracks,
    save_png,
)
from curbside.evaluate.metrics import METRIC_NAMES, MetricsConfig
from curbside.evaluate.report_tables import PAPER, Table, fmt_value, map_table, paper_tables, sweep_tables
from curbside.evaluate.runner import METHOD_LABELS, pool
from curbside.evaluate.uncertainty import MIN_BOOTSTRAP_UNITS, map_intervals, subset_intervals, unit_count
from curbside.io import atomic_path, json_ready
from curbside.localize.runconfig import RunConfig
from curbside.osmseg.mapio import MapLayers


def records(frame: pd.DataFrame) -> list[dict[str, Any]]:
    """A frame as JSON-ready row dicts (NaN as ``None``)."""
    return [json_ready(dict(r)) for r in frame.astype(object).where(frame.notna(), None).to_dict("records")]


#: Column headers of the interval metrics.
INTERVAL_HEADERS = {"csa": "CSA", "euclid_median_m": "median m", "euclid_p90_m": "p90 m",
                    "across_median_m": "across median m"}


def _interval_cell(row: pd.Series) -> str:
    """``value [lo, hi]``; a paired difference is signed and ends with the share of resamples better.
    ``n/a (2 sessions)`` where there were too few sessions to resample (a ``reason``)."""
    digits = 2 if row["metric"] == "csa" else 1
    if isinstance(row.get("reason"), str):
        return f"n/a ({unit_count(int(row['n_units']), str(row['unit']))})"
    if not all(math.isfinite(row[k]) for k in ("value", "lo", "hi")):
        return "n/a"
    value, lo, hi = (round(row[k], digits) + 0.0 for k in ("value", "lo", "hi"))  # + 0.0: no "-0.00"
    if " - " not in row["method"]:
        return f"{value:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"
    return f"{value:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}] {100 * row['better_share']:.0f} %"


def interval_table(intervals: pd.DataFrame, title: str, note: str) -> Table:
    """Rows of :func:`curbside.evaluate.uncertainty.bootstrap_intervals` as a table: one row per method and
    difference (per ``subset`` too when it has several), one column per metric."""
    metrics = [m for m in INTERVAL_HEADERS if m in set(intervals["metric"])]
    groups = ["subset"] if "subset" in intervals and intervals["subset"].nunique() > 1 else []
    rows = []
    for key, part in intervals.groupby([*groups, "method"], sort=False):
        cells = part.set_index("metric").reindex(metrics).reset_index()
        label = " - ".join(METHOD_LABELS.get(m, m) for m in part["method"].iat[0].split(" - "))
        rows.append([*(key[:-1] if groups else ()), label, *(_interval_cell(r) for _, r in cells.iterrows())])
    header = [*groups, "method", *(INTERVAL_HEADERS[m] for m in metrics)]
    if "reason" in intervals and intervals["reason"].notna().any():
        unit = intervals.loc[intervals["reason"].notna(), "unit"].iat[0]
        note += (f" n/a (N {unit}): fewer than {MIN_BOOTSTRAP_UNITS} {unit}, too few to resample for an "
                 "interval; the point figures are in the tables above.")
    return Table(title, header, rows, note)


#: How the interval tables are read (the note under each).
INTERVAL_NOTE = (
    "Each figure with its 95 % percentile interval from 1,000 resamples of the {unit} with replacement "
    "(a cluster bootstrap: the {points} of one {one} move together). Differences are paired, every "
    "method on the same resampled {unit}; the percentage is the share of resamples in which curbside "
    "fused is better."
)
#: The note under the map-source intervals.
MAP_INTERVAL_NOTE = (
    "Curbside fused on each map source, each figure with its 95 % percentile interval from 1,000 "
    "resamples of the sessions (paired: both maps on the same resampled sessions). In a row 'B - A' the "
    "percentage is the share of resamples in which map B does better than map A."
)


# -- the report ---------------------------------------------------------------------------------------------


def _definitions(scoring: MetricsConfig) -> dict[str, Any]:
    """How the metrics were scored, in words and numbers (``metrics.json``'s ``definitions``)."""
    return {
        "csa_on_crossing": (
            f"ground truth > {scoring.on_sidewalk_m} m from every sidewalk: correct when the "
            f"estimate's segment is within {scoring.crossing_slack_m} m of the nearest one's distance"
        ),
        "street_direction": (
            "street of the sidewalk segment nearest to the ground truth (facing_deg, else its long axis)"
        ),
        "rte_window_s": scoring.rte_window_s,
    }


def base_text(base: dict[str, Any]) -> str:
    """The report's base parameters in a sentence: the particle count N of every particle filter (beside
    ``localize run``'s default where that differs: the same walk tracked there gives other figures), the
    jaywalk weight, the map and the GNSS sigma factor."""
    defaults = {m: RunConfig.for_mode(m).filter.n_particles for m in ("inertial", "paper", "fused")}
    differ = [f"{METHOD_LABELS[m]} {n}" for m, n in defaults.items() if n != base["particles"]]
    sigma = "default" if base["gnss_sigma_factor"] is None else f"{base['gnss_sigma_factor']:g}"
    return (f"Base parameters: N = {base['particles']} particles in every particle filter"
            + (f" (localize run's default: {', '.join(differ)})" if differ else "")
            + f", jaywalk weight w = {base['jaywalk_weight']:g}, map '{base['map']}', GNSS sigma factor "
            f"{sigma}. The tables, figures and replay pages are at these unless they name another value.")


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
    base_path = _at_base(per_path, base)
    tables = list(lead_tables or [])
    for map_name in pooled["map"].unique():
        tables += paper_tables(pooled, map_name, base)
    if pooled["map"].nunique() > 1:
        tables.append(map_table(pooled, base))
    tables += sweep_tables(pooled, base)
    sure, sure_rows = _interval_tables(results, base)
    trust_rows = reliability_rows(results, base)
    trust = confidence_table(trust_rows, base["jaywalk_weight"], base["map"])
    tables += sure + ([trust] if trust is not None else []) + (extra_tables or [])
    doc = {
        "generator": f"curbside {curbside.__version__}",
        "metric_names": list(METRIC_NAMES),
        "base": base,
        "paper": {
            k: ({str(w): v for w, v in val.items()} if k == "csa" else val) for k, val in PAPER.items()
        },
        "pooled": records(pooled),
        "per_path": records(per_path),
        "per_session": records(per_session),
        **sure_rows,
        "segment_prob_reliability": trust_rows,
        "definitions": _definitions(MetricsConfig()),  # run_one scores with the defaults
    }
    doc.update(extra_json or {})
    with atomic_path(out_dir) as tmp:
        figures = _write_figures(results, layers, base, base_path, tmp / "figures", trust_rows)
        (tmp / "metrics.json").write_text(json.dumps(json_ready(doc), indent=1), encoding="utf-8")
        from curbside.localize.view import write_session_views

        views = {name: f"view/{name}.html" for name in write_session_views(results, base, tmp / "view")}
        lead = base_text(base)
        (tmp / "report.md").write_text(_markdown_page(intro, tables, figures, views, lead), encoding="utf-8")
        (tmp / "report.html").write_text(_html_page(intro, tables, figures, views, lead), encoding="utf-8")
    return {name: out_dir / name for name in ("metrics.json", "report.md", "report.html")}


def _markdown_page(
    intro: str, tables: list[Table], figures: list, views: dict[str, str], base_note: str = ""
) -> str:
    """``report.md``: the intro, the base parameters (:func:`base_text`), the tables, the figures, a link
    to each session's replay page and the map data's attribution."""
    md = ["# curbside evaluation report", "", *(f"{p}\n" for p in (intro, base_note) if p)]
    md += [t.markdown() for t in tables]
    md += [f"![{alt}](figures/{name})\n" for name, alt, _ in figures]
    md += ["## Replay each session\n\n" + "".join(f"- [{n}]({h})\n" for n, h in sorted(views.items()))]
    return "\n".join([*md, settings.osm_attribution, ""])


#: The note under the segment_prob tables (:mod:`curbside.evaluate.confidence`).
CONFIDENCE_NOTE = (
    "segment_prob is the probability of the sidewalk the filter names (track.csv, the service): for "
    "curbside fused the posterior mass tempered by how long the walk's fixes stay off (docs/filter.md),"
    " for the other filters the mass as it is. Per threshold p: the share of footsteps at which it is "
    "at least p, and the CSA of the posterior-mode estimate over those footsteps, as an app that "
    "announces a side only above p would see it. Calibration error: the footstep-weighted mean gap "
    "between the probability and the share right over bins (0 when a footstep at 0.9 is right 90 % of "
    "the time). Footsteps on crossings are left out; every filter seed pools. accuracy_m is the radius "
    "around the estimate that should hold the walker 68 % of the time (as a phone reports a fix's "
    "accuracy; curbside fused widens it by the same temperature): the share of footsteps it held the "
    "walker, 0.68 when it is what it claims, and its median."
)


def confidence_table(rows: list[dict[str, Any]], jaywalk_weight: float, map_name: str) -> Table | None:
    """:func:`curbside.evaluate.confidence.reliability_rows` of the runs at ``jaywalk_weight`` on
    ``map_name`` as a table (``None`` without rows); the subset column only where the rows have groups."""
    if not rows:
        return None
    grouped = any(r["subset"] is not None for r in rows)
    header = ["subset"] * grouped + ["method", "footsteps", "calibration error"]
    header += [f"p >= {p:g}: share / CSA" for p in THRESHOLDS]
    header += ["accuracy_m held (median m)"]
    body = []
    for r in rows:
        cells = [f"{fmt_value(r[f'coverage_{p:g}'], 2)} / {fmt_value(r[f'csa_{p:g}'], 3)}"
                 for p in THRESHOLDS]
        held = f"{fmt_value(r.get('accuracy_coverage'), 2)} ({fmt_value(r.get('accuracy_median_m'), 1)})"
        body.append([r["subset"]] * grouped + [METHOD_LABELS[r["method"]], str(r["footsteps"]),
                                               fmt_value(r["calibration_error"], 3), *cells, held])
    title = f"How far to trust segment_prob and accuracy_m, w = {jaywalk_weight:g}, map '{map_name}'"
    return Table(title, header, body, CONFIDENCE_NOTE)


def _interval_tables(results: list[dict], base: dict[str, Any]) -> tuple[list[Table], dict[str, Any]]:
    """The "how sure" tables at the base parameters (methods; map sources when several) and their rows."""
    intervals = subset_intervals(results, base)
    maps = map_intervals(results, base)
    w = base["jaywalk_weight"]
    tables = []
    if not intervals.empty:
        note = INTERVAL_NOTE.format(unit="sessions", points="footsteps", one="session")
        title = f"How sure: 95 % intervals, w = {w:g}, map '{base['map']}'"
        tables.append(interval_table(intervals, title, note))
    if not maps.empty:
        title = f"How sure: map sources, curbside fused, w = {w:g}"
        tables.append(interval_table(maps, title, MAP_INTERVAL_NOTE))
    return tables, {"intervals_95": records(intervals), "map_intervals_95": records(maps)}


def _at_base(per_path: pd.DataFrame, base: dict[str, Any]) -> pd.DataFrame:
    """The rows at the base parameters on the base map (GNSS has no filter parameters)."""
    for col in ("jaywalk_weight", "particles", "gnss_sigma_factor"):
        val = base[col]
        keep = (per_path["method"] == "gnss") | (
            per_path[col].isna() if val is None else per_path[col] == val
        )
        per_path = per_path[keep]
    return per_path[per_path["map"] == base["map"]]


def _write_figures(
    results: list[dict],
    layers: MapLayers | None,
    base: dict[str, Any],
    base_path: pd.DataFrame,
    figdir: Path,
    trust_rows: list[dict[str, Any]] | None = None,
) -> list[tuple[str, str, bytes]]:
    """Figures 1, 3 (when a run kept its particles), 4, 5 and ``segment_prob``'s reliability (from
    ``trust_rows``) as PNGs: ``(file name, alt text, bytes)``."""
    figdir.mkdir(parents=True)
    figs = [
        ("fig1_tracks.png", "Fig. 1 tracks", fig_tracks(results, layers, base)),
        ("fig3_particles.png", "Fig. 3 particles", fig_particles(results, layers, base)),
        ("fig4_cdf.png", "Fig. 4 CDF", fig_cdf(results, base)),
        ("fig5_per_path.png", "Fig. 5 per path", fig_per_path(base_path, base)),
        ("fig_reliability.png", "segment_prob reliability", fig_reliability(trust_rows or [], base)),
    ]
    return [(name, alt, save_png(fig, figdir / name)) for name, alt, fig in figs if fig is not None]


#: What every report page's style starts with: a page that reads on a phone (tables scroll sideways in
#: their own box, figures shrink to the screen).
BASE_STYLE = (
    "body{font-family:sans-serif;margin:auto;padding:1em}"
    "table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;"
    "text-align:right}th{background:#eee}.note{color:#555;font-size:90%}img{max-width:100%;height:auto}"
    "td{white-space:nowrap}td:first-child{text-align:left}div.table{overflow-x:auto}figure{margin:1em 0}"
)


def html_document(title: str, style: str, body: str) -> str:
    """A self-contained report page: ``<head>`` with the viewport of a phone's screen, ``title``
    (escaped), ``style`` after :data:`BASE_STYLE`, then ``body`` (markup).

    Parameters
    ----------
    title
        The page title.
    style
        The page's own CSS.
    body
        The body's markup.

    Returns
    -------
    str
        The HTML document.
    """
    return (
        "<!doctype html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{html.escape(title)}</title><style>{BASE_STYLE}{style}</style></head>"
        f"<body>{body}</body></html>"
    )


def _html_page(
    intro: str, tables: list[Table], figures: list[tuple[str, str, bytes]], views: dict[str, str],
    base_note: str = "",
) -> str:
    """``report.html``: self-contained, figures inlined, links to the replay pages."""
    imgs = "".join(
        f"<figure><img alt='{alt}' src='data:image/png;base64,{base64.b64encode(data).decode()}'/></figure>"
        for _, alt, data in figures
    )
    links = "".join(f"<li><a href='{html.escape(href)}'>{html.escape(name)}</a></li>"
                    for name, href in sorted(views.items()))
    lead = "".join(f"<p>{html.escape(p)}</p>" for p in (intro, base_note) if p)
    credit = f"<p class='note'>{html.escape(settings.osm_attribution)}</p>"
    return html_document(
        "curbside report", "body{max-width:1200px}",
        f"<h1>curbside evaluation report</h1>{lead}{''.join(t.html() for t in tables)}{imgs}"
        f"<h2>Replay each session</h2><ul>{links}</ul>{credit}",
    )
