"""The map likelihood: a particle's weight from the map class under it (the paper's geosegments).

Weights: 0 in a building, ``jaywalk_weight`` on street surface outside crosswalks, 1 on crosswalks,
sidewalks, free space and anywhere off the raster. With ``wall_tolerance_m = t > 0`` the walls are soft:
a particle ``d`` metres past a wall weighs ``exp(-d^2 / (2 t^2))``, and 0 beyond ``3 t``, so a map a
metre or two off (an old footprint, a misplaced facade) no longer kills particles on a real sidewalk.
A map whose buildings cover its own sidewalks (a building layer from another source or year than the
streets) is such a map: its walls are soft by at least ``conflict_wall_tolerance_m``
(:func:`wall_tolerance_for`), and its sidewalks and crosswalks, drawn against its streets, win over its
buildings where they overlap (``conflict_walkable_first``; :func:`raster_for`).

The lookup is one gather in the raster's ``uint8`` codes (building cells carry their depth, see
:mod:`curbside.localize.raster`) and one in a 256-entry table of log-weights, compiled into one loop.
The same loop counts the particles that a wall stops (weight under 1 %): ``blocked_share``, which the
divergence recovery's stall test reads.
"""

from __future__ import annotations

import logging
import math

import numba
import numpy as np

from curbside.localize.filter.config import MapConfig
from curbside.localize.filter.kernelmath import cell_index
from curbside.localize.filter.particles import ParticleSet
from curbside.localize.filter.parts import Update
from curbside.localize.raster import BUILDING, STREET, MapRaster, RasterLookup, building_depth_m

logger = logging.getLogger(__name__)

#: A particle whose map weight is below this (1 %) counts as stopped by a wall.
BLOCKED_LOG_WEIGHT = math.log(0.01)


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
        #: Share of the particles that the last :meth:`weigh` found behind a wall (weight under 1 %).
        self.blocked_share = 0.0

    def weigh(self, particles: ParticleSet, update: Update | None = None) -> None:
        """Add the map log-weight of every particle to ``particles.log_weight``."""
        lk = self.lookup
        blocked = _add_map_log_weight(particles.state, particles.log_weight, lk.padded, lk.index_grid,
                                      self.log_table)
        self.blocked_share = blocked / max(1, len(particles))

    def log_likelihood(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Map log-weight of points ``(x, y)`` (any matching shapes; a new array)."""
        return self.log_table[self.raster.codes_at(x, y)]


@numba.njit(cache=True, nogil=True)
def _add_map_log_weight(state, log_weight, padded, grid, table):  # pragma: no cover - compiled
    blocked = 0
    for i in range(state.shape[1]):
        w = table[padded[cell_index(state[0, i], state[1, i], grid)]]
        log_weight[i] += w
        blocked += w < BLOCKED_LOG_WEIGHT
    return blocked
