"""Inference: world-frame velocity from a phone's IMU with a trained RoNIN model.

The shipped model lives in ``weights/ronin_compact.pt`` (a plain ``state_dict``, loaded with
``torch.load(..., weights_only=True)``) with its :class:`~curbside.localize.ronin.model.RoninConfig`
in ``ronin_compact.json`` beside it.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.imu import WorldImu, preprocess
from curbside.localize.ronin.model import RoninConfig, RoninResNet

logger = logging.getLogger(__name__)


def config_path_for(weights: str | Path) -> Path:
    """The JSON config stored beside a weights file (``x.pt`` -> ``x.json``)."""
    return Path(weights).with_suffix(".json")


def load_model(weights: str | Path | None = None) -> RoninResNet:
    """Load a trained model in evaluation mode.

    Parameters
    ----------
    weights
        A ``.pt`` state_dict with its ``.json`` config beside it; default
        ``settings.ronin_default_weights`` (the bundled compact model).

    Returns
    -------
    RoninResNet

    Raises
    ------
    CurbsideInputError
        Missing or unreadable weights or config.
    """
    weights = Path(weights or settings.ronin_default_weights)
    cfg_path = config_path_for(weights)
    for path in (weights, cfg_path):
        if not path.is_file():
            raise CurbsideInputError(path, "no such RoNIN weights/config file")
    try:
        config = RoninConfig.from_dict(json.loads(cfg_path.read_text(encoding="utf-8")))
    except (json.JSONDecodeError, TypeError) as exc:
        raise CurbsideInputError(cfg_path, f"not a RoNIN config ({exc})") from None
    model = RoninResNet(config)
    try:
        state = torch.load(weights, map_location="cpu", weights_only=True)
        model.load_state_dict(state)
    except (RuntimeError, OSError, KeyError) as exc:
        first_line = str(exc).splitlines()[0]
        raise CurbsideInputError(weights, f"not a state_dict for this config ({first_line})") from None
    return model.eval()


def window_starts(n_samples: int, window: int, stride: int) -> np.ndarray:
    """First-sample indices of every full window of ``window`` samples every ``stride`` samples."""
    if n_samples < window:
        return np.zeros(0, dtype=np.int64)
    return np.arange(0, n_samples - window + 1, stride, dtype=np.int64)


def make_windows(features: np.ndarray, starts: np.ndarray, window: int) -> np.ndarray:
    """``(len(starts), C, window)`` views of ``(N, C)`` features (no copy until batched)."""
    view = np.lib.stride_tricks.sliding_window_view(features, window, axis=0)  # (N-window+1, C, window)
    return view[starts]


def predict_windows(model: RoninResNet, windows: np.ndarray, batch_size: int = 4096) -> np.ndarray:
    """Velocities ``(B, 2)`` for windows ``(B, 6, window)``, batched under ``torch.inference_mode``."""
    device = next(model.parameters()).device
    out = np.empty((len(windows), model.config.out_dim), dtype=np.float32)
    with torch.inference_mode():
        for lo in range(0, len(windows), batch_size):
            batch = torch.from_numpy(np.ascontiguousarray(windows[lo : lo + batch_size], dtype=np.float32))
            out[lo : lo + batch_size] = model(batch.to(device)).cpu().numpy()
    return out


def segment_velocity(model: RoninResNet, segment: WorldImu) -> pd.DataFrame:
    """``t,ve,vn`` for one uniform world-frame segment; ``t`` is each window's centre."""
    cfg = model.config
    starts = window_starts(len(segment.t), cfg.window, cfg.stride)
    if len(starts) == 0:
        return pd.DataFrame({"t": [], "ve": [], "vn": []})
    vel = predict_windows(model, make_windows(segment.features, starts, cfg.window))
    t_mid = 0.5 * (segment.t[starts] + segment.t[starts + cfg.window - 1])
    return pd.DataFrame({"t": t_mid, "ve": vel[:, 0].astype(float), "vn": vel[:, 1].astype(float)})


def ronin_velocity(imu_df: pd.DataFrame, model: RoninResNet | str | Path | None = None,
                   source: str = "imu.csv") -> pd.DataFrame:
    """World-frame horizontal walking velocity from an ``imu.csv`` table.

    The IMU is rotated into the gravity-aligned world frame of its quaternion (or of the integrated
    gyroscope), resampled to the model's rate (200 Hz) and cut into windows of one second every
    ``stride`` samples (50 ms); each window gives the mean velocity over that second, stamped at the
    window's centre. Gaps longer than ``settings.imu_max_interp_gap_s`` produce no rows.

    Parameters
    ----------
    imu_df
        ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` (SPEC ``imu.csv``).
    model
        A loaded model, a weights path, or ``None`` for the bundled compact model.
    source
        File name used in messages.

    Returns
    -------
    pandas.DataFrame
        ``t,ve,vn`` in s, m/s east, m/s north (the heading is that of the orientation source, which
        may drift; a game rotation vector's yaw is arbitrary).

    Raises
    ------
    CurbsideInputError
        Bad IMU input (see :mod:`curbside.localize.imu`) or no stretch as long as one window.
    """
    if not isinstance(model, RoninResNet):
        model = load_model(model)
    cfg = model.config
    segments = preprocess(imu_df, rate_hz=cfg.rate_hz, source=source, min_duration_s=cfg.window / cfg.rate_hz)
    parts = [segment_velocity(model, seg) for seg in segments]
    out = pd.concat([p for p in parts if len(p)], ignore_index=True) if any(len(p) for p in parts) else None
    if out is None:
        raise CurbsideInputError(source, f"IMU shorter than one {cfg.window / cfg.rate_hz:g} s window")
    saturated = sum(int(seg.saturated.sum()) for seg in segments)
    if saturated:
        logger.warning("%s: velocities near %d saturated sample(s) are unreliable", source, saturated)
    return out
