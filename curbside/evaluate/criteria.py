"""The "done when" of issue 9, checked on benchmark figures: PASS or FAIL per criterion.

On every subset, curbside fused must beat the paper's method (``paper``) on CSA, median and p90
Euclidean error, and be no worse than GNSS alone on the same three; no session's fused median may
exceed :attr:`DoneWhen.session_ratio_max` times its GNSS median. On ``paper6`` the fused filter must
reach absolute targets. With the DataSF buildings in place of OSM's, fused CSA may fall by at most
:attr:`DoneWhen.datasf_csa_drop_max`. On the held-out IPIN 2023 trials (real phones, no map) the
fused errors at the surveyed waypoints must not regress against version 0.1's
fused filter run beside it (:data:`FUSED_0_1_OVERRIDES`).

All inputs are tables of pooled metrics (:func:`curbside.evaluate.runner.pool` output with a
``subset`` column), so the checks are plain functions, testable without running a filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

#: The run the IPIN criterion must not regress from: version 0.1's fused filter, i.e. today's fused
#: defaults with 0.1's particle count (500), motion and resampling (no speed-scale state or correction,
#: heading noise 0.5 deg, step noise 15 %, resampling at every update, injection without heading
#: jitter and at 0.1's trigger ratio, no stall trigger, no heading correction from the fixes, no switch
#: to the unseen-velocity or the familiar-velocity motion model, no street-heading likelihood, no
#: compensation of the fixes' lag)
#: and 0.1's GNSS tempering (one correlation time for every fix, whatever its accuracy).
#: The benchmark runs it on the same held-out trials and waypoints as the fused filter it judges (a
#: figure from an older run would have been measured on another set of waypoints).
IPIN_BASELINE_RUN = "curbside fused 0.1"
FUSED_0_1_OVERRIDES: dict[str, object] = {
    "filter.n_particles": 500,
    "filter.resample.policy": "always",
    "filter.motion.scale_init_sigma": 0.0,
    "filter.motion.scale_noise_per_step": 0.0,
    "filter.motion.heading_noise_deg": 0.5,
    "filter.motion.step_noise_fraction": 0.15,
    "filter.recovery.inject_heading_sigma_deg": 0.0,
    "filter.recovery.trigger_ratio": 0.5,
    "filter.recovery.stall_ratio": 0.0,
    "filter.scale_correction.fraction": 0.0,
    "filter.heading_correction.fraction": 0.0,
    "filter.gnss.correlation_accuracy_m": 0.0,
    "filter.street_heading.strength_per_m": 0.0,
    "unseen_velocity.mode": "off",
    "familiar_velocity.mode": "off",
    "fix_lag.mode": "off",
}


@dataclass(frozen=True)
class DoneWhen:
    """The thresholds of the criteria (issue 9)."""

    session_ratio_max: float = 1.5
    paper6_csa_min: float = 0.90
    paper6_median_max_m: float = 4.0
    paper6_p90_max_m: float = 12.0
    paper6_across_max_m: float = 1.5
    datasf_csa_drop_max: float = 0.05
    #: Metric rounding allowed when comparing against the IPIN baseline (m).
    ipin_tolerance_m: float = 0.05


@dataclass
class Check:
    """One criterion on one scope: what was compared, and whether it passed (``None``: not run)."""

    criterion: str
    scope: str
    value: str
    passed: bool | None

    def __post_init__(self) -> None:
        if self.passed is not None:
            self.passed = bool(self.passed)  # numpy booleans are not ``False`` by identity

    @property
    def verdict(self) -> str:
        """``PASS``, ``FAIL`` or ``n/a``."""
        return "n/a" if self.passed is None else ("PASS" if self.passed else "FAIL")


_NAMES = {
    "csa": "CSA",
    "euclid_median_m": "median",
    "euclid_p90_m": "p90",
    "across_median_m": "across median",
}


def _row(pooled: pd.DataFrame, subset: str, method: str, map_name: str, w: float) -> pd.Series | None:
    sel = (pooled["subset"] == subset) & (pooled["method"] == method) & (pooled["map"] == map_name)
    if method != "gnss":
        sel &= pooled["jaywalk_weight"] == w
    rows = pooled[sel]
    return rows.iloc[0] if len(rows) else None


def _fmt(value: float, metric: str) -> str:
    if value is None or not math.isfinite(value):
        return "n/a"
    return f"{value:.2f}" if metric == "csa" else f"{value:.1f} m"


def _compare(fused: float, other: float, metric: str, strict: bool) -> bool:
    """Fused better than (``strict``) or no worse than ``other``: higher CSA, lower errors."""
    if not (math.isfinite(fused) and math.isfinite(other)):
        return False
    if metric == "csa":
        return fused > other if strict else fused >= other
    return fused < other if strict else fused <= other


def subset_checks(pooled: pd.DataFrame, map_name: str, w: float) -> list[Check]:
    """Fused against the paper's method (strictly better) and GNSS (no worse), per subset."""
    checks = []
    for subset in pooled["subset"].unique():
        fused = _row(pooled, subset, "fused", map_name, w)
        for other, strict, verb in (
            ("paper", True, "beats the paper's method"),
            ("gnss", False, "no worse than GNSS"),
        ):
            ref = _row(pooled, subset, other, map_name, w)
            for metric in ("csa", "euclid_median_m", "euclid_p90_m"):
                label = f"fused {verb} on {_NAMES[metric]}"
                if fused is None or ref is None:
                    checks.append(Check(label, subset, "not run", None))
                    continue
                value = f"{_fmt(fused[metric], metric)} vs {_fmt(ref[metric], metric)}"
                checks.append(
                    Check(label, subset, value, _compare(fused[metric], ref[metric], metric, strict))
                )
    return checks


