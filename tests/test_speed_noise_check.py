"""benchmarks/speed_noise_check.py: a walk's spread takes its own speed scale out."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
from speed_noise_check import main, summary_row, walk_spread  # noqa: E402


def test_walk_spread_is_relative_to_the_walks_own_scale():
    ratios = np.array([0.9, 1.0, 1.1, 1.0, 1.0])
    assert walk_spread(ratios) == pytest.approx(np.std(ratios))
    assert walk_spread(1.2 * ratios) == pytest.approx(np.std(ratios))  # a per-walk scale does not count
    assert math.isnan(walk_spread(ratios[:3]))  # too few windows


def test_summary_row_skips_walks_without_a_spread():
    row = summary_row("x", [0.1, float("nan"), 0.2, 0.3], 5.0)
    assert row["walks"] == 3
    assert row["spread_median"] == pytest.approx(0.2)


def test_nothing_to_measure_or_a_missing_folder_exits_with_status_2(tmp_path, capsys):
    for argv in ([], ["--sessions", str(tmp_path / "absent")]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
    assert "absent: no such file or folder" in capsys.readouterr().err
