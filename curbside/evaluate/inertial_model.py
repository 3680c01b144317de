"""Simulated inertial sensing: a RoNIN-like world-frame velocity and a hand-held phone's IMU.

``velocity.csv`` is what RoNIN would output: the true velocity averaged over a 1 s window, rotated by
a heading error and scaled by a speed-scale error, plus noise (:class:`VelocityErrorModel`). Two
profiles set the magnitudes:

``nominal`` (:class:`VelocityErrorModel`)
    RoNIN's *published* error levels: a small constant heading bias, a slow linear drift and random
    walk, a 6 % scale error, 0.12 m/s noise.
``phone`` (:class:`PhoneVelocityErrorModel`)
    A phone in a hand, downtown: larger bias, drift and random walk (measured on real phones,
    :mod:`curbside.evaluate.inertial_errors`), abrupt heading offsets when the phone changes hands,
    goes to a pocket or is looked at, a per-walk speed scale off by 10-20 %, step-to-step speed
    noise, and phantom motion while the walker stands at a kerb.

The realised error processes (:class:`InertialErrors`) are drawn once per session, written into
``meta.json`` (bias, drift, every jump with its time and size, the speed scale, phantom distance) and
shared by ``velocity.csv`` and ``imu.csv`` (whose orientation quaternion carries the same heading
error): one phone, one orientation error.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from curbside.evaluate.walker import Walk, ou

GRAVITY = 9.80665


@dataclass(frozen=True)
class VelocityErrorModel:
    """RoNIN-like velocity errors, ``nominal`` profile (RoNIN's published ATE/RTE; docs/evaluate.md).

    The components past ``noise_tau_s`` are zero here: the ``phone`` profile
    (:class:`PhoneVelocityErrorModel`) switches them on.
    """

    #: Output rate (Hz) and averaging window (s).
    rate_hz: float = 10.0
    window_s: float = 1.0
    #: Heading error: constant bias 1-sigma (deg), linear drift 1-sigma (deg/min),
    #: random walk (deg/sqrt(min)).
    heading_bias_deg: float = 4.0
    heading_drift_deg_per_min: float = 1.0
    heading_walk_deg_per_sqrt_min: float = 2.0
    #: Scale error: 1-sigma of the per-walk scale, and of its slow wander (time constant 60 s).
    scale_sd: float = 0.06
    scale_wander_sd: float = 0.03
    #: Velocity noise 1-sigma per axis (m/s), correlated over ``noise_tau_s``; present while
    #: standing too.
    noise_mps: float = 0.12
    noise_tau_s: float = 1.0
    #: Correlated heading noise 1-sigma (deg) and time constant (s): local magnetic disturbances.
    heading_noise_deg: float = 0.0
    heading_noise_tau_s: float = 15.0
    #: Abrupt heading offsets (phone changes hands, goes to a pocket): Poisson rate per minute,
    #: and the range of their size (deg, uniform, random sign). Each one persists.
    heading_jump_rate_per_min: float = 0.0
    heading_jump_deg: tuple[float, float] = (10.0, 25.0)
    #: Probability that the phone is looked at or handled during a stop at a kerb, with a heading
    #: offset of the same size at a random moment of the stop.
    stop_jump_prob: float = 0.0
    #: Step-to-step speed noise: relative 1-sigma, correlated over ``speed_noise_tau_s`` (s).
    speed_noise_cv: float = 0.0
    speed_noise_tau_s: float = 1.0
    #: Phantom motion while standing: RMS speed (m/s) of a spurious velocity, correlated over
    #: ``phantom_tau_s`` (s), added while the walker waits at a kerb.
    phantom_mps: float = 0.0
    phantom_tau_s: float = 3.0


@dataclass(frozen=True)
class PhoneVelocityErrorModel(VelocityErrorModel):
    """The ``phone`` profile: RoNIN on a phone held in a hand, downtown.

    Each magnitude's source (``python -m curbside.evaluate.inertial_errors`` measures the IPIN
    figures; docs/evaluate.md has the tables):
    """

    #: 10 deg: spread of the per-walk mean heading error of RoNIN on the 9 held-out IPIN 2023
    #: trials (10.2 deg; the rotation vector alone on all 43 trials: 9.0 deg, up to 24 deg);
    #: smartphone compasses err by 13-25 deg near steel and electrical infrastructure (Afzal,
    #: Renaudin & Lachapelle, IPIN 2011). The paper's RoNIN used a gyro-only orientation, whose
    #: yaw origin is arbitrary: the start heading removes a bias in any case.
    heading_bias_deg: float = 10.0
    #: 3 deg/min: median absolute linear trend of the heading error per IPIN trial (RoNIN 2.8,
    #: rotation vector 3.3 deg/min).
    heading_drift_deg_per_min: float = 3.0
    #: 5 deg/sqrt(min): the growth of the heading-error variogram over 2 min on IPIN (RoNIN 4.8,
    #: rotation vector 6.9 deg/sqrt(min)).
    heading_walk_deg_per_sqrt_min: float = 5.0
    #: 12 %: "+-10-20 %" per walk. On held-out IPIN, RoNIN's distance ratio spreads by 6 % on the two
    #: phones it was trained on; the same model on another phone and walker (MS indoor, 128 paths)
    #: and PDR with an IPIN-calibrated step constant on MS (ratio 1.21) show what a new phone adds.
    scale_sd: float = 0.12
    #: 5 %: spread of the leg-by-leg speed ratio within an IPIN trial (4.9 % median).
    scale_wander_sd: float = 0.05
    #: 5 deg over 15 s: what remains of the 11 deg per-leg heading noise on IPIN once surveying
    #: and straight-line ground-truth error are allowed for (an assumption within that bound).
    heading_noise_deg: float = 5.0
    #: 0.1 per minute, 10-25 deg ("tens of degrees, a few times per walk", with the stops below):
    #: carrying-mode changes shift the walking-direction error (median 5.5 deg texting vs 12 deg in a
    #: pocket, Combettes & Renaudin, NAVIGATION 67(4), 2020) and disturb the orientation filter in
    #: the transition; IPIN's phones, held steadily, show leg-to-leg changes of 20 deg (median of the
    #: largest per trial), bounded by the ground truth's own noise. Rate and size were chosen on the
    #: tune split (0-0.3/min, 10-45 deg tried) so that RoNIN+PF's median error matches the paper's
    #: phone-in-hand RoNIN+PF (16 m); docs/evaluate.md has the calibration table.
    heading_jump_rate_per_min: float = 0.1
    heading_jump_deg: tuple[float, float] = (10.0, 25.0)
    #: A quarter of the stops: a walker waiting for the light takes the phone out or looks at it (an
    #: assumption, chosen with the jump rate above).
    stop_jump_prob: float = 0.25
    #: 15 % over 1 s: step-to-step variability of RoNIN's speed (IPIN legs average it down to 5 %
    #: over ~10 s legs, i.e. about 15 % per second).
    speed_noise_cv: float = 0.15
    #: 0.25 m/s over 3 s: RoNIN on IPIN phones handled while standing (the trials' calibration
    #: routine) outputs 0.33 m/s mean speed, 0.19 m/s net drift; a phone held still, 0.002 m/s.
    #: A walker waiting at a kerb handles the phone more gently than that routine.
    phantom_mps: float = 0.25


@dataclass
class InertialErrors:
    """Realised error processes of one session, at the velocity's output times.

    Attributes
    ----------
    t
        Times (s).
    heading_deg
        Heading error (clockwise-positive degrees): bias + drift + random walk + noise + jumps.
    scale
        Speed-scale factor (per-walk scale x slow wander x step-to-step noise).
    phantom
        ``(n, 2)`` spurious velocity (m/s) added while standing.
    events
        JSON-ready summary for ``meta.json``: ``heading_bias_deg``, ``heading_drift_deg_per_min``,
        ``heading_jumps`` (``t_s``, ``deg``, ``cause``), ``speed_scale``, ``phantom_m``.
    """

    t: np.ndarray
    heading_deg: np.ndarray
    scale: np.ndarray
    phantom: np.ndarray
    events: dict = field(default_factory=dict)


def _jumps(walk: Walk, duration_s: float, model: VelocityErrorModel, rng: np.random.Generator) -> list[dict]:
    """Heading offsets: a Poisson process over the walk plus one at some stops (time order)."""
    out = []
    n = rng.poisson(model.heading_jump_rate_per_min * duration_s / 60.0)
    for t in rng.uniform(0.0, duration_s, n):
        out.append({"t_s": float(t), "cause": "handling"})
    for stop in walk.stops:
        if rng.random() < model.stop_jump_prob:
            out.append({"t_s": stop.t_s + float(rng.uniform(0.0, stop.wait_s)), "cause": "stop"})
    for jump in out:
        jump["deg"] = float(rng.choice([-1.0, 1.0]) * rng.uniform(*model.heading_jump_deg))
    return sorted(out, key=lambda j: j["t_s"])


def inertial_errors(
    walk: Walk, model: VelocityErrorModel, rng: np.random.Generator, event_rng: np.random.Generator
) -> InertialErrors:
    """Draw the heading, scale and phantom-motion processes of one session.

    ``rng`` draws the nominal components (in the order the nominal simulator always drew them, so
    nominal sessions do not change); ``event_rng`` the phone-profile ones.
    """
    dt_walk = walk.t[1] - walk.t[0]
    stride = max(1, int(round(1.0 / (model.rate_hz * dt_walk))))
    t = walk.t[::stride]
    n = len(t)
    step = stride * dt_walk
    bias = model.heading_bias_deg * rng.standard_normal()
    drift = model.heading_drift_deg_per_min * rng.standard_normal()
    walk_deg = model.heading_walk_deg_per_sqrt_min * np.cumsum(rng.standard_normal(n)) * np.sqrt(step / 60.0)
    heading = bias + drift * t / 60.0 + walk_deg
    per_walk = model.scale_sd * rng.standard_normal()
    scale = 1 + per_walk + model.scale_wander_sd * ou(n, step, 60.0, rng)
    jumps = _jumps(walk, float(t[-1]), model, event_rng)
    for jump in jumps:
        heading = heading + jump["deg"] * (t >= jump["t_s"])
    if model.heading_noise_deg > 0:
        heading = heading + model.heading_noise_deg * ou(n, step, model.heading_noise_tau_s, event_rng)
    if model.speed_noise_cv > 0:
        scale = scale * np.maximum(
            0.0, 1 + model.speed_noise_cv * ou(n, step, model.speed_noise_tau_s, event_rng)
        )
    phantom = np.zeros((n, 2))
    standing = walk.standing(t)
    if model.phantom_mps > 0 and standing.any():
        axis_sd = model.phantom_mps / np.sqrt(2.0)
        phantom = axis_sd * np.column_stack(
            [ou(n, step, model.phantom_tau_s, event_rng), ou(n, step, model.phantom_tau_s, event_rng)]
        )
        phantom *= standing[:, None]
    phantom_m = float(np.hypot(*(phantom.sum(axis=0) * step))) if walk.stops else 0.0
    events = {
        "heading_bias_deg": round(float(bias), 2),
        "heading_drift_deg_per_min": round(float(drift), 3),
        "heading_jumps": [
            {k: round(v, 2) if isinstance(v, float) else v for k, v in j.items()} for j in jumps
        ],
        "speed_scale": round(float(1 + per_walk), 4),
        "phantom_m": round(phantom_m, 2),
    }
    return InertialErrors(t, heading, scale, phantom, events)


def _window_mean(values: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over ``n`` samples (edges shrink the window)."""
    kernel = np.ones(n)
    num = np.apply_along_axis(lambda c: np.convolve(c, kernel, mode="same"), 0, values)
    den = np.convolve(np.ones(len(values)), kernel, mode="same")
    return num / den[:, None]


