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
from dataclasses import fields
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from tqdm.auto import tqdm

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.paths import check_ronin_weights_path
from curbside.localize.ronin.model import RoninConfig, RoninResNet
from curbside.localize.ronin.stream import RoninStream, RoninStreamConfig

logger = logging.getLogger(__name__)


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
        Missing or unreadable weights or config, a file that is not a weights file, or weights
        that do not fit the config.
    """
    weights, cfg_path = check_ronin_weights_path(weights or settings.ronin_default_weights)
    model = RoninResNet(_read_config(cfg_path))
    state = _read_state_dict(weights)
    problem = _state_dict_mismatch(model.state_dict(), state)
    if problem:
        raise CurbsideInputError(weights, f"not a state_dict for the config in {cfg_path.name} ({problem})")
    not_finite = [key for key, value in state.items() if not torch.isfinite(value).all()]
    if not_finite:
        raise CurbsideInputError(weights, f"NaN or infinite values in {_names(not_finite)} (weights of a "
                                          "diverged training run?)")
    model.load_state_dict(state)
    model.source = str(weights)  # for messages about the model
    return model.eval()


def _read_config(path: Path) -> RoninConfig:
    """The :class:`RoninConfig` a JSON file holds."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read the RoNIN config ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise CurbsideInputError(path, "not a RoNIN config (not UTF-8 text)") from None
    except json.JSONDecodeError as exc:
        problem = f"not a RoNIN config (not JSON: {exc.msg} at line {exc.lineno})"
        raise CurbsideInputError(path, problem) from None
    if not isinstance(data, dict):
        raise CurbsideInputError(path, "not a RoNIN config (not a JSON object)")
    # A missing key would silently take its default: an uncalibrated scale, another network size.
    missing = [f.name for f in fields(RoninConfig) if f.name != "extra" and f.name not in data]
    if missing:
        raise CurbsideInputError(path, f"not a RoNIN config (missing {_names(missing)})")
    try:
        config = RoninConfig.from_dict(data)
        RoninResNet(config)
        numbers = np.array([*config.feature_mean, *config.feature_std, config.output_scale], dtype=float)
    except (TypeError, ValueError, KeyError, IndexError, RuntimeError) as exc:
        first_line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise CurbsideInputError(path, f"not a RoNIN config ({first_line})") from None
    if not np.isfinite(numbers).all():
        raise CurbsideInputError(path, "NaN or infinite feature_mean, feature_std or output_scale (the "
                                       "config of a diverged training run?)")
    return config


def _read_state_dict(path: Path) -> dict[str, torch.Tensor]:
    """The tensors a weights file holds, by name."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read the RoNIN weights ({exc.strerror or exc})") from None
    # torch.load raises anything from UnpicklingError to RuntimeError or EOFError (with many-line
    # messages) for a file in another format; none of them says more than this does.
    except Exception:  # noqa: BLE001
        raise CurbsideInputError(
            path, "not a curbside RoNIN weights file (torch cannot read it as saved tensors)"
        ) from None
    if not isinstance(state, dict) or not all(
        isinstance(key, str) and isinstance(value, torch.Tensor) for key, value in state.items()
    ):
        raise CurbsideInputError(
            path, f"not a curbside RoNIN weights file (holds a {type(state).__name__}, not named tensors)"
        )
    return state


def _names(keys: list[str], limit: int = 3) -> str:
    """The first ``limit`` of ``keys``, and how many more."""
    more = f" and {len(keys) - limit} more" if len(keys) > limit else ""
    return ", ".join(keys[:limit]) + more


def _state_dict_mismatch(expected: dict[str, torch.Tensor], state: dict[str, torch.Tensor]) -> str:
    """What keeps ``state`` from loading into a model whose state_dict is ``expected``, in words
    (empty when nothing does)."""
    missing = [key for key in expected if key not in state]
    unexpected = [key for key in state if key not in expected]
    reshaped = [
        f"{key} is {tuple(state[key].shape)}, not {tuple(value.shape)}"
        for key, value in expected.items()
        if key in state and state[key].shape != value.shape
    ]
    problems = []
    if missing:
        problems.append(f"missing {len(missing)} tensor(s): {_names(missing)}")
    if unexpected:
        problems.append(f"unexpected {len(unexpected)} tensor(s): {_names(unexpected)}")
    if reshaped:
        problems.append(f"{len(reshaped)} of another shape: {_names(reshaped, 2)}")
    return "; ".join(problems)


def infer_windows(
    model: RoninResNet, windows: np.ndarray, batch_size: int | None = None, progress: bool = False
) -> np.ndarray:
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
    progress
        A progress bar over the batches on a terminal (for a command's long single inference).

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
        starts = range(0, len(windows), batch_size)
        for lo in tqdm(starts, desc="RoNIN", unit="batch", disable=None if progress else True, leave=False):
            n = min(batch_size, len(windows) - lo)
            batch[:n] = windows[lo : lo + n]
            batch[n:] = 0.0
            out[lo : lo + n] = model(torch.from_numpy(batch).to(device)).cpu().numpy()[:n]
    return out.astype(np.float64)


def ronin_velocity(imu_df: pd.DataFrame, model: RoninResNet | str | Path | None = None,
                   config: RoninStreamConfig | None = None, source: str = "imu.csv",
                   progress: bool = False) -> pd.DataFrame:
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
    progress
        A progress bar over the inference on a terminal (``localize ronin``).

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
    t_mid, windows = imu_windows(imu_df, config, source)
    velocity = infer_windows(model, windows, config.batch_size, progress)
    return pd.DataFrame({"t": t_mid, "ve": velocity[:, 0], "vn": velocity[:, 1]})


def imu_windows(imu_df: pd.DataFrame, config: RoninStreamConfig, source: str = "imu.csv",
                ) -> tuple[np.ndarray, np.ndarray]:
    """The window-centre times and world-frame windows :func:`ronin_velocity` runs the model on.

    Raises
    ------
    CurbsideInputError
        Bad IMU input, or no stretch as long as one window.
    """
    stream = RoninStream(config, source)
    stream.push(imu_df)
    stream.finish()
    t_mid, windows = stream.take_windows()
    if not len(t_mid):
        raise CurbsideInputError(source, f"no stretch of IMU data without gaps lasts one "
                                         f"{config.window / config.rate_hz:g} s window")
    return t_mid, windows


def check_compatible(model: RoninResNet, config: RoninStreamConfig) -> None:
    """Raise :class:`CurbsideInputError` unless the stream feeds the model its window and rate."""
    if (model.config.window, model.config.rate_hz) != (config.window, config.rate_hz):
        trained = f"trained on {model.config.window}-sample windows at {model.config.rate_hz:g} Hz"
        raise CurbsideInputError(getattr(model, "source", "RoNIN model"),
                                 f"{trained}, the stream cuts {config.window} at {config.rate_hz:g} Hz")
