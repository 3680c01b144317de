"""The report's tables beside the paper: what each parenthesised figure is."""

from __future__ import annotations

import pandas as pd

from curbside.evaluate.report_tables import paper_tables, paper_value

BASE = {"map": "osm", "jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}
NAMES = ("csa", "euclid_mean_m", "euclid_median_m", "euclid_p90_m", "along_median_m", "across_median_m",
         "ate_m", "rte_m")


def _pooled() -> pd.DataFrame:
    rows = []
    for method in ("gnss", "inertial", "paper", "fused"):
        for w in (0.0, 0.4, 1.0):
            rows.append({"map": "osm", "method": method, "jaywalk_weight": w, "particles": 500,
                         "gnss_sigma_factor": None, **dict.fromkeys(NAMES, 0.5)})
    return pd.DataFrame(rows)


def test_the_fused_column_says_its_parentheses_hold_the_papers_pf():
    table2, table3, table4 = paper_tables(_pooled(), "osm", BASE)[:3]
    for table in (table2, table3, table4):
        assert table.header[1:] == ["GNSS (paper)", "RoNIN+PF (paper)", "paper PF (paper)",
                                    "curbside fused (paper's PF)"]
        assert "under curbside fused, which the paper does not have" in table.note
    w0 = next(r for r in table2.rows if r[0] == "w = 0")
    assert w0[-1] == f"0.50 ({paper_value('csa', 'paper', 0.0):.2f})"  # the paper PF's figure, 0.30
    assert "| curbside fused (paper's PF) |" in table3.markdown()
