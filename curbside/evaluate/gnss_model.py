"""An urban-canyon error model for phone GNSS, driven by the building heights in OpenStreetMap.

At each fix the model looks at the sky from the walker's true position: for ``n_azimuths`` directions
it finds the elevation angle above which the sky is open (the tallest building in that direction,
``atan(height / distance)``), and the distance to the nearest wall. From that mask:

- **across / along axes**: the blocked directions' principal axis is "across the street" (tall walls
  either side); its normal is "along". ``severity`` along each axis is the mean blocked elevation
  (0 = open sky, 1 = sky blocked to the zenith), averaged over the azimuths near that axis.
- **correlated error**: a first-order Gauss-Markov (AR(1)) process per axis with time constant
  ``tau_s`` and standard deviation ``sqrt(sigma_open_m^2 + (sigma_canyon_m * severity)^2)``, so errors
  are larger across than along and wander over tens of seconds, as multipath / NLOS errors do.
- **wrong sidewalk**: episodes (rate ``wrong_side_rate_per_s * severity``, mean length
  ``wrong_side_dwell_s``) during which the fix is mirrored across the canyon's centre line -- the
  reflected-signal fix "on the other side of the street" (Wang et al. 2015; the paper's Fig. 3).
- **outliers**: rare jumps of ``outlier_m`` metres in a random direction lasting a few seconds.
- **cover**: under a deck (inside a tall building footprint, e.g. the Transit Center) a fix is missing
  with probability ``covered_dropout``; the others carry a large slowly varying error.
- **reported accuracy**: the 68 % radius of the model's own Gauss-Markov error times a log-normal
  factor; it knows nothing of wrong-sidewalk episodes or outliers, so it is only loosely calibrated,
  as a phone's is.

Every parameter, its default and its source are listed in ``docs/evaluate.md``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
import shapely

from curbside.errors import CurbsideInputError
from curbside.evaluate.osmsource import OsmSource


@dataclass(frozen=True)
class GnssErrorModel:
    """Parameters of the urban-canyon GNSS error model (defaults calibrated, see docs/evaluate.md)."""

    #: 1-sigma per-axis error under open sky (m); phone GNSS, e.g. IPIN 2023 ground floor ~4 m median.
    sigma_open_m: float = 3.0
    #: Extra 1-sigma per-axis error at full blockage of that axis (m).
    sigma_canyon_m: float = 10.0
    #: Gauss-Markov time constant of the error (s).
    tau_s: float = 30.0
    #: Wrong-sidewalk episodes start at this rate times the across-street severity (1/s).
    wrong_side_rate_per_s: float = 0.03
    #: Mean length of a wrong-sidewalk episode (s).
    wrong_side_dwell_s: float = 20.0
    #: Outlier jumps per second (times 1 + 2 * severity).
    outlier_rate_per_s: float = 0.005
    #: Size range of outlier jumps (m).
    outlier_m: tuple[float, float] = (30.0, 120.0)
    #: Length range of an outlier episode (s).
    outlier_s: tuple[float, float] = (3.0, 12.0)
    #: Probability that a fix is missing under cover.
    covered_dropout: float = 0.6
    #: 1-sigma per-axis error under cover (m) and its time constant (s).
    sigma_covered_m: float = 30.0
    tau_covered_s: float = 60.0
    #: Reported accuracy = this x the model's per-axis sigma: the 68 % radius of a circular 2-D Gaussian,
    #: sqrt(-2 ln 0.32) = 1.51 (iOS ``horizontalAccuracy`` and Android ``getAccuracy()`` are 68 % radii).
    accuracy_radius_factor: float = 1.51
    #: Log-normal spread of the reported accuracy around that radius.
    accuracy_log_sigma: float = 0.4
    #: Reported accuracy is clipped to this range (m); iOS reports whole metres.
    accuracy_range_m: tuple[float, float] = (3.0, 100.0)
    #: Sky-mask resolution and reach.
    n_azimuths: int = 16
    mask_reach_m: float = 150.0
    #: Fix rate (Hz).
    rate_hz: float = 1.0
    #: Keep the across axis's sign continuous from fix to fix. The principal axis of the sky mask has
    #: no sign of its own, and where it flips (every 25-70 s on the six routes) so does the error drawn
    #: along it; ``False`` keeps the benchmark's sessions as they were scored.
    continuous_axes: bool = False

    def as_dict(self) -> dict:
        """Parameters as a JSON-ready dict."""
        return asdict(self)

    @classmethod
    def named(cls, name: str) -> GnssErrorModel:
        """The model called ``name`` in :data:`GNSS_MODELS` (an unknown name: a one-line input error)."""
        if name not in GNSS_MODELS:
            raise CurbsideInputError("--gnss", f"unknown GNSS model {name!r}; one of {list(GNSS_MODELS)}")
        return GNSS_MODELS[name]


#: The GNSS error models by name. ``canyon`` is the benchmark's (calibrated to the paper's GNSS column).
#: ``persistent`` has the same error sizes but errors that last as long as real phones' do: on the IPIN
#: 2023 trials 0.90 / 0.78 / 0.63 / 0.54 of a fix's error is still there 5 / 10 / 20 / 30 s later,
#: against 0.55-0.63 / 0.31-0.43 / 0.11-0.25 / 0.07-0.15 for ``canyon``'s fixes (90 s windows,
#: ``benchmarks/gnss_persistence.py``, docs/evaluate.md). Its wander has a 300 s time constant, its
#: wrong-sidewalk episodes are a third as frequent and three times as long, its outliers a third as
#: frequent and lasting 20-60 s, and its axes keep their sign; on the six routes its median and p90
#: error stay within 10 % and 20 % of ``canyon``'s.
GNSS_MODELS: dict[str, GnssErrorModel] = {
    "canyon": GnssErrorModel(),
    "persistent": GnssErrorModel(
        tau_s=300.0,
        wrong_side_rate_per_s=0.01,
        wrong_side_dwell_s=60.0,
        outlier_rate_per_s=0.0015,
        outlier_s=(20.0, 60.0),
        continuous_axes=True,
    ),
}


@dataclass
class SkyMask:
    """Per-position view of the sky.

    Attributes
    ----------
    elevation_deg
        ``(n, K)`` elevation of the skyline per azimuth (0 open).
    wall_m
        ``(n, K)`` distance to the nearest wall per azimuth (``mask_reach_m`` when none).
    azimuth
        ``(K, 2)`` unit vectors (east, north) of the azimuths.
    covered
        ``(n,)`` inside a building footprint at least ``covered_min_height_m`` tall.
    """

    elevation_deg: np.ndarray
    wall_m: np.ndarray
    azimuth: np.ndarray
    covered: np.ndarray


def sky_mask(
    xy: np.ndarray, osm: OsmSource, model: GnssErrorModel, covered_min_height_m: float = 15.0
) -> SkyMask:
    """Skyline elevation and wall distance for each position (vectorised over positions x azimuths).

    Parameters
    ----------
    xy
        ``(n, 2)`` positions in the local frame of ``osm``.
    osm
        Buildings with ``height_m``.
    model
        Gives ``n_azimuths`` and ``mask_reach_m``.
    covered_min_height_m
        A position inside a footprint at least this tall is under cover.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    k = model.n_azimuths
    ang = np.arange(k) * 2 * np.pi / k
    az = np.column_stack([np.sin(ang), np.cos(ang)])  # clockwise from north
    n = len(xy)
    start = np.repeat(xy, k, axis=0)
    end = start + np.tile(az, (n, 1)) * model.mask_reach_m
    rays = shapely.linestrings(np.stack([start, end], axis=1))
    geoms = osm.buildings.geometry.values
    heights = osm.buildings["height_m"].to_numpy(float)
    tree = shapely.STRtree(geoms)
    r_idx, b_idx = tree.query(rays, predicate="intersects")
    origin = shapely.points(start[r_idx])
    inside = shapely.contains_xy(geoms[b_idx], start[r_idx, 0], start[r_idx, 1])
    part = shapely.intersection(rays[r_idx], geoms[b_idx])
    dist = np.where(inside, 0.0, shapely.distance(origin, part))
    covered_pair = inside & (heights[b_idx] >= covered_min_height_m)
    # a building we stand in does not block the sky at its own edge for the mask: use what lies beyond
    elev = np.where(inside, 0.0, np.degrees(np.arctan2(heights[b_idx], np.maximum(dist, 0.5))))
    elevation = np.zeros(n * k)
    np.maximum.at(elevation, r_idx, elev)
    wall = np.full(n * k, model.mask_reach_m)
    np.minimum.at(wall, r_idx, np.where(inside, model.mask_reach_m, dist))
    covered = np.zeros(n * k, bool)
    covered[r_idx[covered_pair]] = True
    return SkyMask(elevation.reshape(n, k), wall.reshape(n, k), az, covered.reshape(n, k).any(axis=1))


