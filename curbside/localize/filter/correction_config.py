"""The parameters of the parts that repair a cloud gone wrong by re-drawing particles: sections of
:class:`~curbside.localize.filter.config.FilterConfig`.

:class:`RecoveryConfig` (:mod:`~curbside.localize.filter.recovery`: a collapsed cloud, a cloud that no
longer agrees with GNSS, a cloud the walls hold still, a cloud far from every fix),
:class:`ScaleCorrectionConfig` (:mod:`~curbside.localize.filter.scale`: a speed scale the fixes disagree
with) and
:class:`HeadingCorrectionConfig` (:mod:`~curbside.localize.filter.heading_correction`: a velocity that
turned). ``docs/filter.md`` gives the reasoning behind each value.
"""

from __future__ import annotations

from dataclasses import dataclass

from curbside.configio import check, non_negative, positive, require, unit_interval


def _check_scale_range(min_scale: float, max_scale: float) -> None:
    check(0.0 < min_scale < max_scale,
          f"need 0 < min_scale < max_scale, got min_scale {min_scale} and max_scale {max_scale}")


@dataclass(frozen=True)
class RecoveryConfig:
    """Recovery from a collapsed cloud, from a cloud that no longer agrees with GNSS, and from one far
    from every fix.

    Attributes
    ----------
    collapse_sigma_m
        Spread of particles re-seeded around the last estimate after every weight went to zero.
    alpha_fast, alpha_slow
        Rates (per fix) of the short- and long-term averages of the cloud's GNSS agreement (Augmented
        MCL, Thrun et al. 2005, table 8.3).
    trigger_ratio
        Particles are injected once the short-term average falls below this fraction of the long one.
        0.4 (version 0.1: 0.5): a phone's fixes can be off the same way for a minute, and at 0.5 such
        an episode read as a divergence and re-drew the cloud around the wrong fixes.
    kernel_scale
        The agreement kernel's sigma as a multiple of the GNSS likelihood's sigma.
    max_fraction
        At most this fraction of the particles is re-drawn around a fix at one update (0: off).
    inject_heading_sigma_deg
        A re-drawn particle takes a random particle's heading offset plus a Gaussian jitter of this
        sigma (degrees; 0: the offset as it is). A cloud often diverges because its heading offset is
        wrong, and particles that inherit it exactly run off the same way.
    stall_ratio
        The cloud is *stalled* when its estimate moved less than this fraction of the inertial
        displacement over the last ``stall_window_s`` (0: never). Walkers do not walk into walls, so a cloud
        that the map holds still while the phone walks on is in the wrong place.
    stall_window_s, stall_min_speed_mps
        The window, and the least net inertial speed over it for the test to apply (standing, or
        turning back, is no stall).
    stall_blocked_share
        ... and only when the map stopped at least this share of the particles (weight under 1 %) at
        an average update of the window: the walls hold the cloud, not fixes that pull it back.
    stall_fraction
        While stalled, this fraction of the particles (at most ``max_fraction``) is re-drawn around
        each usable fix, as for a divergence.
    relocate_distance_m
        The cloud is *lost* (started at a phone's stale last-known place, kidnapped) when, for
        ``relocate_after_s``, every usable fix reporting at most ``relocate_max_accuracy_m`` lay farther
        than this from the estimate; the whole cloud is then re-drawn around the latest fix (0: never).
        250 m: the largest fix error is 170 m in the tune split's simulated fixes (the largest distance
        of a fix from the estimate 177 m) and 38 m on the IPIN phones (``docs/filter.md``, "Lost: a
        cloud far from every fix").
    relocate_after_s, relocate_min_fixes
        How long the far fixes must have lasted (20 s: no run of fixes over 150 m from the estimate
        lasted 18 s on the tune split), and how many there must be at least in that time.
    relocate_max_accuracy_m
        Only fixes reporting this accuracy or better count; the others neither count nor stop the count.
    relocate_agreement_m, relocate_agreeing_share
        ... and only when this share of the far fixes of the last ``relocate_after_s`` lie within this
        distance of the latest one, the centre of the re-drawn cloud (one place, not scattered fixes; a
        centre that most of its neighbours agree with is seldom a multipath outlier).
    relocate_heading_sigma_deg
        Heading offsets of the re-drawn particles: each particle's own plus a Gaussian jitter of this
        sigma (degrees), as for an injection (the offset belongs to the phone, not to the place);
        ``None``: over the full circle, as a start at a fix.
    """

    collapse_sigma_m: float = 5.0
    alpha_fast: float = 0.02
    alpha_slow: float = 0.002
    trigger_ratio: float = 0.4
    kernel_scale: float = 5.0
    max_fraction: float = 0.25
    inject_heading_sigma_deg: float = 30.0
    stall_ratio: float = 0.2
    stall_window_s: float = 10.0
    stall_min_speed_mps: float = 0.5
    stall_blocked_share: float = 0.3
    stall_fraction: float = 0.1
    relocate_distance_m: float = 250.0
    relocate_after_s: float = 20.0
    relocate_min_fixes: int = 10
    relocate_max_accuracy_m: float = 20.0
    relocate_agreement_m: float = 50.0
    relocate_agreeing_share: float = 0.8
    relocate_heading_sigma_deg: float | None = 30.0

    def __post_init__(self) -> None:
        positive(self, "collapse_sigma_m", "stall_window_s", "stall_min_speed_mps", "kernel_scale",
                 "relocate_after_s", "relocate_min_fixes", "relocate_max_accuracy_m")
        non_negative(self, "relocate_distance_m", "relocate_agreement_m")
        unit_interval(self, "relocate_agreeing_share")
        if self.relocate_heading_sigma_deg is not None:
            non_negative(self, "relocate_heading_sigma_deg")
        require("lie in [0, 1)", lambda v: 0.0 <= v < 1.0, {"stall_ratio": self.stall_ratio})
        unit_interval(self, "stall_fraction", "stall_blocked_share", "max_fraction")
        non_negative(self, "inject_heading_sigma_deg")
        check(0.0 < self.alpha_slow < self.alpha_fast <= 1.0, "need 0 < alpha_slow < alpha_fast <= 1, got "
              f"alpha_slow {self.alpha_slow} and alpha_fast {self.alpha_fast}")
        require("lie in (0, 1]", lambda v: 0.0 < v <= 1.0, {"trigger_ratio": self.trigger_ratio})


