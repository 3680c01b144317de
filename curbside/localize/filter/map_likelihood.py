"""The map likelihood: a particle's weight from the map class under it (the paper's geosegments).

Weights: 0 in a building, ``jaywalk_weight`` on street surface outside crosswalks, 1 on crosswalks,
sidewalks, free space and anywhere off the raster. A particle on the street whose step runs within
``crossing_angle_deg`` of square to the street (the axis of the sidewalk segment nearest to it) is
crossing it, and weighs ``max(jaywalk_weight, crossing_weight)``: the paper's weight, applied at every
footstep, makes a mid-block crossing of twenty steps cost 0.4^20, so the cloud would rather believe any
particle whose heading offset kept it on the kerb than a walker who crosses; walking along the
carriageway keeps the paper's weight.

With ``wall_tolerance_m = t > 0`` the walls are soft: a particle ``d`` metres past a wall weighs
``exp(-d^2 / (2 t^2))``, and 0 beyond ``3 t``, so a map a metre or two off (an old footprint, a
misplaced facade) no longer kills particles on a real sidewalk.
A map whose buildings cover its own sidewalks (a building layer from another source or year than the
streets) is such a map: its walls are soft by at least ``conflict_wall_tolerance_m``
(:func:`wall_tolerance_for`), and its sidewalks and crosswalks, drawn against its streets, win over its
buildings where they overlap (``conflict_walkable_first``; :func:`raster_for`).

The lookup is one gather in the raster's ``uint8`` codes (building cells carry their depth, see
:mod:`curbside.localize.raster`) and one in a 256-entry table of log-weights, compiled into one loop;
a particle on the street also reads its nearest segment's axis. The same loop counts the particles
that a wall stops (weight under 1 %): ``blocked_share``, which the divergence recovery's stall test
reads.
"""

from __future__ import annotations

import logging
import math

import numba
import numpy as np

from curbside.localize.filter.config import MapConfig
from curbside.localize.filter.kernelmath import cell_indices
from curbside.localize.filter.particles import COS, SIN, ParticleSet, X, Y
from curbside.localize.filter.parts import Update
from curbside.localize.raster import BUILDING, STREET, MapRaster, RasterLookup, building_depth_m

logger = logging.getLogger(__name__)

#: A particle whose map weight is below this (1 %) counts as stopped by a wall.
BLOCKED_LOG_WEIGHT = math.log(0.01)
#: Shorter inertial steps (standing, phantom motion) have no direction: the street weighs as it is.
CROSSING_MIN_STEP_M = 0.2


def in_conflict(raster: MapRaster, config: MapConfig) -> bool:
    """Whether the map's buildings cover at least ``conflict_share_min`` of its sidewalks."""
    share = raster.sidewalk_under_buildings
    return share > 0 and share >= config.conflict_share_min


def wall_tolerance_for(raster: MapRaster, config: MapConfig) -> float:
    """The wall tolerance (m) on ``raster``: ``wall_tolerance_m``, or ``conflict_wall_tolerance_m`` if larger
    where the map's buildings and sidewalks are :func:`in_conflict`."""
    conflict_tolerance_m = config.conflict_wall_tolerance_m if in_conflict(raster, config) else 0.0
    return max(config.wall_tolerance_m, conflict_tolerance_m)


def raster_for(raster: MapRaster, config: MapConfig) -> MapRaster:
    """The raster the likelihood weighs with: :attr:`MapRaster.walkable_first` on a map :func:`in_conflict`
    with ``conflict_walkable_first``, else ``raster``."""
    return raster.walkable_first if config.conflict_walkable_first and in_conflict(raster, config) else raster


def log_weight_table(config: MapConfig, resolution_m: float, wall_tolerance_m: float) -> np.ndarray:
    """Log-weight of each of the 256 raster codes under ``config``, walls soft by ``wall_tolerance_m``."""
    table = np.zeros(256)
    table[STREET] = math.log(config.jaywalk_weight) if config.jaywalk_weight > 0 else -math.inf
    depth = building_depth_m(np.arange(BUILDING, 256), resolution_m)
    t = wall_tolerance_m
    if t > 0:
        table[BUILDING:] = np.where(depth <= 3 * t, -0.5 * (depth / t) ** 2, -math.inf)
    else:
        table[BUILDING:] = -math.inf
    return table


