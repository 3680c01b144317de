"""Does a RoNIN model know this recording? Its yaw-equivariance spread, measured without ground truth.

RoNIN is trained on windows turned by a random yaw (:func:`curbside.localize.ronin.train.rotate_yaw`),
so on data like its training data its velocity turns with its input: turn a window's horizontal axes by
an angle, turn the answer back, and it is the same. On data it does not know (another phone, carrier or
place) the learnt equivariance breaks down, and the answers for the same window under different turns
disagree. The spread of those answers is a label-free measure of how far out of its depth the model is.

Measured on real recordings (``benchmarks/ronin_yaw_spread.py``; docs/ronin.md, "Does the model know
this recording?"): the median spread over a recording's walking windows is 0.043-0.094 m/s on ground
the model knows (the bundled model on the 43 IPIN trials, held-out or not, and both models on 12
held-out MS-indoor paths) and 0.134-0.237 m/s for the model trained on MS-indoor only, on the IPIN
venue it never saw. Across recordings the spread follows the model's velocity error (correlation 0.81).
Over the first 30 s of walking alone the two groups touch (0.153 against 0.137), so the verdict is the
whole recording's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch

from curbside.localize.ronin.infer import imu_windows, infer_windows
from curbside.localize.ronin.model import RoninResNet
from curbside.localize.ronin.stream import RoninStreamConfig
from curbside.localize.ronin.train import rotate_yaw

#: Evenly spaced yaw turns each window is run under.
YAW_TURNS = 6
#: Every how many windows one is tested (the windows overlap: every 5th is one each half second at the
#: default stride).
TEST_EVERY = 5
#: The spread (m/s) above which a model reads a recording as unfamiliar: midway between the highest median
#: of a known recording (0.094) and the lowest of an unknown one (0.134).
UNFAMILIAR_SPREAD_MPS = 0.115
#: The early spread is the median over this many seconds from the first walking window (a record, not
#: the verdict).
EARLY_S = 30.0
#: A window counts as walking when the mean of its turned answers is at least this fast (m/s).
WALKING_MPS = 0.5
#: Fewer walking windows than this give no verdict (10 s of walking at the default test rate).
MIN_WALKING_WINDOWS = 20


def turned_velocities(model: RoninResNet, windows: np.ndarray, turns: int = YAW_TURNS,
                      batch_size: int | None = None) -> np.ndarray:
    """The model's velocity of each window turned by each of ``turns`` evenly spaced yaws, turned back.

    Parameters
    ----------
    model
        A loaded model in evaluation mode.
    windows
        ``(K, 6, window)`` float32 world-frame windows (gyroscope then accelerometer, x east-like).
    turns
        Number of evenly spaced turns (0, 360/turns, ... degrees); at least 2.
    batch_size
        As for :func:`~curbside.localize.ronin.infer.infer_windows`.

    Returns
    -------
    numpy.ndarray
        ``(turns, K, 2)`` east and north velocities (m/s) in the windows' own frame: for a model that
        is exactly yaw-equivariant on these windows, the same for every turn.
    """
    if turns < 2:
        raise ValueError(f"turns must be at least 2, got {turns}")
    x = torch.from_numpy(np.ascontiguousarray(windows, dtype=np.float32))
    no_targets = torch.zeros((len(x), 2))
    answers = []
    for angle_rad in 2 * np.pi * np.arange(turns) / turns:
        turned, _ = rotate_yaw(x, no_targets, torch.full((len(x),), float(angle_rad)))
        ve, vn = infer_windows(model, turned.numpy(), batch_size).T
        cos, sin = np.cos(angle_rad), np.sin(angle_rad)
        answers.append(np.column_stack([cos * ve + sin * vn, -sin * ve + cos * vn]))
    return np.stack(answers)


def yaw_spread_mps(answers: np.ndarray) -> np.ndarray:
    """Per window, the RMS distance (m/s) of :func:`turned_velocities`' answers from their mean."""
    return np.sqrt(np.mean(np.sum((answers - answers.mean(axis=0)) ** 2, axis=-1), axis=0))


