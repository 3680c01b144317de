"""The benchmark report: done-when checks, per-subset and per-session tables, figures.

``report.md`` and a self-contained ``report.html`` (figures embedded), ``metrics.json`` (every pooled
figure, per session too, the checks) and ``run.json`` (every parameter, every run, the timings).
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

import curbside
from curbside import settings
from curbside.evaluate import criteria
from curbside.evaluate.benchmark import IpinScores
from curbside.evaluate.confidence import reliability_rows
from curbside.evaluate.figures import (
    fig_cdf,
    fig_particles,
    fig_per_path,
    fig_reliability,
    fig_session_medians,
    fig_tracks,
    save_png,
)
from curbside.evaluate.report import (
    INTERVAL_NOTE,
    MAP_INTERVAL_NOTE,
    confidence_table,
    html_document,
    interval_table,
    records,
)
from curbside.evaluate.report_tables import (
    CROSSING_NOTE,
    PAPER_NOTE,
    Table,
    fmt_value,
    paper_header,
    paper_value,
)
from curbside.evaluate.runner import METHOD_LABELS, METHODS, SMOOTHED_METHOD, subset_of
from curbside.evaluate.uncertainty import map_intervals, subset_intervals
from curbside.io import atomic_path, json_ready
from curbside.localize.runconfig import UnseenVelocityConfig
from curbside.osmseg.mapio import MapLayers

if TYPE_CHECKING:
    from curbside.evaluate.suite import SuiteConfig

_STYLE = (
    "body{max-width:1250px}td.pass{background:#d9f2d9}td.fail{background:#f7d4d4}"
)
METRICS = ("csa", "euclid_median_m", "euclid_p90_m", "euclid_mean_m", "along_median_m", "across_median_m")
HEADERS = ("CSA", "median m", "p90 m", "mean m", "along median m", "across median m")


def _base(frame: pd.DataFrame, w: float, map_name: str = "osm") -> pd.DataFrame:
    keep = (frame["map"] == map_name) & ((frame["method"] == "gnss") | (frame["jaywalk_weight"] == w))
    return frame[keep]


def subset_table(pooled: pd.DataFrame, subset: str, w: float, sessions: int, lag_s: float = 0.0) -> Table:
    """One subset: every method side by side at the base weight on the OSM map (``lag_s``: the
    smoother's lag, for the note)."""
    rows = []
    base = _base(pooled[pooled["subset"] == subset], w)
    for method in ("gnss", "inertial", "paper", "fused", SMOOTHED_METHOD):
        r = base[base["method"] == method]
        if len(r):
            r = r.iloc[0]
            rows.append([METHOD_LABELS[method]] + [fmt_value(r[m], 2 if m == "csa" else 1) for m in METRICS])
    note = "Pooled over every footstep of the subset."
    if (base["method"] == SMOOTHED_METHOD).any():
        note += (f" '{METHOD_LABELS[SMOOTHED_METHOD]}': curbside fused's fixed-lag smoothed positions"
                 f" (--lag-s {lag_s:g}: offline, each position estimated from the data up to {lag_s:g} s"
                 " later).")
    if subset == "paper6":
        paper = [paper_value(m, "fused", w) for m in METRICS]
        rows.append(
            ["(paper's real walks, GNSS+RoNIN+PF)"]
            + [fmt_value(v, 2 if i == 0 else 1) for i, v in enumerate(paper)]
        )
        note += " The last row is the paper's published result on its real walks, for reference."
    return Table(f"{subset}: {sessions} sessions, w = {w:g}, map 'osm'", ["method", *HEADERS], rows, note)


def sweep_table(pooled: pd.DataFrame, subset: str) -> Table | None:
    """Table 2 of the paper on one subset: CSA per jaywalk weight, the paper's numbers in parentheses."""
    sub = pooled[(pooled["subset"] == subset) & (pooled["map"] == "osm") & (pooled["method"] != "gnss")]
    weights = sorted(sub["jaywalk_weight"].unique())
    if len(weights) < 2:
        return None
    methods = [m for m in ("inertial", "paper", "fused") if (sub["method"] == m).any()]
    rows = []
    for w in weights:
        row = [f"w = {w:g}"]
        for m in methods:
            r = sub[(sub["method"] == m) & (sub["jaywalk_weight"] == w)]
            row.append(
                f"{fmt_value(r['csa'].iat[0] if len(r) else None)} ({fmt_value(paper_value('csa', m, w))})"
            )
        rows.append(row)
    return Table(
        f"Table 2. Correct Sidewalk Assignment by jaywalk weight, {subset}",
        ["", *(paper_header(m) for m in methods)],
        rows,
        f"{PAPER_NOTE} {CROSSING_NOTE}",
    )


def map_table(pooled: pd.DataFrame, w: float) -> Table | None:
    """The DataSF-buildings map against OSM's, per subset and method."""
    if "datasf" not in set(pooled["map"]):
        return None
    rows = []
    for subset in pooled["subset"].unique():
        for method in ("paper", "fused"):
            cells = []
            for map_name in ("osm", "datasf"):
                r = _base(pooled[pooled["subset"] == subset], w, map_name)
                r = r[r["method"] == method]
                cells += [
                    fmt_value(r[m].iat[0], 2 if m == "csa" else 1) if len(r) else "-" for m in METRICS[:3]
                ]
            rows.append([subset, METHOD_LABELS[method], *cells])
    return Table(
        f"Map sources: OSM buildings vs DataSF 2013 buildings (streets and sidewalks from OSM), w = {w:g}",
        ["subset", "method", "CSA osm", "median osm", "p90 osm", "CSA datasf", "median datasf", "p90 datasf"],
        rows,
        "Scored against the OSM map's sidewalk segments in both cases. The DataSF buildings stand on part "
        "of OSM's sidewalks, so curbside fused lets OSM's sidewalks and crosswalks win over them and softens "
        "their walls (filter.map.conflict_*); the paper's method keeps the buildings, with hard walls.",
    )


def _events(session_dir: Path) -> dict[str, Any]:
    meta_path = session_dir / "meta.json"
    sim = json.loads(meta_path.read_text()).get("simulation", {}) if meta_path.is_file() else {}
    ev = sim.get("events", {})
    jumps = ev.get("heading_jumps", [])
    return {
        "gnss_error_median_m": sim.get("gnss_error_median_m"),
        "heading_bias_deg": ev.get("heading_bias_deg"),
        "heading_drift_deg_per_min": ev.get("heading_drift_deg_per_min"),
        "jumps": len(jumps),
        "largest_jump_deg": max((abs(j["deg"]) for j in jumps), default=0.0),
        "speed_scale": ev.get("speed_scale"),
        "stops": len(ev.get("stops", [])),
        "stopped_s": round(sum(s["wait_s"] for s in ev.get("stops", [])), 1),
    }


def session_table(
    per_session: pd.DataFrame, subset: str, w: float, events: dict[str, dict], limit: float
) -> Table:
    """Each session of a subset: every method's CSA and median, fused/GNSS ratio, the error events."""
    base = _base(per_session[per_session["subset"] == subset], w)
    rows = []
    for session in dict.fromkeys(base["session"]):
        s = base[base["session"] == session].set_index("method")

        def get(method: str, column: str, s: pd.DataFrame = s) -> float:
            return s[column].get(method, math.nan)

        ratio = get("fused", "euclid_median_m") / get("gnss", "euclid_median_m")
        ev = events.get(session, {})
        flag = " **" if ratio > limit else ""
        rows.append(
            [session]
            + [fmt_value(get(m, "csa")) for m in ("gnss", "inertial", "paper", "fused")]
            + [fmt_value(get(m, "euclid_median_m"), 1) for m in ("gnss", "inertial", "paper", "fused")]
            + [f"{ratio:.2f}{flag}"]
            + [
                fmt_value(ev.get("heading_bias_deg"), 0),
                fmt_value(ev.get("heading_drift_deg_per_min"), 1),
                f"{ev.get('jumps', 0)} ({ev.get('largest_jump_deg', 0):.0f})",
                fmt_value(ev.get("speed_scale"), 2),
                f"{ev.get('stops', 0)} ({ev.get('stopped_s', 0):.0f} s)",
            ]
        )
    header = [
        "session",
        "CSA gnss",
        "CSA ronin",
        "CSA paper",
        "CSA fused",
        "med gnss",
        "med ronin",
        "med paper",
        "med fused",
        "fused/gnss",
        "bias deg",
        "drift deg/min",
        "jumps (max deg)",
        "speed scale",
        "stops (time)",
    ]
    note = (
        f"Medians in metres. ** marks a fused median above {limit:g} x the GNSS median. The last five "
        "columns are the session's simulated inertial error events (meta.json)."
    )
    return Table(f"Per session, {subset}, w = {w:g}, map 'osm'", header, rows, note)


def interval_tables(
    results: list[dict], config: SuiteConfig
) -> tuple[dict[str, Table | None], dict[str, Any]]:
    """The "how sure" tables of the walks (``subsets``, ``maps``) and how far to trust ``segment_prob``
    (``confidence``), ``None`` where not run, and their rows for ``metrics.json``."""
    w = config.jaywalk_weight
    base = {"map": "osm", "jaywalk_weight": w}
    intervals = subset_intervals(results, base, seed=config.filter_seed)
    maps = map_intervals(results, base, seed=config.filter_seed)
    trust = reliability_rows(results, figure_base(config), subset_of)
    note = INTERVAL_NOTE.format(unit="subset's sessions", points="footsteps", one="session") + (
        " Each route was walked once (--seeds 1), so each session resampled is a route of its own."
        if config.seeds == 1 else
        f" The {config.seeds} sessions of a route are resampled as independent, so the intervals are, if "
        "anything, too narrow for the routes themselves.")
    tables = {
        "subsets": None if intervals.empty else interval_table(
            intervals, f"How sure: 95 % intervals, w = {w:g}, map 'osm'", note),
        "maps": None if maps.empty else interval_table(
            maps, f"How sure: map sources, curbside fused, w = {w:g}", MAP_INTERVAL_NOTE),
        "confidence": confidence_table(trust, w, "osm"),
    }
    return tables, {"intervals_95": records(intervals), "map_intervals_95": records(maps),
                    "segment_prob_reliability": trust}


def ipin_json(ipin_scores: list[IpinScores]) -> dict[str, Any]:
    """``metrics.json``'s IPIN entries: each scoring's pooled figures and intervals (``None`` if not run)."""
    doc: dict[str, Any] = dict.fromkeys(
        ("ipin_held_out", "ipin_intervals_95", "ipin_unseen_ronin", "ipin_unseen_ronin_intervals_95"))
    for scores in ipin_scores:
        doc[scores.key] = scores.summary
        doc[scores.intervals_key] = records(scores.intervals) if not scores.intervals.empty else None
    return doc


def checks_table(checks: list[criteria.Check]) -> Table:
    """The done-when checks, one row each."""
    rows = [[c.criterion, c.scope, c.value, c.verdict] for c in checks]
    return Table(
        "Done when (issue 9)",
        ["criterion", "scope", "figures (fused vs other)", "verdict"],
        rows,
        criteria.overall(checks),
    )


def profile_table(simulation: dict[str, Any], gnss: str = "canyon") -> Table:
    """The simulation profile's error magnitudes (sources: docs/evaluate.md); ``gnss``: the name of
    the GNSS model."""
    v, w = simulation["velocity"], simulation["walker"]
    rows = [
        ["heading bias per walk (1-sigma)", f"{v['heading_bias_deg']:g} deg"],
        [
            "heading drift (1-sigma) / random walk",
            f"{v['heading_drift_deg_per_min']:g} deg/min / "
            f"{v['heading_walk_deg_per_sqrt_min']:g} deg/sqrt(min)",
        ],
        ["correlated heading noise", f"{v['heading_noise_deg']:g} deg over {v['heading_noise_tau_s']:g} s"],
        [
            "heading jumps",
            f"{v['heading_jump_rate_per_min']:g}/min, {v['heading_jump_deg'][0]:g}-"
            f"{v['heading_jump_deg'][1]:g} deg; at {100 * v['stop_jump_prob']:.0f} % of stops",
        ],
        [
            "speed scale per walk (1-sigma) / wander",
            f"{100 * v['scale_sd']:g} % / {100 * v['scale_wander_sd']:g} %",
        ],
        ["step-to-step speed noise", f"{100 * v['speed_noise_cv']:g} % over {v['speed_noise_tau_s']:g} s"],
        ["velocity noise", f"{v['noise_mps']:g} m/s over {v['noise_tau_s']:g} s"],
        ["phantom motion while standing", f"{v['phantom_mps']:g} m/s over {v['phantom_tau_s']:g} s"],
        [
            "stops before crosswalks / jaywalks",
            f"{100 * w['crosswalk_stop_prob']:.0f} % for {w['crosswalk_wait_s'][0]:g}-"
            f"{w['crosswalk_wait_s'][1]:g} s / {100 * w['jaywalk_stop_prob']:.0f} % for "
            f"{w['jaywalk_wait_s'][0]:g}-{w['jaywalk_wait_s'][1]:g} s",
        ],
    ]
    return Table(
        f"Simulation profile '{simulation['profile']}'",
        ["component", "magnitude"],
        rows,
        f"GNSS: the '{gnss}' model of docs/evaluate.md.",
    )


def figure_base(config: SuiteConfig) -> dict[str, Any]:
    """The configuration the figures show: the OSM map, the base jaywalk weight, each method's own N."""
    return {
        "map": "osm",
        "jaywalk_weight": config.jaywalk_weight,
        "particles": {method: config.particles_of(method) for method in METHODS}
        | {SMOOTHED_METHOD: config.particles_of("fused")},
        "gnss_sigma_factor": None,
    }


def _figures(
    results, layers, config, pooled_path, ratios, figdir, trust_rows
) -> list[tuple[str, str, bytes]]:
    base = figure_base(config)
    by_subset = {s: [r for r in results if subset_of(r) == s] for s in config.subsets}
    out = []
    for subset, runs in by_subset.items():
        name = f"fig1_tracks_{subset}.png"
        fig = fig_tracks(runs, layers, base, title=f"Fig. 1  Tracks, {subset}", max_panels=6)
        out.append((name, f"Fig. 1 tracks {subset}", save_png(fig, figdir / name)))
    fig3 = fig_particles(results, layers, base)
    if fig3 is not None:
        out.append(("fig3_particles.png", "Fig. 3 particles", save_png(fig3, figdir / "fig3_particles.png")))
    out.append(
        ("fig4_cdf.png", "Fig. 4 CDF", save_png(fig_cdf(results, base, by_subset), figdir / "fig4_cdf.png"))
    )
    for subset in config.subsets:
        part = pooled_path[pooled_path["subset"] == subset]
        name = f"fig5_per_route_{subset}.png"
        fig = fig_per_path(part, base, title=f"Fig. 5  Mean error per route, {subset}")
        out.append((name, f"Fig. 5 per route {subset}", save_png(fig, figdir / name)))
    fig6 = fig_session_medians(ratios, base, criteria.DoneWhen().session_ratio_max)
    out.append(("fig6_sessions.png", "Per-session medians", save_png(fig6, figdir / "fig6_sessions.png")))
    fig7 = fig_reliability(trust_rows, base)
    if fig7 is not None:
        name = "fig7_reliability.png"
        out.append((name, "segment_prob reliability", save_png(fig7, figdir / name)))
    return out


def _tables(
    pooled: pd.DataFrame,
    per_session: pd.DataFrame,
    checks: list[criteria.Check],
    config,
    counts: dict[str, int],
    events: dict[str, dict],
    run_info: dict[str, Any],
    ipin_scores: list[IpinScores],
    sure: dict[str, Table | None],
) -> list[Table]:
    """Every table of the report, in order."""
    w = config.jaywalk_weight
    limit = criteria.DoneWhen().session_ratio_max
    tables = [checks_table(checks)]
    for subset in config.subsets:
        tables.append(subset_table(pooled, subset, w, counts[subset], config.smoothing_lag_s))
        sweep = sweep_table(pooled, subset)
        if sweep is not None:
            tables.append(sweep)
    tables += [t for t in (sure["subsets"], map_table(pooled, w), sure["maps"], sure["confidence"])
               if t is not None]
    tables += [t for scores in ipin_scores for t in scores.tables()]
    tables.append(profile_table(run_info["simulation"], config.gnss))
    tables += [session_table(per_session, s, w, events, limit) for s in config.subsets]
    return tables


def _seeds(config) -> str:
    """``filter seed 0`` or ``filter seeds 0-2 pooled``."""
    first = config.filter_seed
    if config.filter_seeds == 1:
        return f"filter seed {first}"
    return f"filter seeds {first}-{first + config.filter_seeds - 1} pooled"


def _intro(config, counts, pooled, n_runs, timings, workers, checks) -> str:
    """The report's opening paragraph: what ran, on what, how long, and the verdict."""
    gnss_median = {
        s: _base(pooled[pooled["subset"] == s], config.jaywalk_weight)
        .query("method == 'gnss'")["euclid_median_m"].iat[0]
        for s in config.subsets
    }
    total_s = sum(timings.values())
    subsets = ", ".join(
        f"{s} {counts[s]} sessions (GNSS median {gnss_median[s]:.1f} m)" for s in config.subsets
    )
    stages = ", ".join(f"{k.removesuffix('_s')} {v:.0f} s" for k, v in timings.items())
    return (
        f"Profile '{config.profile}', GNSS '{config.gnss}', split '{config.split}', "
        f"{config.seeds} seed(s) per route: {subsets}. "
        f"{n_runs} runs, N = {config.particles} (curbside fused {config.particles_of('fused')}), "
        f"{_seeds(config)}, every method on the same "
        f"sessions{_preset_note(config.unseen_velocity)}. "
        f"Time: {total_s / 60:.1f} min ({stages}) with {workers} worker(s). "
        f"Done when: {criteria.overall(checks)}."
    )


def _preset_note(mode: str) -> str:
    """The report's note on curbside fused's ``unseen_velocity.mode`` when it is not its default."""
    return "" if mode == UnseenVelocityConfig().mode else f", curbside fused with --unseen-velocity {mode}"


def write_suite_report(
    results: list[dict],
    out_dir: str | Path,
    config: SuiteConfig,
    pooled: pd.DataFrame,
    per_session: pd.DataFrame,
    checks: list[criteria.Check],
    layers: MapLayers | None,
    run_info: dict[str, Any],
    timings: dict[str, float],
    ipin_scores: list[IpinScores] | None = None,
) -> dict[str, Path]:
    """Write ``report.md``, ``report.html``, ``metrics.json``, ``run.json`` and ``figures/`` atomically
    (``ipin_scores``: the held-out IPIN trials first, then any other scoring of them)."""
    from curbside.evaluate.suite import pooled_by_subset

    out_dir = Path(out_dir)
    w = config.jaywalk_weight
    counts = {
        s: int(per_session.loc[per_session["subset"] == s, "session"].nunique()) for s in config.subsets
    }
    session_dirs = {Path(r["spec"]["session"]).name: Path(r["spec"]["session"]) for r in results}
    events = {name: _events(path) for name, path in session_dirs.items()}
    ratios = criteria.session_ratios(per_session, "osm", w)
    pooled_path = _base(pooled_by_subset(results, ("path",)), w)
    ipin_scores = ipin_scores or []
    sure, sure_rows = interval_tables(results, config)
    tables = _tables(pooled, per_session, checks, config, counts, events, run_info, ipin_scores, sure)
    intro = _intro(config, counts, pooled, len(results), timings, run_info["workers"], checks)
    doc = {
        "generator": f"curbside {curbside.__version__}",
        "suite": run_info["suite"],
        "labels": METHOD_LABELS,
        "sessions_per_subset": counts,
        "done_when": {
            "overall": criteria.overall(checks),
            "checks": [c.__dict__ | {"verdict": c.verdict} for c in checks],
        },
        "pooled": records(pooled),
        **sure_rows,
        "per_session": records(per_session),
        "session_ratios": records(ratios),
        "session_events": events,
        **ipin_json(ipin_scores),
        "timings_s": timings,
    }
    with atomic_path(out_dir) as tmp:
        figdir = tmp / "figures"
        figdir.mkdir(parents=True)
        # figures: the filters' own tracks, first filter seed only
        filtered = [r for r in results
                    if r["spec"]["method"] != SMOOTHED_METHOD and r["spec"]["seed"] == config.filter_seed]
        figures = _figures(filtered, layers, config, pooled_path, ratios, figdir,
                           sure_rows["segment_prob_reliability"])
        (tmp / "metrics.json").write_text(json.dumps(json_ready(doc), indent=1), encoding="utf-8")
        (tmp / "run.json").write_text(
            json.dumps(json_ready({**run_info, "timings_s": timings}), indent=1), encoding="utf-8"
        )
        md = ["# curbside benchmark report", "", intro, ""]
        md += [t.markdown() for t in tables]
        md += [f"![{alt}](figures/{name})\n" for name, alt, _ in figures]
        md += [f"Map data {settings.osm_attribution}."]
        (tmp / "report.md").write_text("\n".join(md), encoding="utf-8")
        imgs = "".join(
            f"<figure><img alt='{alt}' src='data:image/png;base64,{base64.b64encode(data).decode()}'/>"
            "</figure>"
            for _, alt, data in figures
        )
        page = html_document(
            "curbside benchmark", _STYLE,
            f"<h1>curbside benchmark report</h1><p>{html.escape(intro)}</p>"
            f"{''.join(t.html() for t in tables)}{imgs}"
            f"<p class='note'>Map data {html.escape(settings.osm_attribution)}</p>",
        )
        (tmp / "report.html").write_text(page, encoding="utf-8")
    return {name: out_dir / name for name in ("metrics.json", "report.md", "report.html", "run.json")}
