"""What the tracker hands its parts, and the interfaces a part implements (write your own to these).

A :class:`~curbside.localize.filter.tracker.Tracker` is assembled from parts, in the manner of Stone
Soup: an initiator places the particles, a predictor moves them at every update, a list of likelihoods
weighs them, a resampler redraws them, and recovery policies repair a cloud that collapsed or drifted
away. Each part is one small class owning its parameters (a frozen config section) and its own compiled
kernel; the tracker only calls the methods below, so replacing a part replaces its behaviour on the one
code path there is.

Example: a likelihood that halves the weight of particles south of a line::

    class SouthIsUnlikely:
        def __init__(self, y_line: float) -> None:
            self.y_line = y_line

        def weigh(self, particles: ParticleSet, update: Update) -> None:
            particles.log_weight[particles.y < self.y_line] += math.log(0.5)

    tracker = Tracker.from_config(raster, config, seed=0)
    tracker.likelihoods.append(SouthIsUnlikely(4182000.0))
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

from curbside.localize.filter.particles import ParticleSet


class GnssFix(NamedTuple):
    """One GNSS fix in the tracker's local frame.

    Attributes
    ----------
    x, y
        Metres east/north in the local CRS.
    accuracy_m
        Reported horizontal accuracy radius (68 %); not positive or not finite = invalid.
    """

    x: float
    y: float
    accuracy_m: float


class Update(NamedTuple):
    """Everything the parts may use at one update.

    Attributes
    ----------
    t
        Time of the update, seconds on the session clock.
    dt_s
        Time since the previous update.
    dx, dy
        Inertial displacement over the step, metres east/north (before each particle's turn and scale).
    fix
        The GNSS fix valid at ``t``, or ``None``.
    """

    t: float
    dt_s: float
    dx: float
    dy: float
    fix: GnssFix | None = None


class Predictor(Protocol):
    """Moves the particles at each update (a proposal; it must keep ``cos_theta``/``sin_theta`` in step)."""

    def predict(self, particles: ParticleSet, dx: float, dy: float, dt_s: float) -> None:
        """Move ``particles`` in place by the inertial displacement ``(dx, dy)`` over ``dt_s`` seconds."""


class Likelihood(Protocol):
    """Weighs the particles given what is known at an update."""

    def weigh(self, particles: ParticleSet, update: Update) -> None:
        """Add each particle's log-likelihood to ``particles.log_weight`` in place (``-inf``: impossible)."""


class Resampler(Protocol):
    """Redraws the particles from their normalised weights."""

    def resample(self, particles: ParticleSet, n_eff: float) -> bool:
        """Resample in place when the policy says so (weights then uniform); return whether it did.

        When it did, ``particles.ancestors[k]`` must hold the index, before resampling, of the particle
        that new particle ``k`` was drawn from (the fixed-lag smoother follows the genealogy).
        """
