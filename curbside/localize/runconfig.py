"""Every parameter of a tracking run, in one frozen :class:`RunConfig` written whole to ``run.json``.

A run is reproducible from its ``run.json`` alone (``localize run --config run.json``): the method, the
seed, the filter's parameters (:class:`~curbside.localize.filter.config.FilterConfig`) and the engine's
(:class:`EngineConfig`: where velocity and footsteps come from, how fixes are matched to updates, when
the filter advances without a footstep). The choices and the defaults that ``--help`` quotes are plain
values in :mod:`curbside.localize.runconstants`, which the command line imports instead of this module.
"""

from __future__ import annotations

import contextlib
import json
import math
import numbers
from dataclasses import dataclass, field, replace
from typing import Any

from curbside.configio import (
    beyond_memory,
    check,
    from_dict,
    non_negative,
    positive,
    require,
    to_dict,
    unit_interval,
    with_overrides,
)
from curbside.errors import CurbsideInputError
from curbside.localize.filter.config import BYTES_PER_PARTICLE, FilterConfig
from curbside.localize.pdr import PdrConfig
from curbside.localize.ronin.stream import RoninStreamConfig
from curbside.localize.runconstants import (
    FAMILIAR_VELOCITY_DEFAULTS,
    FAMILIAR_VELOCITY_MODES,
    FIX_ASSOCIATIONS,
    FIX_LAG_MODES,
    MAX_FIX_LAG_S,
    MODES,
    STEP_SOURCES,
    UNSEEN_VELOCITY_DEFAULTS,
    UNSEEN_VELOCITY_MODES,
    VELOCITY_SOURCES,
)
from curbside.localize.steps import StepConfig

_MAP_KEYS_0_1 = frozenset({"jaywalk_weight", "wall_tolerance_m", "raster_resolution_m", "segment_reach_m"})
#: ``filter.map`` blocks as earlier versions wrote them whole, and the values they ran with.
_MAP_KEYS_STOP_27 = _MAP_KEYS_0_1 | {"conflict_share_min", "conflict_wall_tolerance_m"}
_EARLIER_MAP_BLOCKS: tuple[tuple[frozenset[str], dict[str, Any]], ...] = (
    (
        _MAP_KEYS_0_1,
        {"conflict_wall_tolerance_m": 0.0, "conflict_walkable_first": False, "crossing_weight": None},
    ),
    (_MAP_KEYS_STOP_27, {"conflict_walkable_first": False, "crossing_weight": None}),
    (_MAP_KEYS_STOP_27 | {"conflict_walkable_first"}, {"crossing_weight": None}),
)
#: The keys of every whole ``filter.gnss`` block since 0.1; one without ``correlation_accuracy_m`` was
#: written before it and ran with one correlation time for every fix.
_GNSS_KEYS_0_1 = frozenset(
    {"sigma_factor", "max_accuracy_m", "outlier_prob", "outlier_radius_m", "correlation_time_s",
     "bias_time_s"}
)
#: The keys of every whole ``filter.street_heading`` block since the part came (off by default); one
#: without ``max_turn_deg`` ran without the turn gate. A whole ``filter`` block without the part
#: (whole ``gnss`` block, no ``street_heading``) ran without it.
_STREET_HEADING_KEYS_STOP_25 = frozenset(
    {"strength_per_m", "floor", "min_step_m", "min_sidewalk_share", "min_axis_agreement"}
)


