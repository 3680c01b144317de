"""The particle state, its normalisation and the weighted estimate.

A :class:`ParticleSet` holds every per-particle quantity as one row of a ``(fields, N)`` float64 array,
so that resampling gathers all of them in one pass and the compiled kernels of the parts take one
array instead of a dozen. Rows (:data:`FIELDS`):

``x, y``
    metres east/north in the map's local UTM CRS;
``theta``
    heading offset (radians, counter-clockwise): the inertial displacement is rotated by it;
``cos_theta, sin_theta``
    kept in step with ``theta`` by whoever changes it (the predictor, the initiator, recovery), so that
    neither the predictor's rotation nor the estimate's circular mean recomputes them;
``scale``
    speed scale: the inertial displacement is multiplied by it;
``bias_x, bias_y``
    the GNSS bias state (metres; a fix measures position + bias), zero unless the GNSS part uses it.

Weights stay in the log domain (products of many likelihoods never underflow) and are normalised with
the log-sum-exp trick (:func:`normalise_and_estimate`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from curbside.localize.filter.kernelmath import exp
from curbside.projection import LocalFrame

FIELDS = ("x", "y", "theta", "cos_theta", "sin_theta", "scale", "bias_x", "bias_y")
X, Y, THETA, COS, SIN, SCALE, BIAS_X, BIAS_Y = range(len(FIELDS))


def _row(row: int, doc: str) -> property:
    """A state row as an attribute: a view when read, written in place when assigned."""

    def get(self: ParticleSet) -> np.ndarray:
        return self.state[row]

    def set_(self: ParticleSet, value: np.ndarray) -> None:
        self.state[row] = value

    return property(get, set_, doc=f"{doc} (A view into the state.)")


class ParticleSet:
    """``N`` particles: the state rows of :data:`FIELDS`, log-weights and normalised weights.

    Resampling writes into a spare state array and swaps: read ``particles.x`` after an update, do not
    keep the view across updates.

    Parameters
    ----------
    n
        Number of particles.
    """

    def __init__(self, n: int) -> None:
        self.state = np.zeros((len(FIELDS), n))
        self.state[COS] = 1.0
        self.state[SCALE] = 1.0
        self.spare = np.empty_like(self.state)
        self.log_weight = np.full(n, -math.log(n))
        self.weights = np.full(n, 1.0 / n)
        #: The parent of each particle at the last resampling (written by the resampler).
        self.ancestors = np.arange(n)

    def __len__(self) -> int:
        return self.state.shape[1]

    def swap(self) -> None:
        """Make :attr:`spare` (just filled by a resampler) the state."""
        self.state, self.spare = self.spare, self.state

    def set_heading(self, theta: np.ndarray) -> None:
        """Set ``theta`` and its cosine and sine rows."""
        self.state[THETA] = theta
        np.cos(self.state[THETA], out=self.state[COS])
        np.sin(self.state[THETA], out=self.state[SIN])

    def reset_weights(self) -> None:
        """Uniform weights."""
        self.log_weight.fill(-math.log(len(self)))
        self.weights.fill(1.0 / len(self))

    x = _row(X, "Metres east.")
    y = _row(Y, "Metres north.")
    theta = _row(THETA, "Heading offset, radians (set it with :meth:`set_heading` to keep cos/sin in step).")
    scale = _row(SCALE, "Speed scale.")
    bias_x = _row(BIAS_X, "GNSS bias east, metres.")
    bias_y = _row(BIAS_Y, "GNSS bias north, metres.")


_new_tuple = tuple.__new__  # a named tuple from the kernel's tuple, without its constructor's overhead


class Moments(NamedTuple):
    """Weighted moments of the cloud after normalisation.

    Attributes
    ----------
    ok
        ``False`` when every weight was zero or one was NaN (the cloud collapsed; nothing was written).
    x, y
        Weighted mean position (the paper's estimate), metres.
    theta
        Weighted circular mean of the heading offset, radians.
    scale
        Weighted mean speed scale.
    n_eff
        Kish's effective sample size ``1 / sum(w^2)``.
    spread_m
        Root mean square distance of the weighted particles from ``x, y``, metres.
    """

    ok: bool
    x: float
    y: float
    theta: float
    scale: float
    n_eff: float
    spread_m: float


def normalise_and_estimate(particles: ParticleSet) -> Moments:
    """Normalise the log-weights in place (log-sum-exp), fill ``particles.weights``, return the moments."""
    moments = _normalise_and_estimate(particles.state, particles.log_weight, particles.weights)
    return _new_tuple(Moments, moments)


@numba.njit(cache=True, nogil=True, error_model="numpy")  # kernelmath.exp vectorises under it
def _normalise_and_estimate(state, log_weight, weights):  # pragma: no cover - compiled
    n = log_weight.shape[0]
    peak = -math.inf
    has_nan = False
    for i in range(n):
        lw = log_weight[i]
        has_nan |= lw != lw
        peak = max(peak, lw)
    if has_nan or peak == -math.inf:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(n):
        weights[i] = exp(log_weight[i] - peak)
    total = 0.0
    for i in range(n):
        total += weights[i]
    log_total = math.log(total)
    # The spread from moments about the first particle: metres about UTM coordinates keep their precision.
    x0, y0 = state[0, 0], state[1, 0]
    ex = ey = esc = ec = es = sq = dx_mean = dy_mean = d2_mean = 0.0
    for i in range(n):
        w = weights[i] / total
        weights[i] = w
        log_weight[i] = log_weight[i] - peak - log_total
        ex += w * state[0, i]
        ey += w * state[1, i]
        ec += w * state[3, i]
        es += w * state[4, i]
        esc += w * state[5, i]
        sq += w * w
        dx = state[0, i] - x0
        dy = state[1, i] - y0
        dx_mean += w * dx
        dy_mean += w * dy
        d2_mean += w * (dx * dx + dy * dy)
    spread = math.sqrt(max(d2_mean - dx_mean * dx_mean - dy_mean * dy_mean, 0.0))
    return True, ex, ey, math.atan2(es, ec), esc, 1.0 / sq, spread


def reference_moments(particles: ParticleSet) -> Moments:
    """The numpy oracle of :func:`normalise_and_estimate` (tests only; does not modify the particles)."""
    from scipy.special import logsumexp

    lw = particles.log_weight
    if np.isnan(lw).any() or not np.isfinite(lw.max()):
        return Moments(False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    w = np.exp(lw - logsumexp(lw))
    s = particles.state
    mx, my = float(w @ s[X]), float(w @ s[Y])
    return Moments(
        True,
        mx,
        my,
        math.atan2(float(w @ s[SIN]), float(w @ s[COS])),
        float(w @ s[SCALE]),
        1.0 / float(w @ w),
        math.sqrt(float(w @ ((s[X] - mx) ** 2 + (s[Y] - my) ** 2))),
    )


class Estimate(NamedTuple):
    """The filter's output at one update (a named tuple: cheap to make once per footstep).

    Attributes
    ----------
    t
        Time, seconds on the session clock.
    x, y
        Weighted mean position, metres in the local CRS (the paper's estimate).
    theta
        Weighted circular mean of the heading offset, radians.
    scale
        Weighted mean speed scale.
    n_eff
        Effective sample size before resampling.
    recovered
        Whether the cloud collapsed at this update and was re-seeded.
    frame
        The local frame, for :attr:`lat` / :attr:`lon`.
    segment_id
        ``segment_id`` of the sidewalk segment of largest posterior probability; ``None`` without a
        segment raster or with no weight near a sidewalk.
    segment_prob
        Its probability (0 without one): the posterior mass, calibrated when the tracker has a
        :class:`~curbside.localize.filter.calibration.SegmentCalibration`.
    mode_x, mode_y
        Weighted mean of the particles on that segment (``x, y`` when there is none).
    injected
        Particles re-drawn around the latest fix by the divergence recovery at this update.
    accuracy_m
        Radius around ``x, y`` that holds the walker 68 % of the time, metres (as a phone reports a
        fix's accuracy): from the cloud's spread, widened like ``segment_prob`` is tempered
        (:func:`~curbside.localize.filter.calibration.accuracy_radius_m`), and at least
        ``filter.calibration.radius_floor_m_per_s`` times the seconds since the last agreeing fix.
    """

    t: float
    x: float
    y: float
    theta: float
    scale: float
    n_eff: float
    recovered: bool
    frame: LocalFrame | None = None
    segment_id: str | None = None
    segment_prob: float = 0.0
    mode_x: float = 0.0
    mode_y: float = 0.0
    injected: int = 0
    accuracy_m: float = math.nan

    @property
    def lat(self) -> float:
        """Latitude, WGS84 degrees."""
        return float(self.frame.to_lonlat(self.x, self.y)[1])

    @property
    def lon(self) -> float:
        """Longitude, WGS84 degrees."""
        return float(self.frame.to_lonlat(self.x, self.y)[0])

    @property
    def mode_lonlat(self) -> tuple[float, float]:
        """``(lon, lat)`` of the mode estimate, WGS84 degrees."""
        lon, lat = self.frame.to_lonlat(self.mode_x, self.mode_y)
        return float(lon), float(lat)
