"""A session's streams as they arrive: inertial displacement, footstep times, GNSS fixes.

Each class here takes rows in time order, in chunks of any size (a whole file at once for a batch run,
a few rows per request for the live service), and says up to when its output is final
(``complete_until``): the engine (:mod:`curbside.localize.engine`) makes an update only when every
stream is final up to it, so that the same rows give the same updates however they were chunked.

- :class:`DisplacementIntegrator`: the cumulative inertial displacement ``D(t)`` (metres east/north) of
  a velocity stream, trapezoid rule for a sampled velocity, held means for per-step velocities, nothing
  across gaps.
- :class:`StepTimes`: footstep times from a file, a detector or a fixed cadence.
- :class:`FixStore`: the GNSS fixes in the local frame and the fix to use at an update.
"""

from __future__ import annotations

import math

import numpy as np

from curbside.localize.filter.parts import GnssFix


class _Series:
    """Rows ``(t, values...)`` appended in time order; old rows pruned once no query needs them."""

    def __init__(self, width: int) -> None:
        self.data = np.empty((0, width))
        self._chunks: list[np.ndarray] = []

    def append(self, rows: np.ndarray) -> None:
        if len(rows):
            self._chunks.append(np.asarray(rows, float))

    def rows(self) -> np.ndarray:
        if self._chunks:
            self.data = np.concatenate([self.data, *self._chunks])
            self._chunks = []
        return self.data

    def prune_before(self, t: float, keep: int = 2) -> None:
        """Drop rows before the ``keep``-th last row at or before ``t``."""
        data = self.rows()
        i = int(np.searchsorted(data[:, 0], t, side="right")) - keep
        if i > 64:  # prune in blocks, not at every query
            self.data = data[i:]


class DisplacementIntegrator:
    """Cumulative displacement ``D(t)`` of a velocity stream (see the module docstring).

    Parameters
    ----------
    max_gap_s
        Samples further apart are a gap: nothing is integrated across it.
    step_means
        ``True`` when each row holds the mean velocity since the previous row (PDR); ``False`` for a
        sampled velocity (RoNIN, ``velocity.csv``), integrated with the trapezoid rule.
    """

    def __init__(self, max_gap_s: float, step_means: bool = False) -> None:
        self.max_gap_s = max_gap_s
        self.step_means = step_means
        self.knots = _Series(3)  # t, D_east, D_north
        self._last: tuple[float, float, float, float] | None = None  # t, ve, vn, D_e, D_n of the last row
        self.first_t = math.nan

    @property
    def complete_until(self) -> float:
        """``D(t)`` is final for ``t`` up to the latest row."""
        return -math.inf if self._last is None else self._last[0]

    def push(self, t: np.ndarray, velocity_en: np.ndarray) -> None:
        """Append velocity rows (``t`` increasing, after every row pushed before)."""
        t = np.asarray(t, float)
        v = np.asarray(velocity_en, float).reshape(-1, 2)
        if len(t) == 0:
            return
        if self._last is None:
            self.first_t = float(t[0])
            t_all, v_all, d0 = t, v, np.zeros(2)
        else:
            lt, le, ln, de, dn = self._last
            t_all, v_all, d0 = np.concatenate([[lt], t]), np.vstack([[le, ln], v]), np.array([de, dn])
        dt = np.diff(t_all)
        if self.step_means:
            inc = v_all[1:] * dt[:, None]
        else:
            inc = 0.5 * (v_all[1:] + v_all[:-1]) * dt[:, None]
            inc[dt > self.max_gap_s] = 0.0
        # One running sum from d0 on, ((d0 + a) + b) + c: d0 + (a + b + c) would round differently, and
        # D(t) would depend on where the chunks end (the live service's last digits against the batch's).
        d = np.cumsum(np.vstack([d0, inc]), axis=0)
        if self._last is not None:
            d = d[1:]
        self.knots.append(np.column_stack([t, d]))
        self._last = (float(t[-1]), float(v[-1, 0]), float(v[-1, 1]), float(d[-1, 0]), float(d[-1, 1]))

    def at(self, t: float) -> np.ndarray:
        """``D(t)``: linear between rows, constant before the first and after the last."""
        data = self.knots.rows()
        if len(data) == 0:
            return np.zeros(2)
        return np.array([np.interp(t, data[:, 0], data[:, 1]), np.interp(t, data[:, 0], data[:, 2])])

    def forget_before(self, t: float) -> None:
        """No query will come before ``t`` any more."""
        self.knots.prune_before(t)