def _as_it_ran(filter_block: dict[str, Any]) -> dict[str, Any]:
    """``run.json``'s ``filter`` block with the values an earlier version's whole sub-blocks ran with."""
    map_block, gnss_block = filter_block.get("map"), filter_block.get("gnss")
    for keys, as_it_ran in _EARLIER_MAP_BLOCKS:
        if isinstance(map_block, dict) and set(map_block) == keys:
            filter_block = {**filter_block, "map": {**map_block, **as_it_ran}}
    whole_gnss_block = isinstance(gnss_block, dict) and set(gnss_block) >= _GNSS_KEYS_0_1
    if whole_gnss_block and "correlation_accuracy_m" not in gnss_block:
        filter_block = {**filter_block, "gnss": {**gnss_block, "correlation_accuracy_m": 0.0}}
    if whole_gnss_block and "heading_correction" not in filter_block:
        filter_block = {**filter_block, "heading_correction": {"fraction": 0.0}}
    heading_block = filter_block.get("street_heading")
    if whole_gnss_block and heading_block is None:
        filter_block = {**filter_block, "street_heading": {"strength_per_m": 0.0}}
    elif isinstance(heading_block, dict) and set(heading_block) >= _STREET_HEADING_KEYS_STOP_25:
        filter_block = {**filter_block, "street_heading": {"max_turn_deg": 90.0, **heading_block}}
    return filter_block


def non_finite_keys(tree: Any, prefix: str = "config") -> list[str]:
    """The keys in a config's JSON tree (:func:`~curbside.configio.to_dict` output, or a ``run.json``
    ``config``) that hold a non-finite number (``inf``, ``-inf``, ``nan``), named from ``prefix``."""
    if isinstance(tree, dict):
        return [k for key, value in tree.items() for k in non_finite_keys(value, f"{prefix}.{key}")]
    if isinstance(tree, list | tuple):
        return [k for i, value in enumerate(tree) for k in non_finite_keys(value, f"{prefix}[{i}]")]
    return [prefix] if isinstance(tree, float) and not math.isfinite(tree) else []


def check_finite(tree: Any, prefix: str = "config") -> None:
    """Refuse a config's JSON tree that holds a non-finite number (see :func:`non_finite_keys`).

    Raises
    ------
    CurbsideInputError
        Named by the first such key, e.g. ``config.filter.gnss.sigma_factor: must be a finite number``.
    """
    bad = non_finite_keys(tree, prefix)
    if bad:
        raise CurbsideInputError(bad[0], "must be a finite number")


def _override_value(value: Any) -> Any:
    """An override's value as :func:`~curbside.configio.with_overrides` reads it: JSON text, else as it is."""
    if isinstance(value, str):
        with contextlib.suppress(json.JSONDecodeError):
            return json.loads(value)
    return value


