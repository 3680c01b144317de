"""How long does a GNSS fix's error last? Measured against surveyed ground truth, real or simulated.

The fused filter tempers each fix by the share of an independent fix it carries
(``filter.gnss.correlation_time_s``), and the simulator draws its urban-canyon error as a Gauss-Markov
process (:mod:`curbside.evaluate.gnss_model`). Both stand on how long a fix's error persists. This
module measures it the same way on any recording with fixes and waypoints:

- **Fix errors.** Each fix minus the true position at its time, the straight line between the
  bracketing waypoints (:func:`curbside.evaluate.groundtruth.groundtruth_xy_at`); fixes outside the
  waypoints' span are dropped.
- **Windows.** The errors are put on a 1 s grid and cut into consecutive windows of ``window_s``
  seconds, so that walks of different lengths are read alike.
- **Persistence at lag L**: ``sum e(t) . e(t+L) / sum |e(t)|^2`` over the pairs in a window, the share
  of the error still there L seconds later (1: a constant offset; 0: independent fixes). For a
  Gauss-Markov error of time constant ``tau`` it reads about ``exp(-L / tau)``
  (:func:`ar1_reference` gives the exact figure for a window: 0.84 / 0.69 / 0.47 / 0.31 at 5 / 10 / 20
  / 30 s for ``tau`` 30 s over 90 s windows; a short window reads a little low at long lags).
- **Offset share**: ``|mean e|^2 / mean |e|^2`` over a window, how much of the error a single offset
  for the whole window explains.

``python benchmarks/gnss_persistence.py`` prints the table for the IPIN 2023 trials and for simulated
sessions side by side (docs/evaluate.md, "How long a fix's error lasts").
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from curbside.evaluate.gnss_model import gauss_markov
from curbside.evaluate.groundtruth import groundtruth_xy_at, waypoints_xy
from curbside.projection import LocalFrame

#: Lags (s) at which the persistence is read by default.
DEFAULT_LAGS_S = (5.0, 10.0, 20.0, 30.0)
#: An error longer than this many times its window's median is shortened to it: an outlier of 100 m
#: for a few seconds would otherwise outweigh a minute of metre-scale error (the filter has an outlier
#: component of its own for those; the tempering is about the rest).
CLIP = 3.0


def fix_errors(gnss: pd.DataFrame, waypoints: pd.DataFrame) -> pd.DataFrame:
    """Each fix's error against the waypoints' straight-line truth.

    Parameters
    ----------
    gnss
        ``t, lat, lon, accuracy_m`` (SPEC ``gnss.csv``).
    waypoints
        ``t, lat, lon`` ground-truth taps (at least two).

    Returns
    -------
    pandas.DataFrame
        ``t, east_m, north_m, accuracy_m`` for the fixes inside the waypoints' time span.
    """
    frame = LocalFrame.around(float(waypoints["lon"].iat[0]), float(waypoints["lat"].iat[0]))
    wt, wx, wy = waypoints_xy(waypoints, frame)
    inside = gnss[(gnss["t"] >= wt[0]) & (gnss["t"] <= wt[-1])]
    t = inside["t"].to_numpy(float)
    x, y = frame.to_xy(inside["lon"].to_numpy(), inside["lat"].to_numpy())
    truth = groundtruth_xy_at(wt, wx, wy, t)
    return pd.DataFrame({"t": t, "east_m": x - truth[:, 0], "north_m": y - truth[:, 1],
                         "accuracy_m": inside["accuracy_m"].to_numpy(float)})


def window_persistence(
    errors: pd.DataFrame, window_s: float = 90.0, lags_s: Sequence[float] = DEFAULT_LAGS_S
) -> pd.DataFrame:
    """Persistence and offset share of the errors in each whole window of ``window_s`` seconds.

    Parameters
    ----------
    errors
        ``t, east_m, north_m`` (:func:`fix_errors`); gaps between fixes are interpolated on the 1 s grid.
    window_s
        Window length (s); a tail shorter than a window is left out.
    lags_s
        Lags (s), each shorter than ``window_s``.

    Returns
    -------
    pandas.DataFrame
        One row per window: ``t0`` (its start), ``lag_<L>s`` per lag, ``offset_share``.
    """
    rows = []
    if len(errors) < 2:
        return pd.DataFrame(rows)
    t = errors["t"].to_numpy(float)
    grid = np.arange(t[0], t[-1] + 1e-9, 1.0)
    e = np.column_stack([np.interp(grid, t, errors[c].to_numpy(float)) for c in ("east_m", "north_m")])
    size = int(window_s)
    for start in range(0, len(grid) - size + 1, size):
        row = _window_row(e[start:start + size], lags_s)
        if row is not None:
            rows.append({"t0": float(grid[start]), **row})
    return pd.DataFrame(rows)


def _window_row(w: np.ndarray, lags_s: Sequence[float]) -> dict[str, float] | None:
    """Persistence at each lag and offset share of one window's ``(n, 2)`` errors (``None``: all zero);
    each error is first shortened to at most ``CLIP`` times the window's median error."""
    size = np.hypot(w[:, 0], w[:, 1])
    limit = CLIP * float(np.median(size))
    w = w * np.minimum(1.0, limit / np.maximum(size, 1e-9))[:, None]
    energy = float(np.sum(w * w))
    if energy <= 0:
        return None
    row = {f"lag_{lag:g}s": float(np.sum(w[:-int(lag)] * w[int(lag):]) / np.sum(w[:-int(lag)] ** 2))
           for lag in lags_s}
    row["offset_share"] = float(np.sum(w.mean(axis=0) ** 2) / (energy / len(w)))
    return row


def ar1_reference(
    tau_s: float, window_s: float = 90.0, lags_s: Sequence[float] = DEFAULT_LAGS_S,
    windows: int = 400, seed: int = 0,
) -> dict[str, float]:
    """What :func:`window_persistence` reads, at the median over ``windows`` independent windows, for a
    2-D Gauss-Markov error of time constant ``tau_s`` sampled at 1 Hz (the simulator's
    :func:`~curbside.evaluate.gnss_model.gauss_markov`, one per axis)."""
    rng = np.random.default_rng(seed)
    size = int(window_s)
    rows = [_window_row(np.column_stack([gauss_markov(size, 1.0, tau_s, rng) for _ in range(2)]), lags_s)
            for _ in range(windows)]
    table = pd.DataFrame(rows)
    return {c: float(table[c].median()) for c in table.columns}