class StepTimes:
    """Footstep times known so far and up to when they are final.

    A file's or a detector's steps are pushed with the time up to which the source has reported every
    step; a fixed cadence generates its own.
    """

    def __init__(self, cadence_s: float | None = None) -> None:
        self.cadence_s = cadence_s
        self.times = _Series(1)
        self.complete_until = -math.inf
        self._next_cadence = math.nan

    def push(self, times: np.ndarray, complete_until: float) -> None:
        """New step times (increasing, after earlier ones) and the time up to which all are reported."""
        times = np.asarray(times, float)
        self.times.append(times[:, None])
        self.complete_until = max(self.complete_until, float(complete_until))

    def extend_cadence(self, t0: float, until: float) -> None:
        """Fixed-cadence steps from ``t0`` on, up to ``until``."""
        if math.isnan(self._next_cadence):
            self._next_cadence = t0
        k = np.arange(self._next_cadence, until + 1e-9, self.cadence_s)
        if len(k):
            self.push(k, until)
            self._next_cadence = float(k[-1]) + self.cadence_s
        else:
            self.complete_until = max(self.complete_until, until)

    def next_after(self, t: float) -> float:
        """The first step time after ``t`` (inf if none known yet)."""
        data = self.times.rows()[:, 0]
        i = int(np.searchsorted(data, t, side="right"))
        return float(data[i]) if i < len(data) else math.inf

    def forget_before(self, t: float) -> None:
        """No query will come before ``t`` any more."""
        self.times.prune_before(t)


class FixStore:
    """GNSS fixes in the local frame and the rule that gives the fix to use at an update.

    Parameters
    ----------
    association
        ``interpolate`` or ``once`` (see :class:`curbside.localize.runconfig.EngineConfig`).
    interp_max_gap_s, max_fix_age_s
        Interpolation between fixes at most this far apart; else the latest fix not older than this.
    """

    def __init__(self, association: str, interp_max_gap_s: float, max_fix_age_s: float) -> None:
        self.association = association
        self.interp_max_gap_s = interp_max_gap_s
        self.max_fix_age_s = max_fix_age_s
        self.fixes = _Series(4)  # t, x, y, accuracy_m (valid fixes only)
        self._used_until = -math.inf

    def push(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, accuracy_m: np.ndarray) -> None:
        """Append fixes; invalid ones (accuracy not positive, anything not finite) are dropped."""
        rows = np.column_stack([t, x, y, accuracy_m]).astype(float)
        ok = np.isfinite(rows).all(axis=1) & (rows[:, 3] > 0)
        self.fixes.append(rows[ok])

    def at(self, t: float, hold_forever: bool = False) -> GnssFix | None:
        """The fix to use at an update at ``t`` (``None`` where there is none).

        ``hold_forever``: beyond the interpolation gap, hold the latest fix whatever its age (what a
        phone shows; the ``gnss`` method).
        """
        data = self.fixes.rows()
        if len(data) == 0:
            return None
        prev = int(np.searchsorted(data[:, 0], t, side="right")) - 1
        if self.association == "once" and not hold_forever:
            fresh = prev >= 0 and data[prev, 0] > self._used_until and t - data[prev, 0] <= self.max_fix_age_s
            self._used_until = t
            return GnssFix(*map(float, data[prev, 1:])) if fresh else None
        if prev < 0:
            return None
        p = data[prev]
        if prev + 1 < len(data):
            q = data[prev + 1]
            if t - p[0] <= self.interp_max_gap_s and q[0] - t <= self.interp_max_gap_s:
                a = (t - p[0]) / (q[0] - p[0])
                return GnssFix(*map(float, p[1:] + a * (q[1:] - p[1:])))
        if hold_forever or t - p[0] <= self.max_fix_age_s:
            return GnssFix(*map(float, p[1:]))
        return None

    def forget_before(self, t: float) -> None:
        """No query will come before ``t`` any more."""
        self.fixes.prune_before(t)