@dataclass(frozen=True)
class EngineConfig:
    """How a session's streams become filter updates.

    Attributes
    ----------
    velocity_source
        ``auto`` (``velocity.csv``, else RoNIN on ``imu.csv``, PDR on one ``localize simulate`` made or
        without RoNIN), ``file``, ``ronin`` or ``pdr``.
    step_source
        ``auto`` (``steps.csv``, else detected in ``imu.csv``, else a fixed cadence), ``file``,
        ``detect`` or ``cadence``.
    cadence_s
        Update interval when footsteps come from a fixed cadence.
    max_update_interval_s
        With no footstep for this long, the filter still advances (a time-grid update): no stretch of
        walking goes untracked when the detector misses steps, and the track covers the recording.
    fix_association
        ``interpolate`` (the paper: the fix interpolated at every update, bracketing fixes at most
        ``interp_max_gap_s`` apart, else the latest one not older than ``max_fix_age_s``) or ``once``
        (each fix at the first update at or after it, and never again).
    interp_max_gap_s, max_fix_age_s
        See ``fix_association``.
    velocity_max_gap_s
        Velocity samples further apart are a gap: no motion is integrated across it.
    standing_speed_mps
        A time-grid update (no footstep for ``max_update_interval_s``) whose inertial speed over the
        interval is under this counts as standing: the particles do not move (0: off). A velocity
        model reads a few tenths of a m/s for a phone in the hand of someone standing still; the
        speed bound keeps a walk whose footsteps the detector misses moving. Needs footsteps (a file
        or the detector), not a fixed cadence.
    heading_align_distance_m
        With a known start heading, the heading offset turns the first this-many metres of inertial
        motion onto it.
    extent_tolerance_m
        A session is outside the map when no fix lies within this distance of its extent.
    steps
        The footstep detector (:class:`~curbside.localize.steps.StepConfig`).
    pdr
        Pedestrian dead reckoning, the velocity when RoNIN is not available
        (:class:`~curbside.localize.pdr.PdrConfig`).
    ronin
        RoNIN on the IMU stream: rate, window, stride, inference batch and IMU preprocessing
        (:class:`~curbside.localize.ronin.stream.RoninStreamConfig`).
    """

    velocity_source: str = "auto"
    step_source: str = "auto"
    cadence_s: float = 0.5
    max_update_interval_s: float = 1.0
    fix_association: str = "interpolate"
    interp_max_gap_s: float = 2.0
    max_fix_age_s: float = 3.0
    velocity_max_gap_s: float = 1.0
    standing_speed_mps: float = 0.0
    heading_align_distance_m: float = 3.0
    extent_tolerance_m: float = 100.0
    steps: StepConfig = field(default_factory=StepConfig)
    pdr: PdrConfig = field(default_factory=PdrConfig)
    ronin: RoninStreamConfig = field(default_factory=RoninStreamConfig)

    def __post_init__(self) -> None:
        check(
            self.velocity_source in VELOCITY_SOURCES,
            f"velocity_source must be one of {VELOCITY_SOURCES}, got {self.velocity_source!r}",
        )
        check(
            self.step_source in STEP_SOURCES,
            f"step_source must be one of {STEP_SOURCES}, got {self.step_source!r}",
        )
        check(
            self.fix_association in FIX_ASSOCIATIONS,
            f"fix_association must be one of {FIX_ASSOCIATIONS}, got {self.fix_association!r}",
        )
        positive(self, "cadence_s", "max_update_interval_s", "velocity_max_gap_s")
        non_negative(self, "interp_max_gap_s", "max_fix_age_s", "heading_align_distance_m",
                     "extent_tolerance_m", "standing_speed_mps")

    @property
    def fix_lookahead_s(self) -> float:
        """How far past an update the fixes must be known before the update can be made."""
        return self.interp_max_gap_s if self.fix_association == "interpolate" else 0.0


@dataclass(frozen=True)
class UnseenVelocityConfig:
    """The motion model for a velocity model that has not seen this phone, its carrier or the place.

    A new user's usual case (docs/filter.md, "A velocity model that has not seen the place"): a wider
    step noise, the standing rule and the GNSS-driven speed-scale correction. Chosen on the benchmark's
    tune split and the IPIN training trials tracked with a RoNIN that never saw that venue; where the
    model was trained on the same place (the IPIN held-out trials with the bundled RoNIN) it costs
    accuracy, hence ``auto``.

    Attributes
    ----------
    mode
        ``off``; ``on`` (``--unseen-velocity``: from the start); ``auto`` (curbside fused's default): from
        the update at which the velocity model is caught reading motion while the walker stands (below).
    still_speed_mps, still_updates, settle_s
        ``auto``: after ``still_updates`` time-grid updates at least ``settle_s`` after the last footstep
        (RoNIN's one-second window still carries the last steps before that) and slower than the
        standing bound, the model is unseen when their median inertial speed is at least
        ``still_speed_mps``. The bundled RoNIN reads 0.002 m/s on the IPIN trials while no footstep
        comes, a RoNIN that never saw them 0.25-0.49 m/s (per-trial 10th-90th percentile). Needs
        footsteps (a file or the detector) and sampled velocity (not PDR).
    step_noise_fraction, step_noise_across_fraction, standing_speed_mps, scale_correction_fraction
        The preset: ``filter.motion.step_noise_fraction`` (along the step) and
        ``step_noise_across_fraction`` (across it; ``None``: isotropic), ``engine.standing_speed_mps`` and
        ``filter.scale_correction.fraction`` once it applies.
    """

    mode: str = UNSEEN_VELOCITY_DEFAULTS.mode
    still_speed_mps: float = UNSEEN_VELOCITY_DEFAULTS.still_speed_mps
    still_updates: int = UNSEEN_VELOCITY_DEFAULTS.still_updates
    settle_s: float = UNSEEN_VELOCITY_DEFAULTS.settle_s
    step_noise_fraction: float = UNSEEN_VELOCITY_DEFAULTS.step_noise_fraction
    step_noise_across_fraction: float | None = UNSEEN_VELOCITY_DEFAULTS.step_noise_across_fraction
    standing_speed_mps: float = UNSEEN_VELOCITY_DEFAULTS.standing_speed_mps
    scale_correction_fraction: float = UNSEEN_VELOCITY_DEFAULTS.scale_correction_fraction

    def __post_init__(self) -> None:
        check(
            self.mode in UNSEEN_VELOCITY_MODES,
            f"mode must be one of {UNSEEN_VELOCITY_MODES}, got {self.mode!r}",
        )
        check(self.still_updates >= 1, f"still_updates must be at least 1, got {self.still_updates}")
        check(
            self.step_noise_across_fraction is None or self.step_noise_across_fraction >= 0,
            f"step_noise_across_fraction must be non-negative, got {self.step_noise_across_fraction}",
        )
        non_negative(self, "still_speed_mps", "settle_s", "step_noise_fraction", "standing_speed_mps")
        unit_interval(self, "scale_correction_fraction")


