"""Every parameter of the particle filter: one frozen dataclass per part, gathered in :class:`FilterConfig`.

Each part of the filter (:mod:`~curbside.localize.filter.predict`, ``map_likelihood``, ``gnss``,
``resample``, ``recovery``, ``scale``, ``initiate``, ``smoother``, ``calibration``) takes its own section
(those of the parts that re-draw particles are in :mod:`~curbside.localize.filter.correction_config`,
calibration's in :mod:`~curbside.localize.filter.calibration`); :class:`FilterConfig` holds them all and
is written whole to ``run.json`` (:func:`curbside.configio.to_dict`), so a run is reproducible from that
file alone. Defaults are curbside's fused filter; :meth:`FilterConfig.preset` gives the paper's plain
filter for comparison.
``docs/filter.md`` gives the reasoning behind each value.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from curbside.configio import check, non_negative, positive, unit_interval
from curbside.localize.filter.calibration import CalibrationConfig
from curbside.localize.filter.correction_config import (
    HeadingCorrectionConfig,
    RecoveryConfig,
    ScaleCorrectionConfig,
)

PRESETS = ("fused", "paper")
RESAMPLE_POLICIES = ("always", "ess")
#: Peak memory of one filter's particle arrays while it tracks, bytes per particle: the state, the
#: weights, the map lookup's buffers and the parts' scratch arrays (measured: 10^6 particles on a
#: 458 s simulated walk with a map raise the peak by 160 MB).
BYTES_PER_PARTICLE = 160


@dataclass(frozen=True)
class MotionConfig:
    """The inertial predictor: how a particle moves by a step's inertial displacement.

    Attributes
    ----------
    step_noise_fraction, step_noise_floor_m
        Position noise per update, east and north: sigma = max(floor, fraction * step length).
    step_noise_across_fraction
        With a value, the position noise is anisotropic: ``step_noise_fraction`` along the particle's
        step and this across it (``None``: isotropic). Inertial speed errors lie along the step; the
        heading state already carries the direction's.
    heading_noise_deg
        Random walk of the heading offset per update (one sigma, degrees).
    heading_jump_prob
        Probability per particle and update of an abrupt heading-offset jump (the phone changes hands,
        goes into a pocket): a mixture proposal that keeps a few particles exploring other offsets.
    heading_jump_sigma_deg
        Sigma of a jump (degrees).
    scale_init_sigma, scale_noise_per_step
        Speed-scale spread around 1 at the start and its random walk per update (0 and 0: the paper's
        three-state filter).
    gap_s
        Updates further apart than this (s) leave the walker's motion in between unknown (an app
        stopped, a phone asleep): the position noise of such an update is at least ``gap_spread_mps``
        times its duration (the engine updates at least every ``engine.max_update_interval_s``, 1 s).
    gap_spread_mps
        Position noise sigma (m per axis) per second of such a gap (0: none): a walker at 1.4 m/s ends
        within 2 sigma with 0.7 m/s.
    """

    step_noise_fraction: float = 0.25
    step_noise_floor_m: float = 0.05
    step_noise_across_fraction: float | None = None
    heading_noise_deg: float = 1.5
    heading_jump_prob: float = 0.0
    heading_jump_sigma_deg: float = 30.0
    scale_init_sigma: float = 0.09
    scale_noise_per_step: float = 0.001
    gap_s: float = 10.0
    gap_spread_mps: float = 0.7

    def __post_init__(self) -> None:
        non_negative(self, "step_noise_fraction", "step_noise_floor_m", "heading_noise_deg",
                     "scale_init_sigma", "scale_noise_per_step", "gap_spread_mps")
        positive(self, "gap_s")
        check(
            self.step_noise_across_fraction is None or self.step_noise_across_fraction >= 0,
            f"step_noise_across_fraction must be non-negative, got {self.step_noise_across_fraction}",
        )
        unit_interval(self, "heading_jump_prob")
        positive(self, "heading_jump_sigma_deg")


@dataclass(frozen=True)
class StartConfig:
    """Where the particles start.

    Attributes
    ----------
    position_sigma_m, heading_sigma_deg
        Spread around a known start pose.
    fix_heading_sigma_deg
        Heading-offset spread when starting from a GNSS fix; ``None`` for the full circle (right for a
        velocity whose yaw reference is arbitrary).
    fix_sigma_factor
        Position spread around a start fix = this times its reported accuracy.
    max_snap_m
        A start pose in a building moves to the nearest free cell within this distance.
    """

    position_sigma_m: float = 1.0
    heading_sigma_deg: float = 5.0
    fix_heading_sigma_deg: float | None = None
    fix_sigma_factor: float = 0.66
    max_snap_m: float = 30.0

    def __post_init__(self) -> None:
        non_negative(self, "position_sigma_m", "heading_sigma_deg", "max_snap_m")
        positive(self, "fix_sigma_factor")


@dataclass(frozen=True)
class MapConfig:
    """The map likelihood and its raster.

    Attributes
    ----------
    jaywalk_weight
        Weight of a particle on street surface outside crosswalks, in [0, 1] (the paper: 0.4).
    crossing_weight
        Weight, in [0, 1], of a particle on the street that is crossing it (``crossing_angle_deg``): it
        weighs ``max(jaywalk_weight, crossing_weight)`` instead of ``jaywalk_weight``, since a walker
        crosses a street outside a crosswalk now and then, but does not walk along it (``None``: the
        paper's single weight; see ``docs/filter.md``, "Crossing the street outside a crosswalk").
    crossing_angle_deg
        A particle on the street is crossing it when its step (its inertial step turned by its heading
        offset) runs within this angle (degrees, in (0, 90]; 90: any step) of square to the street (the
        axis of its nearest sidewalk segment). Unused when ``crossing_weight`` is ``None``.
    wall_tolerance_m
        Soft building edges: a particle ``d`` metres inside a building weighs ``exp(-d^2 / (2 t^2))``
        instead of 0 (0: the paper's hard walls), and 0 beyond ``3 t``. Tolerates metre-scale map error.
    conflict_share_min, conflict_wall_tolerance_m, conflict_walkable_first
        A map whose buildings cover at least ``conflict_share_min`` of its sidewalk area, or of its
        mapped sidewalk ways' length (:attr:`~curbside.localize.raster.MapRaster.sidewalk_under_buildings`:
        a building layer from another source or year than the streets, or misaligned with them), has
        walls soft by at least ``conflict_wall_tolerance_m`` (0 m: every map keeps ``wall_tolerance_m``)
        and, with ``conflict_walkable_first``, its sidewalks and crosswalks win over its buildings where
        they overlap (:attr:`~curbside.localize.raster.MapRaster.walkable_first`).
    raster_resolution_m
        Cell size of the map raster. A raster that would need more memory than the machine has (about
        70 bytes a cell while it is built: 1.6 GiB for 2.4 km square at 0.5 m) is refused.
    segment_reach_m
        Cells farther than this from every sidewalk belong to no segment.
    """

    jaywalk_weight: float = 0.4
    crossing_weight: float | None = 0.7
    crossing_angle_deg: float = 30.0
    wall_tolerance_m: float = 0.0
    conflict_share_min: float = 0.02
    conflict_wall_tolerance_m: float = 1.5
    conflict_walkable_first: bool = True
    raster_resolution_m: float = 0.5
    segment_reach_m: float = 25.0

    def __post_init__(self) -> None:
        check(0.0 <= self.jaywalk_weight <= 1.0,
               f"jaywalk_weight must lie in [0, 1], got {self.jaywalk_weight}")
        check(
            self.crossing_weight is None or 0.0 <= self.crossing_weight <= 1.0,
            f"crossing_weight must lie in [0, 1] or be None, got {self.crossing_weight}",
        )
        check(0.0 < self.crossing_angle_deg <= 90.0,
               f"crossing_angle_deg must lie in (0, 90], got {self.crossing_angle_deg}")
        non_negative(self, "wall_tolerance_m", "conflict_wall_tolerance_m")
        unit_interval(self, "conflict_share_min")
        positive(self, "raster_resolution_m", "segment_reach_m")


@dataclass(frozen=True)
class StreetHeadingConfig:
    """The street-heading likelihood (:mod:`~curbside.localize.filter.street_heading`).

    Attributes
    ----------
    strength_per_m
        Concentration of the axial von Mises density per metre walked (0: off).
    floor
        Weight kept by a particle walking across its sidewalk's axis (in (0, 1)).
    min_step_m
        Shorter steps (standing, phantom motion) weigh nothing.
    min_sidewalk_share
        The term applies only when at least this share of the weight is on sidewalk cells ...
    min_axis_agreement
        ... and those cells' street axes agree (mean resultant length of the doubled angles, in [0, 1]) ...
    max_turn_deg
        ... and the cloud's mean step (the inertial step turned by each particle's heading offset) runs
        within this angle of the axis, either way (degrees, in (0, 90]; 90: no such gate). A walker
        turning off the street at a corner is not walking along it.
    """

    strength_per_m: float = 4.0
    floor: float = 0.2
    min_step_m: float = 0.2
    min_sidewalk_share: float = 0.8
    min_axis_agreement: float = 0.95
    max_turn_deg: float = 30.0

    def __post_init__(self) -> None:
        check(0.0 < self.max_turn_deg <= 90.0, f"max_turn_deg must lie in (0, 90], got {self.max_turn_deg}")
        check(self.strength_per_m >= 0, f"strength_per_m must be non-negative, got {self.strength_per_m}")
        check(0.0 < self.floor < 1.0, f"floor must lie in (0, 1), got {self.floor}")
        check(self.min_step_m >= 0, f"min_step_m must be non-negative, got {self.min_step_m}")
        unit_interval(self, "min_sidewalk_share", "min_axis_agreement")


@dataclass(frozen=True)
class GnssConfig:
    """The GNSS likelihood (:class:`~curbside.localize.filter.gnss.GnssLikelihood`).

    Attributes
    ----------
    sigma_factor
        Likelihood sigma = factor * reported accuracy radius.
    max_accuracy_m
        Fixes reporting a worse accuracy make no update.
    outlier_prob
        Weight, in [0, 1), of a flat outlier component mixed with the Gaussian; 0: the plain Gaussian
        (``outlier_radius_m`` then unused).
    outlier_radius_m
        Radius (m, > 0) of the disc the outlier component is uniform over: it adds the constant density
        ``outlier_prob / (pi * outlier_radius_m**2)`` at every distance from the fix, a floor under the
        likelihood (a larger radius: a lower floor).
    across_factor
        Anisotropy: the error across the street (the nearest sidewalk segment's normal) has this many
        times the sigma of the error along it (1: isotropic). In urban canyons GNSS is worse across the
        street than along it, and wrong-side fixes are mirrored across it (Wang et al. 2015).
    student_dof
        Degrees of freedom of a bivariate Student-t used instead of the Gaussian-and-outlier mixture
        (0: not used). Heavy-tailed like the mixture (one fix cannot drag the cloud far), but a fix
        far from every particle still favours the nearer ones, so a cloud stuck tens of metres off
        keeps being pulled by good fixes instead of seeing them all as outliers.
    correlation_time_s
        Time constant of the GNSS error; each fix's log-likelihood is tempered by the fraction of an
        independent fix it carries (0: independent fixes).
    correlation_accuracy_m
        A fix reporting an accuracy worse than this has a time constant longer in proportion:
        ``correlation_time_s * accuracy_m / correlation_accuracy_m`` (0: one time constant for every
        fix). A fix that reports tens of metres is off by multipath, whose error lasts as long as the
        walker's geometry to the reflecting facades, so it carries less than its sigma alone says.
    min_accuracy_m
        A fix reporting a positive accuracy under this counts as reporting this (a phone reports
        metres; a radius near zero would leave the likelihoods nothing to divide by).
    bias_sigma_factor
        A GNSS bias state (0: none): the slowly wandering error that successive fixes share, a
        first-order Gauss-Markov process with time constant ``bias_time_s`` and stationary sigma
        ``bias_sigma_factor`` times the reported accuracy (per axis). It is Rao-Blackwellised: each
        particle carries the Kalman mean of its bias, all share one variance, and a fix measures
        position + bias + white noise of sigma ``sigma_factor`` times the accuracy. It replaces
        tempering (set ``correlation_time_s`` to 0 with it).
    bias_time_s
        The bias state's time constant (s, > 0; unused while ``bias_sigma_factor`` is 0).
    """

    sigma_factor: float = 0.66
    max_accuracy_m: float = 50.0
    outlier_prob: float = 0.05
    outlier_radius_m: float = 50.0
    across_factor: float = 1.0
    student_dof: float = 0.0
    correlation_time_s: float = 3.0
    correlation_accuracy_m: float = 10.0
    min_accuracy_m: float = 0.1
    bias_sigma_factor: float = 0.0
    bias_time_s: float = 30.0

    def __post_init__(self) -> None:
        check(self.sigma_factor > 0, f"sigma_factor must be positive, got {self.sigma_factor}")
        check(self.max_accuracy_m > 0, f"max_accuracy_m must be positive, got {self.max_accuracy_m}")
        check(0 < self.min_accuracy_m < self.max_accuracy_m,
              f"min_accuracy_m must lie in (0, max_accuracy_m), got min_accuracy_m {self.min_accuracy_m} and "
              f"max_accuracy_m {self.max_accuracy_m}")
        check(0.0 <= self.outlier_prob < 1.0, f"outlier_prob must lie in [0, 1), got {self.outlier_prob}")
        check(self.outlier_radius_m > 0, f"outlier_radius_m must be positive, got {self.outlier_radius_m}")
        check(self.student_dof >= 0, f"student_dof must be non-negative, got {self.student_dof}")
        check(self.across_factor >= 1, f"across_factor must be at least 1, got {self.across_factor}")
        non_negative(self, "correlation_time_s", "correlation_accuracy_m", "bias_sigma_factor")
        positive(self, "bias_time_s")


@dataclass(frozen=True)
class ResampleConfig:
    """When to resample (:class:`~curbside.localize.filter.resample.SystematicResampler`).

    Attributes
    ----------
    policy
        ``ess`` (the default): when the effective sample size falls below ``ess_fraction * N``, which
        keeps the diversity the speed-scale state needs; ``always``: at every update (the paper).
    ess_fraction
        The threshold of ``ess``, as a share of N.
    """

    policy: str = "ess"
    ess_fraction: float = 0.5

    def __post_init__(self) -> None:
        check(
            self.policy in RESAMPLE_POLICIES,
            f"policy must be one of {RESAMPLE_POLICIES}, got {self.policy!r}",
        )
        check(0.0 < self.ess_fraction <= 1.0, f"ess_fraction must lie in (0, 1], got {self.ess_fraction}")


@dataclass(frozen=True)
class SmootherConfig:
    """The fixed-lag smoother, an opt-in output for offline analysis (:mod:`.smoother`).

    Attributes
    ----------
    lag_s
        Each update's position is also estimated from the particles' genealogy ``lag_s`` seconds later
        (0: off). The filter's own estimates do not change.
    """

    lag_s: float = 0.0

    def __post_init__(self) -> None:
        check(0 <= self.lag_s < float("inf"), f"lag_s must be finite and >= 0, got {self.lag_s}")


@dataclass(frozen=True)
class FilterConfig:
    """All parameters of the particle filter.

    Attributes
    ----------
    n_particles
        Number of particles N. curbside fused's default: 2000; the paper's, and its preset's
        (``--mode paper``): 500. On the tune split's 180 walks 2000 beat 500 on every subset
        (docs/tuning.md, "Number of particles"). A run whose particles would need more memory than the
        machine has (about 160 bytes each, twice under ``familiar_velocity.mode = auto``) is refused.
    motion, start, map, gnss, resample, recovery
        One section per part.
    scale_correction, heading_correction, street_heading, smoother, calibration
        One section per part.
    segment_estimate
        Compute the posterior over sidewalk segments and its mode at each update (needs a map with
        sidewalk segments); ``calibration`` says how far its probability is trusted.
    """

    n_particles: int = 2000
    motion: MotionConfig = field(default_factory=MotionConfig)
    start: StartConfig = field(default_factory=StartConfig)
    map: MapConfig = field(default_factory=MapConfig)
    gnss: GnssConfig = field(default_factory=GnssConfig)
    resample: ResampleConfig = field(default_factory=ResampleConfig)
    recovery: RecoveryConfig = field(default_factory=RecoveryConfig)
    scale_correction: ScaleCorrectionConfig = field(default_factory=ScaleCorrectionConfig)
    heading_correction: HeadingCorrectionConfig = field(default_factory=HeadingCorrectionConfig)
    street_heading: StreetHeadingConfig = field(default_factory=StreetHeadingConfig)
    smoother: SmootherConfig = field(default_factory=SmootherConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    segment_estimate: bool = True

    def __post_init__(self) -> None:
        check(int(self.n_particles) >= 1, f"n_particles must be at least 1, got {self.n_particles}")

    @classmethod
    def preset(cls, name: str) -> FilterConfig:
        """``"fused"``: curbside's filter (the defaults). ``"paper"``: the paper's plain filter.

        The paper's filter (Dubiner, Ren & Manduchi; Ren & Ke 2010 for the GNSS weighting): 500
        particles, position and heading-drift noise, hard walls, one weight for every particle on the
        street (crossing it or not), a Gaussian GNSS likelihood with sigma equal to the reported
        accuracy for fixes under a threshold, every fix counted as independent, resampling at every
        update, no outlier model, no speed scale, no recovery beyond re-seeding a collapsed cloud, and the
        segment's posterior mass reported as it is.
        """
        if name == "fused":
            return cls()
        if name == "paper":
            return cls(
                n_particles=500,
                motion=MotionConfig(
                    step_noise_fraction=0.15,
                    step_noise_floor_m=0.05,
                    heading_noise_deg=0.5,
                    scale_init_sigma=0.0,
                    scale_noise_per_step=0.0,
                ),
                gnss=GnssConfig(
                    sigma_factor=1.0, outlier_prob=0.0, correlation_time_s=0.0, correlation_accuracy_m=0.0
                ),
                resample=ResampleConfig(policy="always"),
                map=MapConfig(
                    crossing_weight=None, conflict_wall_tolerance_m=0.0, conflict_walkable_first=False
                ),
                recovery=RecoveryConfig(max_fraction=0.0, stall_ratio=0.0),
                scale_correction=ScaleCorrectionConfig(fraction=0.0),
                heading_correction=HeadingCorrectionConfig(fraction=0.0),
                street_heading=StreetHeadingConfig(strength_per_m=0.0),
                start=StartConfig(fix_sigma_factor=1.0),
                calibration=CalibrationConfig(temperature=1.0, temperature_per_persistence=0.0),
            )
        raise ValueError(f"unknown preset {name!r}; one of {PRESETS}")