def canyon_axes(mask: SkyMask) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Across-street axis, severities across/along, and the mirror offset across the canyon.

    Returns
    -------
    across
        ``(n, 2)`` unit vectors: the principal axis of the blocked directions.
    sev_across, sev_along
        ``(n,)`` blocked elevation (fraction of 90 degrees) of the azimuths near each axis, in [0, 1].
    mirror
        ``(n, 2)`` displacement that mirrors the position across the canyon centre line.
    """
    w = mask.elevation_deg / 90.0
    u = mask.azimuth
    k = len(u)
    m = np.einsum("nk,ki,kj->nij", w, u, u) * (2.0 / k)
    _, vecs = np.linalg.eigh(m)  # ascending eigenvalues: the last vector is the most blocked axis
    across = vecs[:, :, 1]
    along = np.column_stack([-across[:, 1], across[:, 0]])
    sev_across = _axis_severity(w, u, across)
    sev_along = _axis_severity(w, u, along)
    # walls nearest to +across and -across
    cos = across @ u.T
    plus = np.argmax(cos, axis=1)
    minus = np.argmin(cos, axis=1)
    rows = np.arange(len(w))
    d_plus = np.minimum(mask.wall_m[rows, plus], 40.0)
    d_minus = np.minimum(mask.wall_m[rows, minus], 40.0)
    mirror = across * (d_plus - d_minus)[:, None]
    return across, sev_across, sev_along, mirror


def continuous_sign(axes: np.ndarray) -> np.ndarray:
    """``(n, 2)`` unit axes with each sign chosen so that consecutive axes never point apart."""
    flips = np.einsum("ij,ij->i", axes[1:], axes[:-1]) < 0
    sign = np.cumprod(np.concatenate([[1.0], np.where(flips, -1.0, 1.0)]))
    return axes * sign[:, None]


def _axis_severity(w: np.ndarray, u: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Mean blockage of the azimuths near ``axis`` (both ways), weighted by ``cos^4`` of the angle."""
    weight = (axis @ u.T) ** 4
    return np.clip(np.sum(w * weight, axis=1) / np.sum(weight, axis=1), 0, 1)


