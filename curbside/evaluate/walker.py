"""The simulated walker: pace, footsteps, wander off the straight legs, and stops at the kerb.

The walker follows a route's waypoints at a constant speed per leg. Their true path wanders a little
off the straight legs (a lateral Ornstein-Uhlenbeck offset that fades out within 3 m of each
waypoint), so the paper's straight-line ground truth is as approximate here as it was there.

With a stop probability above zero (the ``phone`` profile) the walker may stop at the kerb before a
crossing -- waiting for the light at a crosswalk, for a gap in the traffic before a jaywalk. The walk
is first laid out on a *walking clock* that excludes stops; each stop then inserts its wait at the
kerb waypoint. The waypoint is tapped twice, on arrival and on departure, so the ground truth (taps
joined by straight lines at constant speed) stays exact: it holds still between the two taps.
Footsteps are placed on the walking clock, so there are none while standing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from curbside.evaluate import routes as routes_mod


@dataclass(frozen=True)
class WalkerModel:
    """How the simulated walker moves (the ``nominal`` profile; values from gait literature).

    Sources: docs/evaluate.md, "Simulation parameters and their sources".
    """

    #: Mean walking speed (m/s) and its spread between walks; legs vary by ``leg_speed_cv``.
    speed_mps: float = 1.35
    speed_sd_mps: float = 0.08
    leg_speed_cv: float = 0.05
    #: Step frequency (Hz) and its spread between walks.
    cadence_hz: float = 1.85
    cadence_sd_hz: float = 0.08
    #: Lateral wander off the straight legs: 1-sigma (m) and time constant (s).
    wander_m: float = 0.3
    wander_tau_s: float = 4.0
    #: Probability of stopping at the kerb before a crosswalk crossing, and the wait (uniform, s).
    crosswalk_stop_prob: float = 0.0
    crosswalk_wait_s: tuple[float, float] = (10.0, 40.0)
    #: Probability of stopping before a crossing off the crosswalks, and the wait (uniform, s).
    jaywalk_stop_prob: float = 0.0
    jaywalk_wait_s: tuple[float, float] = (2.0, 8.0)


@dataclass(frozen=True)
class PhoneWalkerModel(WalkerModel):
    """The ``phone`` profile's walker: the nominal one who also waits at crossings.

    Half the walkers wait at a crosswalk (Li 2013, Transportation Research B 51: the distribution of
    pedestrians' waiting time at signalised crossings is U-shaped -- many cross at once, many wait
    for the whole red phase), 10-40 s (Zafri et al. 2019, Infrastructures 4(3):39: pedestrians do
    not want to wait more than 20-30 s; downtown SF signal cycles are 60-90 s). Before a jaywalk
    half of them wait 2-8 s for a gap in the traffic (gap acceptance; an assumption).
    """

    crosswalk_stop_prob: float = 0.5
    jaywalk_stop_prob: float = 0.5


@dataclass
class Stop:
    """One wait at a kerb: the waypoint index, arrival time, wait and the kind of crossing after it."""

    waypoint: int
    t_s: float
    wait_s: float
    kind: str


@dataclass
class Walk:
    """The true motion of one simulated walk, sampled at a fixed rate.

    Attributes
    ----------
    t, xy
        Sample times (s) and true positions (m, local frame).
    waypoint_t, waypoint_xy
        The ground-truth taps: one per route waypoint, two (arrival, departure) where the walker
        stopped.
    step_t
        True footstep times (none while standing).
    cadence_hz, speed_mps
        The walk's cadence and mean speed.
    stops
        The waits, in time order.
    """

    t: np.ndarray
    xy: np.ndarray
    waypoint_t: np.ndarray
    waypoint_xy: np.ndarray
    step_t: np.ndarray
    cadence_hz: float
    speed_mps: float
    stops: list[Stop] = field(default_factory=list)

    def standing(self, t: np.ndarray) -> np.ndarray:
        """Boolean mask of the times ``t`` at which the walker stands at a kerb."""
        t = np.asarray(t, float)
        out = np.zeros(len(t), bool)
        for stop in self.stops:
            out |= (t >= stop.t_s) & (t < stop.t_s + stop.wait_s)
        return out


def ou(n: int, dt: float, tau: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance Ornstein-Uhlenbeck samples (exact AR(1) discretisation) via a linear filter."""
    from scipy.signal import lfilter

    phi = np.exp(-dt / tau)
    noise = rng.standard_normal(n) * np.sqrt(1 - phi**2)
    noise[0] = rng.standard_normal()
    return lfilter([1.0], [1.0, -phi], noise)


def draw_stops(
    kinds: np.ndarray, walker: WalkerModel, rng: np.random.Generator
) -> list[tuple[int, float, str]]:
    """``(waypoint index, wait s, kind)`` of the stops before each crossing of a route.

    A stop happens at the waypoint where a run of ``crossing`` legs, or a ``jaywalk`` leg, begins.
    """
    out = []
    for i in range(1, len(kinds)):
        kind = str(kinds[i])
        if kind == "crossing" and kinds[i - 1] != "crossing":
            prob, span = walker.crosswalk_stop_prob, walker.crosswalk_wait_s
        elif kind == "jaywalk":
            prob, span = walker.jaywalk_stop_prob, walker.jaywalk_wait_s
        else:
            continue
        if prob > 0 and rng.random() < prob:
            out.append((i, float(rng.uniform(*span)), kind))
    return out