@dataclass(frozen=True)
class FamiliarVelocityConfig:
    """The calm motion model for a velocity model that knows this phone, its carrier and the place.

    A learned velocity model on ground it knows reads a smooth speed from one half-second to the next;
    one new to the phone, the gait or the place jitters (docs/filter.md, "A velocity model fitted to
    the walker"). On the IPIN trials the bundled RoNIN, trained on the other repetitions of the same
    routes, changes its speed by 3.4 % at the median from one half-second to the next, a RoNIN that
    never saw the venue by 8.9 %, and the simulator's ``phone`` profile by 8.3 %. Where the model knows
    the walker, its speed scale is right and its heading drifts slowly, and a calm motion model beats
    the default one, which is made for phones the model has not seen.

    Attributes
    ----------
    mode
        ``off`` (the default); ``auto`` (``--familiar-velocity``): a second filter with the calm motion
        runs beside the default one from the start, and the track follows it while the speed reads
        smooth (below); the decision is final after ``final_samples``, and the filter that lost is then
        dropped; ``on``: the calm motion from the start. Opt-in: a velocity that is smooth but whose
        scale is off by 10 % or more loses to good fixes under the calm motion (docs/filter.md), so
        use it where the velocity model is known to be fitted to the walker (a model trained on their
        own walks).
    window_s, min_speed_mps
        The speed is sampled over consecutive windows of ``window_s`` seconds; a pair of windows both at
        least ``min_speed_mps`` (walking) gives one sample of the relative change
        ``|v2 - v1| / mean(v1, v2)``.
    jitter_max, min_samples, final_samples
        The velocity reads smooth while the median of the samples so far is under ``jitter_max``, once
        there are ``min_samples`` of them; at ``final_samples`` the decision is final (0: never).
        Needs sampled velocity (RoNIN or a velocity file), not PDR, whose speed is smooth by
        construction.
    heading_noise_deg, step_noise_fraction
        The calm motion: ``filter.motion.heading_noise_deg`` and ``step_noise_fraction`` (isotropic) ...
    scale_init_sigma, scale_correction_fraction
        ... and its speed scale: ``filter.motion.scale_init_sigma`` (no random walk) and
        ``filter.scale_correction.fraction``; by default 0 and 0, no speed-scale state, since a scale
        learnt from phones' fixes comes out too small (docs/filter.md).
    """

    mode: str = FAMILIAR_VELOCITY_DEFAULTS.mode
    window_s: float = FAMILIAR_VELOCITY_DEFAULTS.window_s
    min_speed_mps: float = FAMILIAR_VELOCITY_DEFAULTS.min_speed_mps
    jitter_max: float = FAMILIAR_VELOCITY_DEFAULTS.jitter_max
    min_samples: int = FAMILIAR_VELOCITY_DEFAULTS.min_samples
    final_samples: int = FAMILIAR_VELOCITY_DEFAULTS.final_samples
    heading_noise_deg: float = FAMILIAR_VELOCITY_DEFAULTS.heading_noise_deg
    step_noise_fraction: float = FAMILIAR_VELOCITY_DEFAULTS.step_noise_fraction
    scale_init_sigma: float = FAMILIAR_VELOCITY_DEFAULTS.scale_init_sigma
    scale_correction_fraction: float = FAMILIAR_VELOCITY_DEFAULTS.scale_correction_fraction

    def __post_init__(self) -> None:
        check(
            self.mode in FAMILIAR_VELOCITY_MODES,
            f"mode must be one of {FAMILIAR_VELOCITY_MODES}, got {self.mode!r}",
        )
        positive(self, "window_s", "min_speed_mps", "jitter_max")
        check(self.min_samples >= 1, f"min_samples must be at least 1, got {self.min_samples}")
        non_negative(self, "final_samples", "heading_noise_deg", "step_noise_fraction", "scale_init_sigma")
        unit_interval(self, "scale_correction_fraction")