def session_checks(per_session: pd.DataFrame, map_name: str, w: float, limit: float) -> list[Check]:
    """Every session's fused median at most ``limit`` x its GNSS median (one check per subset)."""
    checks = []
    ratios = session_ratios(per_session, map_name, w)
    for subset, rows in ratios.groupby("subset", sort=False):
        worst = rows.loc[rows["ratio"].idxmax()]
        over = int((rows["ratio"] > limit).sum())
        value = f"worst {worst['ratio']:.2f} ({worst['session']}); {over} of {len(rows)} over {limit:g}"
        checks.append(
            Check(f"every session's fused median <= {limit:g} x GNSS median", subset, value, over == 0)
        )
    return checks


def session_ratios(per_session: pd.DataFrame, map_name: str, w: float) -> pd.DataFrame:
    """``subset, session, gnss, paper, fused, ratio`` (medians in m; ratio = fused / GNSS)."""
    base = per_session[per_session["map"] == map_name]
    base = base[(base["method"] == "gnss") | (base["jaywalk_weight"] == w)]
    wide = base.pivot_table(
        index=["subset", "session"], columns="method", values="euclid_median_m", sort=False
    )
    wide = wide.reset_index()
    for method in ("gnss", "paper", "fused"):
        if method not in wide:
            wide[method] = float("nan")
    wide["ratio"] = wide["fused"] / wide["gnss"]
    return wide[["subset", "session", "gnss", "paper", "fused", "ratio"]]


def paper6_checks(pooled: pd.DataFrame, map_name: str, w: float, t: DoneWhen) -> list[Check]:
    """The absolute targets on the paper-like subset."""
    fused = _row(pooled, "paper6", "fused", map_name, w)
    targets = (
        ("csa", t.paper6_csa_min, ">="),
        ("euclid_median_m", t.paper6_median_max_m, "<="),
        ("euclid_p90_m", t.paper6_p90_max_m, "<="),
        ("across_median_m", t.paper6_across_max_m, "<="),
    )
    checks = []
    for metric, bound, op in targets:
        shown = f"{bound:.2f}" if metric == "csa" else f"{bound:g} m"
        label = f"fused {_NAMES[metric]} {op} {shown}"
        if fused is None:
            checks.append(Check(label, "paper6", "not run", None))
            continue
        value = fused[metric]
        ok = math.isfinite(value) and (value >= bound if op == ">=" else value <= bound)
        checks.append(Check(label, "paper6", _fmt(value, metric), ok))
    return checks