def simulate_walk(
    route: routes_mod.Route,
    walker: WalkerModel,
    rng: np.random.Generator,
    rate_hz: float = 100.0,
    stop_rng: np.random.Generator | None = None,
) -> Walk:
    """Walk ``route``; return the true path at ``rate_hz`` (see the module docstring).

    Parameters
    ----------
    route
        Waypoints in the local frame.
    walker
        Speed, cadence, wander and stops.
    rng
        Seeded generator of the pace, wander and footsteps.
    rate_hz
        Sampling rate of the returned path.
    stop_rng
        Seeded generator of the stops (a separate stream, so a walker who never stops draws
        nothing from it); default: no stops.
    """
    wp = route.xy
    legs = np.hypot(*np.diff(wp, axis=0).T)
    speed = max(0.6, rng.normal(walker.speed_mps, walker.speed_sd_mps))
    leg_speed = speed * np.clip(1 + walker.leg_speed_cv * rng.standard_normal(len(legs)), 0.7, 1.3)
    wt = np.concatenate([[0.0], np.cumsum(legs / leg_speed)])
    dt = 1.0 / rate_hz
    tau = np.arange(0.0, wt[-1] + dt / 2, dt)  # the walking clock
    x = np.interp(tau, wt, wp[:, 0])
    y = np.interp(tau, wt, wp[:, 1])
    leg = np.clip(np.searchsorted(wt, tau, side="right") - 1, 0, len(legs) - 1)
    direction = np.diff(wp, axis=0) / np.maximum(legs, 1e-9)[:, None]
    normal = np.column_stack([-direction[:, 1], direction[:, 0]])[leg]
    # the wander fades out within 3 m of each waypoint: the walker taps at the waypoint itself
    dist_to_wp = np.minimum(tau - wt[leg], wt[leg + 1] - tau) * leg_speed[leg]
    fade = np.clip(dist_to_wp / 3.0, 0, 1)
    offset = walker.wander_m * ou(len(tau), dt, walker.wander_tau_s, rng) * fade
    xy = np.column_stack([x, y]) + normal * offset[:, None]
    cadence = max(1.4, rng.normal(walker.cadence_hz, walker.cadence_sd_hz))
    n_steps = int(wt[-1] * cadence)
    step_tau = (np.arange(1, n_steps + 1) / cadence) + rng.normal(0, 0.01, n_steps)
    step_tau = np.sort(np.clip(step_tau, dt, tau[-1]))
    drawn = draw_stops(route.kinds, walker, stop_rng) if stop_rng is not None else []
    if not drawn:
        return Walk(tau, xy, wt, wp, step_tau, cadence, speed)
    return _insert_stops(tau, xy, wt, wp, step_tau, cadence, speed, drawn, dt)


def _insert_stops(
    tau: np.ndarray,
    xy: np.ndarray,
    wt: np.ndarray,
    wp: np.ndarray,
    step_tau: np.ndarray,
    cadence: float,
    speed: float,
    drawn: list[tuple[int, float, str]],
    dt: float,
) -> Walk:
    """Stretch a walk laid out on the walking clock by the waits at its kerbs (exact taps)."""
    n_wait = [max(1, int(round(wait / dt))) for _, wait, _ in drawn]
    waits = np.asarray(n_wait) * dt
    stop_tau = wt[[i for i, _, _ in drawn]]
    # samples up to and including the kerb, then the wait at the waypoint itself, then the rest
    cut = np.searchsorted(tau, stop_tau, side="right")
    pieces, start = [], 0
    for k, (i, _, _) in enumerate(drawn):
        pieces.append(xy[start : cut[k]])
        pieces.append(np.repeat(wp[i][None, :], n_wait[k], axis=0))
        start = cut[k]
    pieces.append(xy[start:])
    xy_out = np.vstack(pieces)
    t_out = np.arange(len(xy_out)) * dt

    def shift(clock: np.ndarray, inclusive: bool) -> np.ndarray:
        side = "right" if inclusive else "left"
        return clock + np.concatenate([[0.0], np.cumsum(waits)])[np.searchsorted(stop_tau, clock, side=side)]

    arrive_t = shift(wt, inclusive=False)
    stopped = {i: k for k, (i, _, _) in enumerate(drawn)}
    taps_t, taps_xy = [], []
    for i in range(len(wt)):
        taps_t.append(arrive_t[i])
        taps_xy.append(wp[i])
        if i in stopped:
            taps_t.append(arrive_t[i] + waits[stopped[i]])
            taps_xy.append(wp[i])
    stops = [Stop(i, float(arrive_t[i]), float(waits[k]), kind) for k, (i, _, kind) in enumerate(drawn)]
    return Walk(
        t_out,
        xy_out,
        np.asarray(taps_t),
        np.asarray(taps_xy),
        shift(step_tau, inclusive=True),
        cadence,
        speed,
        stops,
    )
