"""Inference: world-frame velocity from a phone's IMU with a trained RoNIN model.

:func:`infer_windows` runs windows of any number of sessions (from
:class:`~curbside.localize.ronin.stream.RoninStream`) through the model in fixed-shape batches;
:func:`ronin_velocity` is the batch entry point, one whole table through the same stream.

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
from curbside.localize.ronin.model import RoninConfig, RoninResNet
from curbside.localize.ronin.stream import RoninStream, RoninStreamConfig

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


def infer_windows(model: RoninResNet, windows: np.ndarray, batch_size: int | None = None) -> np.ndarray:
    """Velocities of windows from any number of sessions, each independent of the others.

    The windows go through the model in batches of one fixed shape, the last one zero-padded. On
    CPU, torch picks its convolution kernels by batch size (batches of 1 to 3 windows give results
    that differ from larger ones at the 1e-7 level), but for a fixed shape a window's velocity is
    bit-identical whatever else is in the batch and wherever it sits (tested in
    ``tests/test_ronin_stream.py``). So a live service may batch windows of many sessions together
    and still reproduce the batch command exactly.

    Parameters
    ----------
    model
        A loaded model (:func:`load_model`), in evaluation mode.
    windows
        ``(K, 6, window)`` float32, e.g. from :meth:`RoninStream.take_windows`.
    batch_size
        The fixed batch shape (default :attr:`RoninStreamConfig.batch_size`).

    Returns
    -------
    numpy.ndarray
        ``(K, 2)`` float64 velocity (m/s, world-frame east and north).
    """
    batch_size = batch_size or RoninStreamConfig().batch_size
    cfg = model.config
    if windows.ndim != 3 or windows.shape[1:] != (cfg.in_channels, cfg.window):
        raise ValueError(f"windows must be (K, {cfg.in_channels}, {cfg.window}), not {windows.shape}")
    device = next(model.parameters()).device
    out = np.empty((len(windows), cfg.out_dim), dtype=np.float32)
    batch = np.zeros((batch_size, cfg.in_channels, cfg.window), dtype=np.float32)
    with torch.inference_mode():
        for lo in range(0, len(windows), batch_size):
            n = min(batch_size, len(windows) - lo)
            batch[:n] = windows[lo : lo + n]
            batch[n:] = 0.0
            out[lo : lo + n] = model(torch.from_numpy(batch).to(device)).cpu().numpy()[:n]
    return out.astype(np.float64)


def ronin_velocity(imu_df: pd.DataFrame, model: RoninResNet | str | Path | None = None,
                   config: RoninStreamConfig | None = None, source: str = "imu.csv") -> pd.DataFrame:
    """World-frame horizontal walking velocity from an ``imu.csv`` table.

    The batch entry point of the streaming path: the whole table is pushed through one
    :class:`~curbside.localize.ronin.stream.RoninStream` and its windows through
    :func:`infer_windows`, so a session streamed in any chunks gives exactly these rows. The IMU is
    rotated into the gravity-aligned world frame of its quaternion (or of the integrated
    gyroscope), resampled to the model's rate (200 Hz) and cut into windows of one second every
    ``config.stride`` samples; each window gives the mean velocity over that second, stamped at the
    window's centre. Gaps longer than ``config.imu.max_gap_s`` produce no rows.

    Parameters
    ----------
    imu_df
        ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` (SPEC ``imu.csv``).
    model
        A loaded model, a weights path, or ``None`` for the bundled compact model.
    config
        Stream parameters (default :class:`RoninStreamConfig`, whose window and rate must be the
        model's).
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
        Bad IMU input (see :mod:`curbside.localize.imu`), a model trained for another window or
        rate, or no stretch as long as one window.
    """
    if not isinstance(model, RoninResNet):
        model = load_model(model)
    config = config or RoninStreamConfig()
    check_compatible(model, config)
    stream = RoninStream(config, source)
    stream.push(imu_df)
    stream.finish()
    t_mid, windows = stream.take_windows()
    if not len(t_mid):
        raise CurbsideInputError(source, f"no stretch of IMU data without gaps lasts one "
                                         f"{config.window / config.rate_hz:g} s window")
    velocity = infer_windows(model, windows, config.batch_size)
    return pd.DataFrame({"t": t_mid, "ve": velocity[:, 0], "vn": velocity[:, 1]})


def check_compatible(model: RoninResNet, config: RoninStreamConfig) -> None:
    """Raise :class:`CurbsideInputError` unless the stream feeds the model its window and rate."""
    if (model.config.window, model.config.rate_hz) != (config.window, config.rate_hz):
        raise CurbsideInputError(
            "RoNIN model", f"trained on {model.config.window}-sample windows at {model.config.rate_hz:g} Hz, "
                           f"the stream cuts {config.window} at {config.rate_hz:g} Hz"
        )