def simulate_velocity(
    walk: Walk, model: VelocityErrorModel, errors: InertialErrors, rng: np.random.Generator
) -> pd.DataFrame:
    """RoNIN-like world-frame velocity ``t, ve, vn`` along a walk (see :class:`VelocityErrorModel`).

    Parameters
    ----------
    walk
        The true motion.
    model
        Rate, window and noise.
    errors
        Heading, scale and phantom processes (:func:`inertial_errors`).
    rng
        Generator of the additive noise (the stream that drew the nominal errors).
    """
    dt = walk.t[1] - walk.t[0]
    v_true = np.gradient(walk.xy, dt, axis=0)
    v_smooth = _window_mean(v_true, max(1, int(round(model.window_s / dt))))
    stride = max(1, int(round(1.0 / (model.rate_hz * dt))))
    v = v_smooth[::stride]
    n = len(errors.t)
    step = stride * dt
    heading = np.radians(errors.heading_deg)
    c, s = np.cos(heading), np.sin(heading)
    # heading error is clockwise-positive (a compass bearing error): rotate (e, n) by -heading
    ve = errors.scale * (c * v[:, 0] + s * v[:, 1]) + errors.phantom[:, 0]
    vn = errors.scale * (-s * v[:, 0] + c * v[:, 1]) + errors.phantom[:, 1]
    ve += model.noise_mps * ou(n, step, model.noise_tau_s, rng)
    vn += model.noise_mps * ou(n, step, model.noise_tau_s, rng)
    return pd.DataFrame({"t": np.round(errors.t, 3), "ve": ve, "vn": vn})