@dataclass(frozen=True)
class FixLagConfig:
    """The GNSS receiver's lag: a phone's fixes trail its walker.

    A phone's location comes out of the receiver's own smoothing filter, so the fixes trail the walk:
    on the IPIN trials by 2.0 m along the walking direction at the median (docs/filter.md, "Fixes that
    trail the walker"). The engine moves each fix forward by the inertial motion that a first-order lag
    of ``lag_s`` seconds holds back: ``D(t) - EMA(D)(t)``, ``D`` the inertial displacement.

    Attributes
    ----------
    mode
        ``off`` (the default): the fixes as they are; ``fixed``: ``lag_s`` everywhere, for a receiver
        whose lag is known; ``auto``: a batch run estimates the lag from the whole recording before it
        tracks (:func:`curbside.localize.fix_lag.estimate_fix_lag`), a stream, which cannot look ahead,
        uses ``lag_s``. Opt-in: on the IPIN trials a 2 s lag takes 0.2 m off the median error, but the
        estimate gains nothing on the held-out trials and reads a lag into 2 of the simulated open-sky
        walks, whose fixes have none (docs/filter.md, "Fixes that trail the walker").
    lag_s
        The lag compensated by ``fixed`` and by a stream under ``auto`` (s; 0: none; at most 10 s,
        :data:`~curbside.localize.runconstants.MAX_FIX_LAG_S`: a receiver lags a few seconds).
    candidates_s
        The lags the estimate chooses from (besides 0): at least one, each in (0, 10] s.
    block_s, hop_s, min_fixes
        The recording is cut into blocks of ``block_s`` seconds every ``hop_s``; a block with at least
        ``min_fixes`` usable fixes is scored.
    ratio_max, min_block_share
        A lag is chosen only if its mean residual is under ``ratio_max`` times the residual of no lag,
        and it beats no lag in at least ``min_block_share`` of the blocks.
    accuracy_max_m
        Fixes reporting a worse accuracy are not used by the estimate.
    """

    mode: str = "off"
    lag_s: float = 0.0
    candidates_s: tuple[float, ...] = (1.0, 2.0, 3.0, 4.0)
    block_s: float = 60.0
    hop_s: float = 30.0
    min_fixes: int = 20
    ratio_max: float = 0.92
    min_block_share: float = 0.7
    accuracy_max_m: float = 50.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "candidates_s", tuple(float(c) for c in self.candidates_s))
        check(self.mode in FIX_LAG_MODES, f"mode must be one of {FIX_LAG_MODES}, got {self.mode!r}")
        why = f"{MAX_FIX_LAG_S:g}] s (a receiver's smoothing lags a few seconds)"
        require(f"lie in [0, {why}", lambda v: 0 <= v <= MAX_FIX_LAG_S, {"lag_s": self.lag_s})
        check(bool(self.candidates_s), "candidates_s must list at least one lag for the estimate to weigh "
              "against none, got []")
        require(f"lie in (0, {why}", lambda v: 0 < v <= MAX_FIX_LAG_S,
                {f"candidates_s[{i}]": c for i, c in enumerate(self.candidates_s)})
        positive(self, "block_s", "accuracy_max_m")
        check(0 < self.hop_s <= self.block_s,
              f"hop_s must lie in (0, block_s], got hop_s {self.hop_s} and block_s {self.block_s}")
        check(self.min_fixes >= 3, f"min_fixes must be at least 3, got {self.min_fixes}")
        require("lie in (0, 1]", lambda v: 0 < v <= 1, {"ratio_max": self.ratio_max})
        unit_interval(self, "min_block_share")


