"""The cloud's inertial path beside the recent fixes, and the similarity fit between them.

Two parts compare the fixes with the cloud's own inertial motion:
:class:`~curbside.localize.filter.scale.ScaleCorrection` (a speed scale the cloud cannot reach) and
:class:`~curbside.localize.filter.heading_correction.HeadingCorrection` (a velocity whose direction
turned faster than the heading state follows). Both keep a :class:`FixPathWindow`: the *unscaled*
inertial displacement of every update turned by the latest estimate's heading offset,
``P(t) = sum R(theta) (dx, dy)``, and for the last ``window_s`` seconds each accepted fix ``g_j`` with
the path point ``P_j`` of its update. :func:`fit_similarity` maps the path onto the fixes by the
weighted least-squares similarity (weights ``1 / accuracy^2``; complex numbers, both centred on their
weighted means)::

    z = sum_j w_j conj(P_j - P0) (g_j - g0) / sum_j w_j |P_j - P0|^2

``|z|`` is the speed scale the fixes ask for, ``arg z`` the turn, and ``g0 + z (P - P0)`` where the fit
puts a path point. A rotation leaves ``|z|`` unchanged, and a bias the fixes share over the window
cancels in the centring.
"""

from __future__ import annotations

import collections
import math
import statistics
from typing import NamedTuple

import numpy as np

from curbside.localize.filter.parts import GnssFix, Update


class PathFit(NamedTuple):
    """A similarity fit of fixes on a path (see the module docstring)."""

    z: complex
    path_centre: complex
    fix_centre: complex
    residuals: np.ndarray

    @property
    def scale(self) -> float:
        """Speed scale the fixes ask of the path."""
        return abs(self.z)

    @property
    def rotation(self) -> float:
        """Turn (radians, counter-clockwise) the fixes ask of the path."""
        return math.atan2(self.z.imag, self.z.real)

    @property
    def rms_m(self) -> float:
        """Root mean square distance of the fixes from the fitted path (m)."""
        return float(np.sqrt(np.mean(np.abs(self.residuals) ** 2)))

    def place(self, point: complex) -> complex:
        """Where the fit maps a path point."""
        return self.fix_centre + self.z * (point - self.path_centre)


def fit_similarity(path: np.ndarray, fixes: np.ndarray, accuracy: np.ndarray) -> PathFit:
    """Weighted similarity fit of ``fixes`` on ``path`` (complex arrays, metres; weights 1 / accuracy²)."""
    w = 1.0 / accuracy**2
    path_centre = complex(np.sum(w * path) / np.sum(w))
    fix_centre = complex(np.sum(w * fixes) / np.sum(w))
    p = path - path_centre
    g = fixes - fix_centre
    z = complex(np.sum(w * np.conj(p) * g) / np.sum(w * np.abs(p) ** 2))
    return PathFit(z, path_centre, fix_centre, g - z * p)


def span_m(points: np.ndarray) -> float:
    """Diagonal of the bounding box of complex ``points`` (m)."""
    return math.hypot(float(np.ptp(points.real)), float(np.ptp(points.imag)))


class FixPathWindow:
    """The cloud's inertial path and the accepted fixes of the last ``window_s`` seconds.

    Each kept fix carries the path point and the estimate of its update, so a part can fit the fixes
    on the inertial path and on the filter's own track alike. The window's length is given at each
    :meth:`add`, so a part whose parameters change mid-walk keeps its history.
    """

    def __init__(self) -> None:
        self.path = 0j
        self.entries: collections.deque[tuple[float, complex, complex, float, complex]] = collections.deque()
        self.next_fit_t = -math.inf

    def advance(self, update: Update, theta: float) -> None:
        """Extend the path by the update's inertial displacement turned by ``theta`` (radians)."""
        self.path += complex(math.cos(theta), math.sin(theta)) * complex(update.dx, update.dy)

    def add(self, t: float, fix: GnssFix, estimate: complex, window_s: float) -> bool:
        """Keep ``fix`` (at the current path point), drop those older than ``window_s``; ``True`` when a
        fit is due: the window is three quarters full and a quarter window has passed since the last."""
        entries = self.entries
        entries.append((t, self.path, complex(fix.x, fix.y), fix.accuracy_m, estimate))
        while entries and entries[0][0] < t - window_s:
            entries.popleft()
        if t < self.next_fit_t or entries[-1][0] - entries[0][0] < 0.75 * window_s:
            return False
        self.next_fit_t = t + 0.25 * window_s
        return True

    def median_accuracy_m(self) -> float:
        """The kept fixes' median reported accuracy (as ``numpy.median``, without building arrays)."""
        return float(statistics.median(entry[3] for entry in self.entries))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(path points, fixes, accuracies, estimates)`` of the kept fixes."""
        _, path, fixes, accuracy, estimates = (np.array(v) for v in zip(*self.entries, strict=True))
        return path, fixes, accuracy, estimates
