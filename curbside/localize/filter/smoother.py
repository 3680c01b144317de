"""Fixed-lag smoothing from the particles' genealogy: an opt-in output for offline analysis.

The filter's estimate at time ``t`` uses the data up to ``t``. Offline, where the walker was at ``t``
is better told by what came after too: a corner turned ten seconds later shows which sidewalk the
particles that survive it were on. The smoother keeps every particle's position at each update; when
the resampler redraws the cloud, each kept position follows its particle's parent
(:attr:`~curbside.localize.filter.particles.ParticleSet.ancestors`), so column ``i`` of the buffer is
the past path of today's particle ``i``. Weighting those paths by today's weights estimates the
position ``lag_s`` seconds ago given everything seen since, ``p(x_{t-L} | z_{1:t})`` (Kitagawa 1996;
Doucet & Johansen 2009, section 4.2). Once an update is ``lag_s`` old its smoothed position is final.

The paths degenerate as the lag grows (resampling leaves fewer distinct ancestors far back), so a lag
of seconds to a few tens of seconds is the useful range. Particles that a recovery re-draws (a
collapse, a divergence injection) keep the path of the particle whose slot they take: their own past
is unknown. The filter's estimates are untouched; ``localize serve`` reports filtered estimates only.
"""

from __future__ import annotations

import math

import numpy as np

from curbside.localize.filter.config import SmootherConfig
from curbside.localize.filter.particles import ParticleSet, X, Y


class FixedLagSmoother:
    """Keeps the particles' recent paths and smooths each update ``lag_s`` later (module docstring).

    Parameters
    ----------
    config
        The lag.
    n
        Number of particles.
    capacity
        Updates the buffer holds before it grows (it doubles as needed).
    """

    def __init__(self, config: SmootherConfig, n: int, capacity: int = 64) -> None:
        self.lag_s = float(config.lag_s)
        self._t = np.empty(capacity)
        self._xy = np.empty((capacity, 2, n))
        self._head = 0  # oldest update not yet smoothed
        self._tail = 0  # next free slot

    def __len__(self) -> int:
        """Updates kept and not yet smoothed."""
        return self._tail - self._head

    def record(self, t: float, particles: ParticleSet, resampled: bool) -> np.ndarray:
        """After an update: follow the genealogy, keep the positions, smooth the updates ``lag_s`` old.

        Parameters
        ----------
        t
            Time of the update.
        particles
            The cloud after the update (weights normalised).
        resampled
            Whether the update resampled (then ``particles.ancestors`` holds the parents).

        Returns
        -------
        numpy.ndarray
            ``(m, 3)`` rows ``t, x, y`` of the updates smoothed now, oldest first (often ``m = 0``).
        """
        if resampled and len(self):
            live = slice(self._head, self._tail)
            self._xy[live] = self._xy[live][:, :, particles.ancestors]
        self._append(t, particles.state[X : Y + 1])
        return self._emit(particles.weights, t - self.lag_s)

    def flush(self, particles: ParticleSet) -> np.ndarray:
        """At the end of the data: smooth every update still kept (the same rows as :meth:`record`)."""
        return self._emit(particles.weights, math.inf)

    def _emit(self, weights: np.ndarray, until_t: float) -> np.ndarray:
        stop = self._head + int(np.searchsorted(self._t[self._head : self._tail], until_t, side="right"))
        if stop == self._head:
            return np.empty((0, 3))
        xy = self._xy[self._head : stop] @ weights
        out = np.column_stack([self._t[self._head : stop], xy])
        self._head = stop
        return out

    def _append(self, t: float, xy: np.ndarray) -> None:
        if self._tail == len(self._t):
            kept = len(self)
            if kept > len(self._t) // 2:
                self._t = np.resize(self._t, 2 * len(self._t))
                self._xy = np.concatenate([self._xy, np.empty_like(self._xy)])
            self._t[:kept] = self._t[self._head : self._tail]
            self._xy[:kept] = self._xy[self._head : self._tail]
            self._head, self._tail = 0, kept
        self._t[self._tail] = t
        self._xy[self._tail] = xy
        self._tail += 1
