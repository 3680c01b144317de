"""How the service feeds a batch to a session: the IMU rate check, and refusals in the client's words.

A session's RoNIN stream decides on its first two seconds of IMU whether it can be tracked
(:class:`~curbside.localize.imu.WorldFrameStream`): a rate under 20 Hz, a gyroscope reading all zeros
or a quaternion no reading of which fits gravity makes it unusable. That decision counts only rows
less than ``max_gap_s`` (0.5 s) apart, so a stream whose rows all come further apart (1 Hz) is never
judged: it would wait for good, and at its end log a warning per row. :class:`ImuRateCheck` judges the
rate on the session's first rows, gaps included, before they reach the session.

Such a verdict is on the phone's stream, not on one batch: the batch that shows it is refused (422)
and the session fails (``status: failed``, every later batch refused), so the client learns from that
one reply that it must open a new session. Every other refusal leaves the session as it was.
"""

from __future__ import annotations

import logging

import numpy as np

from curbside.errors import CurbsideInputError
from curbside.localize.imu import low_rate_problem
from curbside.localize.live import LiveSession
from curbside.localize.live_input import check_imu

logger = logging.getLogger(__name__)

#: Intervals the rate is judged on at least, so that a stray first row cannot decide it.
MIN_RATE_INTERVALS = 10

#: What a refusal that ends a session's usefulness adds to its reason.
FAILED_SUFFIX = ": the session cannot go on (open a new session)"


class ImuRateCheck:
    """The rate of a session's first IMU rows (at least ``decision_s`` of them, gaps included, and
    :data:`MIN_RATE_INTERVALS` intervals): the median interval must be at most ``1 / min_rate_hz``.

    For rows without gaps this is the window and the figure of the RoNIN stream's own start-up
    decision, which it precedes.

    Parameters
    ----------
    min_rate_hz, decision_s
        The RoNIN stream's minimum rate (Hz) and decision span (s), ``ImuConfig``'s.
    """

    def __init__(self, min_rate_hz: float, decision_s: float) -> None:
        self.min_rate_hz = min_rate_hz
        self.decision_s = decision_s
        self.judged = False
        self._times = np.zeros(0)  # the session's IMU row times while the rate is not judged

    def problem(self, t: np.ndarray) -> str | None:
        """What is wrong with the rate once the rows at times ``t`` follow the session's (``None``: nothing,
        or not known yet). Changes nothing; rows out of order are left to the session to refuse."""
        if self.judged or not len(t):
            return None
        times = np.concatenate([self._times, t])
        dt = np.diff(times)
        if not (np.isfinite(times).all() and (dt > 0).all()):
            return None
        enough = np.flatnonzero((times - times[0] >= self.decision_s)[MIN_RATE_INTERVALS:])
        if not len(enough):
            return None
        return low_rate_problem(float(np.median(dt[: enough[0] + MIN_RATE_INTERVALS])), self.min_rate_hz)

    def accept(self, t: np.ndarray) -> None:
        """The session took rows at times ``t`` (after :meth:`problem` found nothing wrong with them)."""
        if self.judged or not len(t):
            return
        times = np.concatenate([self._times, t])
        self.judged = bool(times[-1] - times[0] >= self.decision_s and len(times) > MIN_RATE_INTERVALS)
        self._times = np.zeros(0) if self.judged else times


def push_batch(
    live: LiveSession,
    rate: ImuRateCheck | None,
    imu: np.ndarray | None,
    gnss: np.ndarray | None,
    columns: tuple[str, ...],
) -> list[str]:
    """Feed a batch to ``live`` (:meth:`~curbside.localize.live.LiveSession.push`) after ``rate``'s check.

    Returns
    -------
    list of str
        The batch's warnings.

    Raises
    ------
    CurbsideInputError
        The batch refused, named as the client wrote it (``imu``, not the session's log name); a reason
        that makes the session unusable says so (:data:`FAILED_SUFFIX`).
    """
    failed_before = live.failed
    try:
        if rate is not None and imu is not None and len(imu) and not live.failed:
            problem = rate.problem(imu[:, 0])
            if problem is not None:
                check_imu(imu, live.last_imu_t, live.limits)  # rows refused as such leave the session be
                live.failed = problem
                raise CurbsideInputError("imu", problem)
        warnings = live.push(imu, gnss, columns)
    except CurbsideInputError as exc:
        source = exc.source.removeprefix(f"{live.name} ")  # the RoNIN stream's rows are the client's imu
        if live.failed and not failed_before:
            logger.warning("%s: %s: the session cannot go on", live.name, live.failed)
            raise CurbsideInputError(source, f"{exc.problem}{FAILED_SUFFIX}") from None
        raise CurbsideInputError(source, exc.problem) from None
    if rate is not None and imu is not None:
        rate.accept(imu[:, 0])
    return warnings