class MapLikelihood:
    """Log-likelihood of each particle's position given the map (see the module docstring).

    Parameters
    ----------
    raster
        The map raster (:func:`curbside.localize.raster.load_or_build_raster`); on a map in conflict the
        likelihood keeps :func:`raster_for`'s.
    config
        Jaywalking weight, wall tolerance and the conflict rule.
    """

    def __init__(self, raster: MapRaster, config: MapConfig) -> None:
        self.raster = raster_for(raster, config)
        self.config = config
        self.lookup = RasterLookup(self.raster)
        #: The walls' softness on this map (m; :func:`wall_tolerance_for`).
        self.wall_tolerance_m = wall_tolerance_for(raster, config)
        #: Whether the map's sidewalks and crosswalks win over its buildings (:func:`raster_for`).
        self.walkable_first = config.conflict_walkable_first and in_conflict(raster, config)
        if self.wall_tolerance_m > config.wall_tolerance_m or self.walkable_first:
            logger.info(
                "the map's buildings stand on %.1f %% of its sidewalks (another source or year than its "
                "streets, or misaligned?): walls soft by %.2g m%s (filter.map.conflict_*)",
                100 * raster.sidewalk_under_buildings,
                self.wall_tolerance_m,
                ", sidewalks and crosswalks over buildings" if self.walkable_first else "",
            )
        self.log_table = log_weight_table(config, raster.resolution_m, self.wall_tolerance_m)
        #: Log-weight of a step across the street, and the largest ``|cos|`` of the angle between a
        #: crossing step and the street's axis (-1: the rule is off, or the map has no segments).
        self.log_crossing, self.max_along = self.log_table[STREET], -1.0
        self._segments = np.full(1, -1, np.int16)
        self._axes = np.zeros((1, 2))
        if config.crossing_weight is not None and self.raster.segment_axes is not None:
            crossing = max(config.jaywalk_weight, config.crossing_weight)
            self.log_crossing = math.log(crossing) if crossing > 0 else -math.inf
            self.max_along = math.sin(math.radians(config.crossing_angle_deg))
            self._segments = self.lookup.padded_segments
            self._axes = np.ascontiguousarray(self.raster.segment_axes, dtype=np.float64)
        #: Share of the particles that the last :meth:`weigh` found behind a wall (weight under 1 %).
        self.blocked_share = 0.0

    def weigh(self, particles: ParticleSet, update: Update | None = None) -> None:
        """Add each particle's map log-weight, for its step in ``update``, to ``particles.log_weight``."""
        ux, uy, max_along = _step_direction(update, self.max_along)
        lk = self.lookup
        blocked = _add_map_log_weight(particles.state, particles.log_weight, lk.padded, lk.index_grid,
                                      self.log_table, self._segments, self._axes, ux, uy, max_along,
                                      self.log_crossing)
        self.blocked_share = blocked / max(1, len(particles))

    def log_likelihood(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Map log-weight of points ``(x, y)`` standing still (any matching shapes; a new array)."""
        return self.log_table[self.raster.codes_at(x, y)]

    def reference_log_likelihood(self, particles: ParticleSet, update: Update | None) -> np.ndarray:
        """The numpy oracle of :meth:`weigh`'s log-weights (tests)."""
        s = particles.state
        out = self.log_likelihood(s[X], s[Y])
        ux, uy, max_along = _step_direction(update, self.max_along)
        if max_along < 0:
            return out
        segment = self.raster.segments_at(s[X], s[Y]).astype(np.int64)
        step_x, step_y = s[COS] * ux - s[SIN] * uy, s[SIN] * ux + s[COS] * uy
        axes = self.raster.segment_axes[np.maximum(segment, 0)]
        along = np.abs(step_x * axes[:, 0] + step_y * axes[:, 1])
        crossing = (self.raster.codes_at(s[X], s[Y]) == STREET) & (segment >= 0) & (along <= max_along)
        out[crossing] = self.log_crossing
        return out


def _step_direction(update: Update | None, max_along: float) -> tuple[float, float, float]:
    """Unit vector of the update's inertial step and the crossing rule's bound (-1: no direction)."""
    length = 0.0 if update is None else math.hypot(update.dx, update.dy)
    if length < CROSSING_MIN_STEP_M:
        return 0.0, 0.0, -1.0
    return update.dx / length, update.dy / length, max_along


@numba.njit(cache=True, nogil=True)
def _add_map_log_weight(
    state, log_weight, padded, grid, table, padded_segments, axes, ux, uy, max_along, log_crossing
):  # pragma: no cover - compiled
    cells = cell_indices(state, grid)
    blocked = 0
    for i in range(state.shape[1]):
        cell = cells[i]
        code = padded[cell]
        w = table[code]
        if code == STREET and max_along >= 0.0:
            k = padded_segments[cell]
            if k >= 0:
                c, s = state[COS, i], state[SIN, i]
                along = (c * ux - s * uy) * axes[k, 0] + (s * ux + c * uy) * axes[k, 1]
                if abs(along) <= max_along:
                    w = log_crossing
        log_weight[i] += w
        blocked += w < BLOCKED_LOG_WEIGHT
    return blocked
