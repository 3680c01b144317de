"""The paper's tables: Tables 2-4 of Dubiner, Ren and Manduchi beside the paper's own numbers, the
posterior-mode, map-source and sweep tables, and :class:`Table`, which renders every table of the reports
as Markdown and HTML (:mod:`curbside.evaluate.report` writes them into the report).
"""

from __future__ import annotations

import html
import math
from typing import Any

import pandas as pd

from curbside.evaluate.runner import METHOD_LABELS, METHODS, MODE_SUFFIX
from curbside.localize.filter.config import MapConfig

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


def paper_header(method: str) -> str:
    """The header of a method's column beside the paper: what the parenthesised figure is. The paper has
    no curbside fused; beside it stands the paper's own best, its GNSS+RoNIN+PF ("paper PF")."""
    source = "paper's PF" if method == "fused" else "paper"
    return f"{METHOD_LABELS[method]} ({source})"


#: The note on the parentheses under the tables beside the paper.
PAPER_NOTE = (
    "In parentheses: the paper's figure for the same method on its real walks; under curbside fused, "
    "which the paper does not have, the paper's GNSS+RoNIN+PF (paper PF) figure, the one to beat."
)


def paper_value(name: str, method: str, jaywalk_weight: float | None = None) -> float | None:
    """The paper's published figure for a metric and method (``paper`` and ``fused`` both show the
    paper's GNSS+RoNIN+PF column); ``None`` where the paper has none."""
    column = "fused" if method == "paper" else method
    table = PAPER.get(name)
    if table is None:
        return None
    if name == "csa":
        table = table.get(round(float(jaywalk_weight if jaywalk_weight is not None else 0.4), 2), {})
    return table.get(column)


def fmt_value(value: Any, digits: int = 2) -> str:
    """A table cell: ``n/a`` for missing or non-finite values, ``digits`` decimals for floats."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _td(cell: str) -> str:
    """An HTML cell; a ``PASS`` or ``FAIL`` verdict gets the class ``pass`` or ``fail``."""
    cls = f" class='{cell.lower()}'" if cell in ("PASS", "FAIL") else ""
    return f"<td{cls}>{html.escape(cell)}</td>"


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
        body = "".join("<tr>" + "".join(_td(c) for c in r) + "</tr>" for r in self.rows)
        note = f"<p class='note'>{html.escape(self.note)}</p>" if self.note else ""
        # wrapped: a table wider than a phone's screen scrolls on its own, the page's text does not
        return (f"<h3>{html.escape(self.title)}</h3><div class='table'><table><tr>{head}</tr>{body}</table>"
                f"</div>{note}")


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


#: Why curbside's filter and the paper's method respond differently to the jaywalk weight (Table 2).
CROSSING_NOTE = (
    "w weighs a particle on the street. Curbside's filter (RoNIN+PF, curbside fused) weighs a step across "
    f"the street outside a crosswalk at least {MapConfig().crossing_weight:g}, whatever w "
    "(filter.map.crossing_weight); the paper's method weighs w at every footstep."
)


def paper_tables(pooled: pd.DataFrame, map_name: str, base: dict[str, Any]) -> list[Table]:
    """Tables 2, 3 and 4 of the paper for one map source, beside the paper's numbers."""
    methods = [m for m in METHODS if (pooled["method"] == m).any()]
    header = [""] + [paper_header(m) for m in methods]
    where = {"map": map_name, "particles": base["particles"], "gnss_sigma_factor": base["gnss_sigma_factor"]}
    rows2 = []
    for w in sorted(pooled.loc[pooled["method"] != "gnss", "jaywalk_weight"].unique()):
        row = [f"w = {w:g}"]
        for m in methods:
            r = _lookup(pooled, m, jaywalk_weight=w, **where)
            paper = paper_value("csa", m, w)
            row.append(f"{fmt_value(None if r is None else r['csa'])} ({fmt_value(paper)})")
        rows2.append(row)
    tables = [
        Table(
            f"Table 2. Correct Sidewalk Assignment, map '{map_name}'",
            header,
            rows2,
            f"Pooled over all footsteps; GNSS does not depend on w. {PAPER_NOTE} {CROSSING_NOTE}",
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
                ours = fmt_value(None if r is None else r[name], 1)
                row.append(f"{ours} ({fmt_value(paper_value(name, m), 1)})")
            rows.append(row)
        tables.append(Table(f"{title}, w = {w0:g}, map '{map_name}'", header, rows, PAPER_NOTE))
    rows = []
    for name in ("ate_m", "rte_m"):
        row = [name]
        for m in methods:
            r = _lookup(pooled, m, jaywalk_weight=w0, **where)
            row.append(fmt_value(None if r is None else r[name], 1))
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
            row.append("-" if r is None else f"{fmt_value(r['csa'])} / {fmt_value(r[f'csa{MODE_SUFFIX}'])}")
        rows.append(row)
    header = [""] + [METHOD_LABELS[m] for m in methods]
    errors = []
    for name in ("euclid_mean_m", "euclid_median_m", "euclid_p90_m", "along_median_m", "across_median_m"):
        row = [name]
        for m in methods:
            r = _lookup(pooled, m, jaywalk_weight=w0, **where)
            mode = None if r is None else r[f"{name}{MODE_SUFFIX}"]
            row.append("-" if r is None else f"{fmt_value(r[name], 1)} / {fmt_value(mode, 1)}")
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
                    [map_name, METHOD_LABELS[m]] + [fmt_value(r[n], 2 if n == "csa" else 1) for n in names]
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
                fmt_value(r["csa"]),
                fmt_value(r["euclid_median_m"], 1),
                fmt_value(r["euclid_p90_m"], 1),
                fmt_value(r["across_median_m"], 1),
            ]
            for _, r in sub.iterrows()
        ]
        header = ["map", "method", labels[param], "csa", "euclid_median_m", "euclid_p90_m", "across_median_m"]
        tables.append(Table(f"Sweep: {labels[param]}", header, rows))
    return tables