@dataclass(frozen=True)
class RunConfig:
    """One tracking run: method, seed, whether to use the known start pose, and every parameter.

    Attributes
    ----------
    mode
        ``gnss``, ``inertial``, ``paper`` or ``fused`` (:data:`MODES`).
    seed
        Seed of the filter: same seed and inputs, same track.
    use_start_pose
        Start from ``meta.json``'s start pose when there is one (the paper's setting); otherwise from
        the first usable fix at or after the pose's time.
    filter
        The particle filter's parameters (the ``paper`` mode uses ``FilterConfig.preset("paper")``).
    engine
        How the session's streams become updates.
    unseen_velocity
        When to switch to the motion model for a velocity model new to the phone or the place.
    familiar_velocity
        When to follow the calm motion model for a velocity model that knows the walker.
    fix_lag
        How far the GNSS fixes trail the walker, and whether to estimate it.
    """

    mode: str = "fused"
    seed: int = 0
    use_start_pose: bool = True
    filter: FilterConfig = field(default_factory=FilterConfig)
    engine: EngineConfig = field(default_factory=EngineConfig)
    unseen_velocity: UnseenVelocityConfig = field(default_factory=UnseenVelocityConfig)
    familiar_velocity: FamiliarVelocityConfig = field(default_factory=FamiliarVelocityConfig)
    fix_lag: FixLagConfig = field(default_factory=FixLagConfig)

    def __post_init__(self) -> None:
        check(self.mode in MODES, f"mode must be one of {MODES}, got {self.mode!r}")
        # numpy would refuse a negative seed only when the filter starts (an internal error by then)
        check(isinstance(self.seed, numbers.Integral) and self.seed >= 0,
               f"seed must be a non-negative integer, got {self.seed!r}")
        # the sections check their ranges with comparisons, which inf passes and nan escapes
        check_finite(to_dict(self))
        self._check_particle_memory()

    def _check_particle_memory(self) -> None:
        """Refuse particles whose arrays need more memory than the machine has (two filters track
        under ``familiar_velocity.mode = auto``)."""
        if self.mode == "gnss":
            return
        n = self.filter.n_particles
        filters = 2 if self.familiar_velocity.mode == "auto" else 1
        lacking = beyond_memory(filters * n * BYTES_PER_PARTICLE)
        two = " (two filters under familiar_velocity.mode auto)" if filters == 2 else ""
        check(lacking is None, f"filter.n_particles (--particles) {n}: the particle arrays{two} would need "
              f"{lacking}")

    @classmethod
    def for_mode(cls, mode: str, **kwargs: Any) -> RunConfig:
        """The default run of ``mode`` (the paper preset for ``paper``); ``kwargs`` set other fields.

        Only curbside fused switches to the unseen-velocity motion model (``auto``); the baselines
        (``inertial``, ``paper``) keep their own motion model and take the fixes as they come.
        """
        check(mode in MODES, f"mode must be one of {MODES}, got {mode!r}")
        preset = FilterConfig.preset("paper" if mode == "paper" else "fused")
        if mode != "fused":
            kwargs.setdefault("unseen_velocity", UnseenVelocityConfig(mode="off"))
        return cls(mode=mode, filter=kwargs.pop("filter", preset), **kwargs)

    def with_overrides(self, overrides: dict[str, Any]) -> RunConfig:
        """A copy with ``{"filter.gnss.sigma_factor": 1.0, ...}`` overrides (see :mod:`curbside.configio`).

        Raises
        ------
        CurbsideInputError
            An unknown key or a bad value; a non-finite number is named ``config.KEY`` before any range
            check of its section sees it.
        """
        for key, value in overrides.items():
            check_finite(_override_value(value), f"config.{key}")
        return with_overrides(self, overrides) if overrides else self

    def with_particles(self, n: int) -> RunConfig:
        """A copy with ``n`` particles."""
        return replace(self, filter=replace(self.filter, n_particles=int(n)))

    def with_unseen_velocity(self) -> RunConfig:
        """A copy whose filter and engine carry the :class:`UnseenVelocityConfig` preset's values."""
        u = self.unseen_velocity
        f = self.filter
        return replace(
            self,
            filter=replace(
                f,
                motion=replace(
                    f.motion,
                    step_noise_fraction=u.step_noise_fraction,
                    step_noise_across_fraction=u.step_noise_across_fraction,
                ),
                scale_correction=replace(f.scale_correction, fraction=u.scale_correction_fraction),
            ),
            engine=replace(self.engine, standing_speed_mps=u.standing_speed_mps),
        )

    def with_familiar_velocity(self) -> RunConfig:
        """A copy whose filter moves with the :class:`FamiliarVelocityConfig` calm motion (no speed-scale
        state)."""
        c = self.familiar_velocity
        motion = replace(
            self.filter.motion,
            heading_noise_deg=c.heading_noise_deg,
            step_noise_fraction=c.step_noise_fraction,
            step_noise_across_fraction=None,
            scale_init_sigma=c.scale_init_sigma,
            scale_noise_per_step=0.0,
        )
        correction = replace(self.filter.scale_correction, fraction=c.scale_correction_fraction)
        return replace(self, filter=replace(self.filter, motion=motion, scale_correction=correction))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the ``config`` member of ``run.json``)."""
        return to_dict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "run.json config") -> RunConfig:
        """Rebuild from :meth:`to_dict` output (unknown keys or bad values: one-line input error).

        A config written before the ``unseen_velocity`` block existed ran without it: it replays with
        mode ``off``, not today's default. One whose ``filter.map`` holds exactly the keys an earlier
        version wrote replays without the conflict rule's later parts, as it ran: hard walls on every
        map before ``conflict_*`` existed, buildings over sidewalks before ``conflict_walkable_first``
        (a partial block written by hand keeps the defaults). A whole ``filter.gnss`` block without
        ``correlation_accuracy_m`` replays with one correlation time for every fix; a whole ``filter``
        block without ``street_heading`` replays without that part, and a whole ``street_heading`` block
        without ``max_turn_deg`` without its turn gate; a whole ``filter`` block without
        ``heading_correction`` replays without the heading correction. A non-finite number (JSON's
        ``Infinity``, ``NaN``) is refused, named ``WHERE.KEY``.
        """
        check_finite(data, where)  # named here with the file; the class's own check cannot say which
        if isinstance(data, dict) and "unseen_velocity" not in data:
            data = {**data, "unseen_velocity": {"mode": "off"}}
        filter_block = data.get("filter") if isinstance(data, dict) else None
        if isinstance(filter_block, dict):
            data = {**data, "filter": _as_it_ran(filter_block)}
        return from_dict(cls, data, where)