@dataclass(frozen=True)
class Familiarity:
    """A recording's yaw-equivariance spread under one model, over the windows it reads as walking.

    Attributes
    ----------
    early_spread_mps
        Median spread over the walking windows of the first :data:`EARLY_S` seconds of walking
        (NaN: none).
    spread_mps
        Median spread over every walking window (NaN: none).
    windows
        Walking windows tested.
    familiar
        ``spread_mps`` at most :data:`UNFAMILIAR_SPREAD_MPS`; ``None`` with fewer than
        :data:`MIN_WALKING_WINDOWS` walking windows.
    """

    early_spread_mps: float
    spread_mps: float
    windows: int
    familiar: bool | None

    def to_dict(self) -> dict:
        """The record written to ``run.json`` and the ``ronin-eval`` report (NaN as ``None``)."""
        return {"early_spread_mps": _or_none(self.early_spread_mps), "spread_mps": _or_none(self.spread_mps),
                "walking_windows": self.windows, "familiar": self.familiar,
                "unfamiliar_above_mps": UNFAMILIAR_SPREAD_MPS, "early_s": EARLY_S}

    def describe(self) -> str:
        """One line for a log or a summary."""
        if self.familiar is None:
            return (f"cannot tell whether the RoNIN model knows this recording: {self.windows} of its "
                    f"windows read walking, {MIN_WALKING_WINDOWS} needed")
        verdict = "knows" if self.familiar else "does not know"
        return (f"the RoNIN model {verdict} this recording: yaw-equivariance spread {self.spread_mps:.3f} "
                f"m/s while walking (unfamiliar above {UNFAMILIAR_SPREAD_MPS:g})")


def _or_none(value: float) -> float | None:
    return None if np.isnan(value) else value


def familiarity(model: RoninResNet, t_s: np.ndarray, windows: np.ndarray,
                every: int = TEST_EVERY) -> Familiarity:
    """The yaw-equivariance verdict on every ``every``-th window of a recording.

    Windows whose mean answer is under :data:`WALKING_MPS` are left out: a model reads a standing
    walker as still under every turn, whether it knows the phone or not.

    Parameters
    ----------
    model
        A loaded model.
    t_s
        ``(K,)`` window-centre times (s), increasing.
    windows
        ``(K, 6, window)`` windows, as :func:`~curbside.localize.ronin.infer.infer_windows` takes them.
    every
        Test one window in ``every`` (the cost is ``YAW_TURNS / every`` times the model's inference).
    """
    t_s, windows = np.asarray(t_s)[::every], windows[::every]
    answers = turned_velocities(model, windows)
    walking = np.linalg.norm(answers.mean(axis=0), axis=1) >= WALKING_MPS
    t_s, spread = t_s[walking], yaw_spread_mps(answers[:, walking])
    if len(t_s) < MIN_WALKING_WINDOWS:
        nan = float("nan")
        return Familiarity(nan, nan, len(t_s), None)
    early_spread = float(np.median(spread[t_s <= t_s[0] + EARLY_S]))
    whole_spread = float(np.median(spread))
    return Familiarity(early_spread, whole_spread, len(t_s), whole_spread <= UNFAMILIAR_SPREAD_MPS)


def session_familiarity(model: RoninResNet, imu_df: pd.DataFrame, config: RoninStreamConfig | None = None,
                        source: str = "imu.csv") -> Familiarity:
    """:func:`familiarity` on the windows :func:`~curbside.localize.ronin.infer.ronin_velocity` runs on.

    Raises
    ------
    CurbsideInputError
        As :func:`~curbside.localize.ronin.infer.imu_windows`.
    """
    t_mid, windows = imu_windows(imu_df, config or RoninStreamConfig(), source)
    return familiarity(model, t_mid, windows)
