"""How far a phone's GNSS fixes trail its walker: estimated from a recording, compensated per update.

A phone reports the output of its receiver's own smoothing filter, not raw positions, so the fixes lag
the walk: on the IPIN 2023 trials they trail the surveyed walker by 2.0 m along the walking direction at
the median (docs/filter.md, "Fixes that trail the walker"). A first-order lag of ``T`` seconds turns the
true path ``x(t)`` into ``EMA_T(x)(t)``, which trails it by ``x - EMA_T(x)``: about ``T`` times the
speed on a straight walk, less round a corner, and nothing at a standstill once ``T`` has passed.

- :func:`estimate_fix_lag` chooses ``T`` from a whole recording. For each candidate it lags the inertial
  displacement ``D(t)`` by ``T``, fits the fixes to it block by block with a 2-D similarity (rotation,
  scale, shift: the inertial heading bias, speed scale and start are unknown), and scores the median
  residual. A lag is chosen only when it explains the fixes clearly better than none, and in most
  blocks (:class:`~curbside.localize.runconfig.FixLagConfig`).
- :class:`LagCompensator` gives, at each update, the vector ``D(t) - EMA_T(D)(t)`` that moves a fix
  forward to where the walker is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from curbside.localize.runconfig import FixLagConfig
from curbside.localize.streams import DisplacementIntegrator

#: Time step of the grid the estimate resamples the inertial displacement on (s).
GRID_S = 0.1


@dataclass(frozen=True)
class FixLagEstimate:
    """What :func:`estimate_fix_lag` found.

    Attributes
    ----------
    lag_s
        The chosen lag (0: none).
    residual_m
        Per candidate lag (0 first), the mean over blocks of the fixes' median residual from the lagged
        inertial track (m); empty when no block had enough fixes.
    blocks
        How many blocks were scored.
    block_share
        The share of them in which the best candidate beats no lag (0 when the best is no lag).
    """

    lag_s: float
    residual_m: dict[float, float]
    blocks: int
    block_share: float

    def to_dict(self) -> dict[str, object]:
        """JSON-ready (``run.json``'s ``fix_lag``)."""
        return {
            "mode": "auto",
            "lag_s": self.lag_s,
            "blocks": self.blocks,
            "block_share": round(self.block_share, 3),
            "residual_m": {f"{lag:g}": round(r, 4) for lag, r in self.residual_m.items()},
        }


def lagged(d: np.ndarray, lag_s: float, dt_s: float) -> np.ndarray:
    """``EMA_T(D)`` of a displacement sampled every ``dt_s`` (starting at rest at ``D[0]``)."""
    if lag_s == 0:
        return d
    a = math.exp(-dt_s / lag_s)
    return d[0] + lfilter([1.0 - a], [1.0, -a], d - d[0], axis=0)


def _similarity_residual(inertial: np.ndarray, fixes: np.ndarray, weight: np.ndarray) -> float:
    """Median distance of ``fixes`` from the weighted least-squares 2-D similarity of ``inertial``."""
    p = inertial[:, 0] + 1j * inertial[:, 1]
    q = fixes[:, 0] + 1j * fixes[:, 1]
    root_w = np.sqrt(weight)
    design = np.column_stack([p, np.ones_like(p)]) * root_w[:, None]
    (turn_scale, shift), *_ = np.linalg.lstsq(design, q * root_w, rcond=None)
    return float(np.median(np.abs(q - (turn_scale * p + shift))))


def estimate_fix_lag(
    fix_t_s: np.ndarray,
    fix_xy_m: np.ndarray,
    accuracy_m: np.ndarray,
    displacement: DisplacementIntegrator,
    config: FixLagConfig,
) -> FixLagEstimate:
    """Choose the fixes' lag from a whole recording.

    Parameters
    ----------
    fix_t_s, fix_xy_m, accuracy_m
        The fixes: times, local metric positions ``(n, 2)`` and reported accuracies (m).
    displacement
        The inertial displacement the filter moves with, every velocity row pushed.
    config
        Candidates, blocks and the acceptance ratio.

    Returns
    -------
    FixLagEstimate
        Lag 0 unless a candidate's mean residual is under ``config.ratio_max`` times that of no lag and
        it beats no lag in at least ``config.min_block_share`` of the blocks (a receiver's lag is there
        all walk; a run of correlated canyon error that happens to look like one is not).
    """
    usable = np.isfinite(accuracy_m) & (accuracy_m > 0) & (accuracy_m <= config.accuracy_max_m)
    t_first, t_last = displacement.first_t, displacement.complete_until
    usable &= (fix_t_s >= t_first) & (fix_t_s <= t_last)
    t, xy, acc = fix_t_s[usable], fix_xy_m[usable], accuracy_m[usable]
    if len(t) < config.min_fixes:
        return FixLagEstimate(0.0, {}, 0, 0.0)
    grid = np.arange(t_first, t_last + GRID_S, GRID_S)
    d_grid = displacement.at(grid).T
    weight = 1.0 / np.maximum(acc, 3.0) ** 2  # a 3 m floor: a fix reporting 1 m does not own the fit
    lags = (0.0, *config.candidates_s)
    at_fixes = []
    for lag in lags:
        e = lagged(d_grid, lag, GRID_S)
        at_fixes.append(np.column_stack([np.interp(t, grid, e[:, k]) for k in range(2)]))
    per_block = []  # (blocks, lags) median residuals
    for start in np.arange(t[0], t[-1] - config.block_s / 2, config.hop_s):
        rows = (t >= start) & (t < start + config.block_s)
        if rows.sum() >= config.min_fixes:
            per_block.append([_similarity_residual(p[rows], xy[rows], weight[rows]) for p in at_fixes])
    if not per_block:
        return FixLagEstimate(0.0, {}, 0, 0.0)
    residuals = np.array(per_block)
    means = residuals.mean(axis=0)
    best = int(np.argmin(means))
    share = float(np.mean(residuals[:, best] < residuals[:, 0])) if best else 0.0
    chosen = means[best] < config.ratio_max * means[0] and share >= config.min_block_share
    by_lag = {lg: float(m) for lg, m in zip(lags, means, strict=True)}
    return FixLagEstimate(lags[best] if chosen else 0.0, by_lag, len(residuals), share)


class LagCompensator:
    """Per update, the vector that moves a fix lagging by ``lag_s`` forward to the walker.

    It follows ``EMA_T(D)`` exactly for a displacement linear between updates, so any spacing of the
    updates gives the same lag.
    """

    def __init__(self, lag_s: float) -> None:
        self.lag_s = float(lag_s)
        self._last: tuple[float, np.ndarray, np.ndarray] | None = None  # t, D, EMA(D)

    def offset(self, t: float, d: np.ndarray) -> np.ndarray:
        """``D(t) - EMA_T(D)(t)`` for the inertial displacement ``d`` at update time ``t`` (in order)."""
        if self._last is None:
            ema = np.array(d, float)
        else:
            t0, d0, ema0 = self._last
            dt = t - t0
            if dt <= 0:
                ema = ema0
            else:
                slope = (d - d0) / dt
                a = math.exp(-dt / self.lag_s)
                ema = d - self.lag_s * slope + a * (ema0 - d0 + self.lag_s * slope)
        self._last = (t, np.array(d, float), ema)
        return d - ema