@dataclass(frozen=True)
class ImuModel:
    """A hand-held phone's IMU (noise and bias magnitudes of consumer MEMS, e.g. Bosch BMI160)."""

    rate_hz: float = 100.0
    #: Gait acceleration amplitudes (m/s^2): vertical bounce, fore-aft surge, lateral sway.
    bounce: float = 2.0
    surge: float = 1.0
    sway: float = 0.5
    #: Phone pitch (deg; screen tilted up toward the face) and hand sway in yaw (deg).
    pitch_deg: float = 35.0
    hand_yaw_deg: float = 3.0
    accel_noise: float = 0.05
    accel_bias: float = 0.05
    gyro_noise: float = 0.01
    gyro_bias: float = 0.003


def simulate_imu(
    walk: Walk, model: ImuModel, errors: InertialErrors, rng: np.random.Generator
) -> pd.DataFrame:
    """Phone IMU ``t, ax..gz, qx..qw`` at ``model.rate_hz`` along a walk.

    The phone points along the walking direction (device +y forward, screen tilted up by
    ``pitch_deg``), swaying a little in the hand. ``q`` is the device-to-ENU quaternion whose yaw
    carries the session's heading error (``errors.heading_deg``, interpolated).
    """
    dt_walk = walk.t[1] - walk.t[0]
    stride = max(1, int(round(1.0 / (model.rate_hz * dt_walk))))
    t = walk.t[::stride]
    dt = stride * dt_walk
    xy = walk.xy[::stride]
    n = len(t)
    v = _window_mean(np.gradient(xy, dt, axis=0), max(1, int(round(0.5 / dt))))
    speed = np.hypot(*v.T)
    heading = np.unwrap(np.arctan2(v[:, 0], v[:, 1]))  # clockwise from north
    heading = _window_mean(heading[:, None], max(1, int(round(0.5 / dt))))[:, 0]
    phase = 2 * np.pi * walk.cadence_hz * t
    moving = np.clip(speed / max(walk.speed_mps, 1e-6), 0, 1)
    fwd = np.column_stack([np.sin(heading), np.cos(heading)])
    right = np.column_stack([fwd[:, 1], -fwd[:, 0]])
    a_h = np.gradient(v, dt, axis=0)
    a_world = np.zeros((n, 3))
    a_world[:, :2] = (
        a_h
        + (fwd * (model.surge * np.sin(phase))[:, None] + right * (model.sway * np.sin(phase / 2))[:, None])
        * moving[:, None]
    )
    a_world[:, 2] = model.bounce * np.cos(phase) * moving
    yaw_hand = np.radians(model.hand_yaw_deg) * np.sin(phase / 2 + 0.3)
    # device-to-ENU: yaw about Up (heading is clockwise, ENU yaw counter-clockwise), then pitch about x
    true_rot = Rotation.from_euler(
        "ZX", np.column_stack([-(heading + yaw_hand), np.full(n, np.radians(model.pitch_deg))])
    )
    specific = a_world + [0.0, 0.0, GRAVITY]
    acc = true_rot.inv().apply(specific)
    acc += model.accel_bias * rng.standard_normal(3) + model.accel_noise * rng.standard_normal((n, 3))
    rel = (true_rot[:-1].inv() * true_rot[1:]).as_rotvec() / dt
    gyro = np.vstack([rel, rel[-1:]])
    gyro += model.gyro_bias * rng.standard_normal(3) + model.gyro_noise * rng.standard_normal((n, 3))
    yaw_err = np.radians(np.interp(t, errors.t, errors.heading_deg))
    reported = Rotation.from_euler("Z", -yaw_err[:, None]) * true_rot
    q = reported.as_quat()  # x, y, z, w
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return pd.DataFrame(
        {
            "t": np.round(t, 4),
            "ax": acc[:, 0],
            "ay": acc[:, 1],
            "az": acc[:, 2],
            "gx": gyro[:, 0],
            "gy": gyro[:, 1],
            "gz": gyro[:, 2],
            "qx": q[:, 0],
            "qy": q[:, 1],
            "qz": q[:, 2],
            "qw": q[:, 3],
        }
    )