@dataclass(frozen=True)
class ScaleCorrectionConfig:
    """GNSS-driven speed-scale correction (:class:`~curbside.localize.filter.scale.ScaleCorrection`).

    Attributes
    ----------
    fraction
        Share of the particles whose speed scale is re-drawn around the fitted one when a fit disagrees
        with the cloud (0, the default: off; 0.05 is the value tried, see ``docs/filter.md``).
    window_s
        The fixes of the last this many seconds are fitted against the cloud's inertial path; a fit is
        made at most every quarter window, once the window is three quarters full.
    trigger
        A fit acts only when its scale differs from the cloud's mean by more than this (relative) ...
    significance
        ... and by more than this many of its standard errors ...
    max_rotation_deg
        ... and it needs a rotation under this (a fit that turns the path a lot does not describe it).
    sigma
        Log-normal spread of the re-drawn scales around the fitted one.
    min_scale, max_scale
        Re-drawn scales are clipped to this range.
    min_path_m
        A fit needs a path spanning at least ``max(min_path_m, 3 sqrt(2) median accuracy)``.
    trim_share
        The fit is repeated without this share of the fixes farthest from the first fit.
    correlation_s
        The fit's standard error counts one independent fix per this many seconds (successive fixes
        share most of their error).
    """

    fraction: float = 0.0
    window_s: float = 60.0
    trigger: float = 0.15
    significance: float = 3.0
    max_rotation_deg: float = 20.0
    sigma: float = 0.05
    min_scale: float = 0.6
    max_scale: float = 1.6
    min_path_m: float = 20.0
    trim_share: float = 0.2
    correlation_s: float = 30.0

    def __post_init__(self) -> None:
        unit_interval(self, "fraction")
        require("lie in [0, 1)", lambda v: 0.0 <= v < 1.0, {"trim_share": self.trim_share})
        _check_scale_range(self.min_scale, self.max_scale)
        positive(self, "window_s", "trigger", "significance", "max_rotation_deg", "correlation_s")
        non_negative(self, "sigma", "min_path_m")


@dataclass(frozen=True)
class HeadingCorrectionConfig:
    """GNSS-driven correction of a velocity that turned (:mod:`~curbside.localize.filter.heading_correction`).

    Attributes
    ----------
    fraction
        Share of the particles re-drawn, after resampling, where the fit puts the walker, with the
        fitted turn and speed scale, when the gates below pass (0: off; the paper's preset).
    window_s
        The accepted fixes of the last this many seconds are fitted on the cloud's inertial path and on
        its estimated track; a fit is made at most every quarter window, once three quarters are in.
    max_accuracy_m
        The fixes' median reported accuracy must be at most this: only fixes good enough to steer by.
    max_residual_ratio
        The fixes must lie this close to the fitted path: root mean square distance at most this times
        their median accuracy (fixes that wander with multipath do not fit a turned walk).
    min_rotation_deg
        The fit must turn the inertial path by at least this ...
    min_estimate_rotation_deg
        ... and the filter's own track by at least this: the cloud really walks off the fixes.
    min_scale, max_scale
        The fitted speed scale must lie in this range (a fit outside it describes no walk).
    min_path_m, min_fix_span_m
        The window's inertial path must span at least ``min_path_m`` and its fixes
        ``max(min_fix_span_m, 3 sqrt(2) median accuracy)``.
    heading_sigma_deg, scale_sigma, position_sigma_factor
        Spread of the re-drawn particles: heading offset (degrees) around the cloud's own plus the
        fitted turn, log-normal speed scale around the fitted one, position around where the fit puts
        the walker (times the median accuracy).
    """

    fraction: float = 0.1
    window_s: float = 30.0
    max_accuracy_m: float = 6.0
    max_residual_ratio: float = 0.5
    min_rotation_deg: float = 30.0
    min_estimate_rotation_deg: float = 20.0
    min_scale: float = 0.5
    max_scale: float = 2.2
    min_path_m: float = 5.0
    min_fix_span_m: float = 10.0
    heading_sigma_deg: float = 10.0
    scale_sigma: float = 0.05
    position_sigma_factor: float = 0.66

    def __post_init__(self) -> None:
        unit_interval(self, "fraction")
        _check_scale_range(self.min_scale, self.max_scale)
        positive(self, "window_s", "max_accuracy_m", "max_residual_ratio")
        non_negative(self, "min_rotation_deg", "min_estimate_rotation_deg", "min_path_m", "min_fix_span_m",
                     "heading_sigma_deg", "scale_sigma", "position_sigma_factor")