def datasf_checks(
    pooled: pd.DataFrame, osm_map: str, datasf_map: str | None, w: float, drop: float
) -> list[Check]:
    """Fused CSA with the DataSF buildings within ``drop`` of the OSM map's, per subset."""
    checks = []
    for subset in pooled["subset"].unique():
        label = f"fused CSA with DataSF buildings within {drop:g} of OSM's"
        osm = _row(pooled, subset, "fused", osm_map, w)
        other = _row(pooled, subset, "fused", datasf_map, w) if datasf_map else None
        if osm is None or other is None:
            checks.append(Check(label, subset, "not run (pass DataSF tiles)", None))
            continue
        value = f"{other['csa']:.2f} vs {osm['csa']:.2f}"
        checks.append(Check(label, subset, value, bool(osm["csa"] - other["csa"] <= drop)))
    return checks


def ipin_checks(
    fused: dict[str, float] | None, baseline: dict[str, float], tolerance_m: float
) -> list[Check]:
    """Fused median and p90 at the IPIN waypoints no worse than ``baseline`` (``None``: not run)."""
    checks = []
    for key, name in (("median_m", "median"), ("p90_m", "p90")):
        label = f"IPIN held-out fused {name} does not regress"
        if fused is None:
            checks.append(Check(label, "ipin2023", "not run (pass --ipin)", None))
            continue
        ref = baseline.get(key, float("nan"))
        if not math.isfinite(ref):
            checks.append(Check(label, "ipin2023", f"{fused[key]:.2f} m (no baseline)", None))
            continue
        checks.append(
            Check(label, "ipin2023", f"{fused[key]:.2f} vs {ref:.2f} m", fused[key] <= ref + tolerance_m)
        )
    return checks


def done_when(
    pooled: pd.DataFrame,
    per_session: pd.DataFrame,
    w: float = 0.4,
    osm_map: str = "osm",
    datasf_map: str | None = None,
    ipin_fused: dict[str, float] | None = None,
    thresholds: DoneWhen | None = None,
    ipin_baseline: dict[str, float] | None = None,
) -> list[Check]:
    """Every criterion of issue 9 on benchmark figures.

    Parameters
    ----------
    pooled
        Metrics pooled per ``subset, map, method, jaywalk_weight``.
    per_session
        The same per ``session`` too.
    w
        The jaywalk weight the criteria are judged at.
    osm_map, datasf_map
        Map names of the OSM map and of the DataSF-buildings map (``None``: not run).
    ipin_fused
        Fused ``median_m`` and ``p90_m`` on the held-out IPIN trials (``None``: not run).
    thresholds
        The criteria's numbers.
    ipin_baseline
        ``median_m`` and ``p90_m`` not to regress from: the :data:`IPIN_BASELINE_RUN` of the same run
        (``None``: that criterion has no baseline and is not evaluated).
    """
    t = thresholds or DoneWhen()
    checks = subset_checks(pooled, osm_map, w)
    checks += session_checks(per_session, osm_map, w, t.session_ratio_max)
    if (pooled["subset"] == "paper6").any():
        checks += paper6_checks(pooled, osm_map, w, t)
    checks += datasf_checks(pooled, osm_map, datasf_map, w, t.datasf_csa_drop_max)
    checks += ipin_checks(ipin_fused, ipin_baseline or {}, t.ipin_tolerance_m)
    return checks


def overall(checks: list[Check]) -> str:
    """One line: ``PASS`` only when every criterion was evaluated and passed."""
    failed = sum(c.passed is False for c in checks)
    missing = sum(c.passed is None for c in checks)
    verdict = "PASS" if failed == 0 and missing == 0 else "FAIL"
    return f"{verdict}: {len(checks) - failed - missing} passed, {failed} failed, {missing} not evaluated"