def gauss_markov(n: int, dt: float, tau: np.ndarray | float, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance first-order Gauss-Markov sequence (AR(1)) of length ``n``."""
    phi = np.exp(-dt / np.broadcast_to(np.asarray(tau, float), (n,)))
    noise = rng.standard_normal(n)
    out = np.empty(n)
    out[0] = noise[0]
    scale = np.sqrt(1 - phi**2)
    for i in range(1, n):  # a recursion over time, not over geometries
        out[i] = phi[i] * out[i - 1] + scale[i] * noise[i]
    return out


def _episodes(n: int, start_prob: np.ndarray, length_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Episode id (0 = none) per fix for a process that starts with ``start_prob`` per fix."""
    starts = rng.random(n) < start_prob
    active = np.zeros(n, np.int64)
    episode = 0
    i = 0
    while i < n:  # episodes are rare: a handful per walk
        if starts[i]:
            episode += 1
            stop = min(n, i + max(1, int(round(length_s[i]))))
            active[i:stop] = episode
            i = stop
        else:
            i += 1
    return active


def simulate_gnss(
    t: np.ndarray, xy: np.ndarray, osm: OsmSource, model: GnssErrorModel, rng: np.random.Generator
) -> pd.DataFrame:
    """Phone GNSS fixes along a true trajectory.

    Parameters
    ----------
    t
        Fix times (s), regularly spaced at ``1 / model.rate_hz``.
    xy
        ``(n, 2)`` true positions at ``t`` in the local frame of ``osm``.
    osm
        Buildings with heights.
    model
        Error-model parameters.
    rng
        Seeded generator.

    Returns
    -------
    pandas.DataFrame
        ``t, x_m, y_m, accuracy_m, true_x_m, true_y_m, wrong_side, outlier, covered`` -- one row per
        fix that was delivered (dropouts removed).
    """
    t = np.asarray(t, float)
    n = len(t)
    dt = 1.0 / model.rate_hz
    mask = sky_mask(xy, osm, model)
    across, sev_a, sev_b, mirror = canyon_axes(mask)
    if model.continuous_axes:
        across = continuous_sign(across)
    along = np.column_stack([-across[:, 1], across[:, 0]])
    covered = mask.covered
    sig_a = np.hypot(model.sigma_open_m, model.sigma_canyon_m * sev_a)
    sig_b = np.hypot(model.sigma_open_m, model.sigma_canyon_m * sev_b)
    sig_a = np.where(covered, model.sigma_covered_m, sig_a)
    sig_b = np.where(covered, model.sigma_covered_m, sig_b)
    tau = np.where(covered, model.tau_covered_s, model.tau_s)
    za = gauss_markov(n, dt, tau, rng)
    zb = gauss_markov(n, dt, tau, rng)
    err = across * (sig_a * za)[:, None] + along * (sig_b * zb)[:, None]

    ws_prob = model.wrong_side_rate_per_s * dt * sev_a
    ws_len = rng.exponential(model.wrong_side_dwell_s, n)
    wrong = _episodes(n, ws_prob, ws_len, rng) > 0
    err += mirror * wrong[:, None]

    out_prob = model.outlier_rate_per_s * dt * (1 + 2 * sev_a)
    out_len = rng.uniform(*model.outlier_s, n)
    outlier_id = _episodes(n, out_prob, out_len, rng)
    jump_r = rng.uniform(*model.outlier_m, n + 1)
    jump_a = rng.uniform(0, 2 * np.pi, n + 1)
    jump = np.column_stack([np.sin(jump_a), np.cos(jump_a)]) * jump_r[:, None]
    outlier = outlier_id > 0
    err += jump[outlier_id] * outlier[:, None]

    sigma = np.sqrt((sig_a**2 + sig_b**2) / 2)
    reported = (
        model.accuracy_radius_factor * sigma * np.exp(model.accuracy_log_sigma * rng.standard_normal(n))
    )
    reported = np.round(np.clip(reported, *model.accuracy_range_m))
    keep = ~(covered & (rng.random(n) < model.covered_dropout))
    fixes = pd.DataFrame(
        {
            "t": t,
            "x_m": xy[:, 0] + err[:, 0],
            "y_m": xy[:, 1] + err[:, 1],
            "accuracy_m": reported,
            "true_x_m": xy[:, 0],
            "true_y_m": xy[:, 1],
            "wrong_side": wrong,
            "outlier": outlier,
            "covered": covered,
        }
    )
    return fixes[keep].reset_index(drop=True)
