"""Training RoNIN: seeded, resumable, validated every epoch, best weights kept.

One epoch draws ``windows_per_epoch`` labelled windows from the training recordings (without
replacement, by a generator seeded from ``seed`` and the epoch number, so a resumed run draws the
same windows), rotates each window and its target by a random yaw (RoNIN's augmentation: the
network must not learn the world frame's arbitrary heading), and minimises the mean squared
velocity error with Adam and a cosine learning-rate schedule. Validation uses held-out recordings,
unrotated. A checkpoint (model, optimiser, schedule, history, the best weights so far, a digest of
the data) is written after every epoch; the weights with the lowest validation loss are saved, once
training ends, as a plain ``state_dict`` plus a JSON config.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm.auto import tqdm

from curbside.cache import content_key
from curbside.errors import CurbsideInputError
from curbside.io import atomic_path, note_written
from curbside.localize.paths import config_path_for
from curbside.localize.ronin.data import WindowSet
from curbside.localize.ronin.model import RoninConfig, RoninResNet, count_parameters

logger = logging.getLogger(__name__)


@dataclass
class TrainOptions:
    """Knobs of :func:`train`.

    Attributes
    ----------
    arch
        ``"compact"`` or ``"resnet18"``.
    epochs
        Number of epochs.
    windows_per_epoch
        Training windows drawn per epoch (all of them when larger than the set).
    batch_size, lr, weight_decay
        Optimiser settings (Adam, cosine decay to ``lr / 100``).
    seed
        Seeds weight initialisation, window draws, yaw augmentation and dropout.
    device
        ``"cpu"``, ``"cuda"``...
    num_threads
        CPU threads for torch (2 on the shared development machine).
    val_every
        Use every n-th validation window (validation cost).
    """

    arch: str = "compact"
    epochs: int = 12
    windows_per_epoch: int = 120_000
    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-4
    seed: int = 0
    device: str = "cpu"
    num_threads: int = 2
    val_every: int = 1

    def schedule_key(self) -> dict:
        """The options a resumed run must share with the checkpoint (not the device or threads)."""
        return {k: v for k, v in asdict(self).items() if k not in ("device", "num_threads")}


def normalisation_stats(features: np.ndarray) -> tuple[list[float], list[float]]:
    """Per-channel mean and std that commute with yaw rotations.

    Horizontal channels (x, y of the gyroscope and of the accelerometer) get mean 0 and one pooled
    standard deviation, so that normalising then rotating equals rotating then normalising.
    """
    f = features.astype(np.float64)
    mean = np.zeros(6)
    std = np.ones(6)
    for base in (0, 3):
        xy = f[:, base : base + 2]
        std[base : base + 2] = np.sqrt(np.mean(xy**2))
        mean[base + 2] = f[:, base + 2].mean()
        std[base + 2] = f[:, base + 2].std()
    return mean.tolist(), np.maximum(std, 1e-6).tolist()


def rotate_yaw(x: torch.Tensor, y: torch.Tensor, angle: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotate windows ``(B, 6, W)`` and targets ``(B, 2)`` about the vertical by ``angle`` (B,) rad."""
    c, s = torch.cos(angle), torch.sin(angle)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)  # (B, 2, 2)
    x = x.clone()
    for base in (0, 3):
        x[:, base : base + 2] = torch.einsum("bij,bjw->biw", rot, x[:, base : base + 2])
    return x, torch.einsum("bij,bj->bi", rot, y)


class WindowBatcher:
    """Gathers ``(B, 6, W)`` windows and ``(B, 2)`` targets of a :class:`WindowSet` on a device."""

    def __init__(self, windows: WindowSet, device: torch.device) -> None:
        self.features = torch.from_numpy(windows.features).to(device)
        self.starts = torch.from_numpy(windows.starts).to(device)
        self.targets = torch.from_numpy(windows.targets).to(device)
        self.offsets = torch.arange(windows.window, device=device)

    def __len__(self) -> int:
        return len(self.starts)

    def batch(self, index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Windows and targets of the window numbers ``index``."""
        rows = self.starts[index, None] + self.offsets  # (B, W)
        return self.features[rows].permute(0, 2, 1), self.targets[index]


def _set_determinism(seed: int, device: torch.device) -> None:
    torch.manual_seed(seed)
    if device.type == "cuda":
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        torch.backends.cudnn.benchmark = False
    torch.use_deterministic_algorithms(True, warn_only=True)


def evaluate_loss(model: nn.Module, batcher: WindowBatcher, every: int = 1, batch_size: int = 4096) -> float:
    """Mean squared velocity error over every ``every``-th window (no augmentation)."""
    model.eval()
    index = torch.arange(0, len(batcher), every, device=batcher.starts.device)
    total, count = 0.0, 0
    with torch.inference_mode():
        for lo in range(0, len(index), batch_size):
            x, y = batcher.batch(index[lo : lo + batch_size])
            total += float(((model(x) - y) ** 2).sum())
            count += y.numel()
    return total / max(count, 1)


def save_weights(model: RoninResNet, path: str | Path) -> Path:
    """Write ``path`` (state_dict) and its JSON config beside it, atomically, and list both in the
    folder's marker (a later ``train-ronin -o`` the same path may replace them)."""
    path = Path(path)
    # Both are staged before either replaces its file: a Ctrl-C or a full disk while writing leaves the
    # previous pair (or none), never new weights beside an old config.
    with atomic_path(path) as tmp_weights, atomic_path(config_path_for(path)) as tmp_config:
        torch.save({k: v.detach().cpu() for k, v in model.state_dict().items()}, tmp_weights)
        tmp_config.write_text(json.dumps(model.config.to_dict(), indent=1, allow_nan=False), encoding="utf-8")
    for written in (path, config_path_for(path)):
        note_written(written, "localize train-ronin")
    return path


def data_fingerprint(train_set: WindowSet, val_set: WindowSet) -> str:
    """SHA-256 of the training and validation windows (features, starts, targets): a checkpoint
    resumes only on the data it was made from."""
    return content_key(*(getattr(ws, name) for ws in (train_set, val_set)
                         for name in ("features", "starts", "targets")))


def _read_checkpoint(path: Path, device: torch.device, options: TrainOptions, data_key: str) -> dict:
    """A checkpoint's state, checked to belong to this run (same options, same data)."""
    try:
        state = torch.load(path, map_location=device, weights_only=True)
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read the checkpoint ({exc.strerror or exc})") from None
    # torch.load raises many types (with many-line messages) for a file in another format.
    except Exception:  # noqa: BLE001
        raise CurbsideInputError(path, "not a train-ronin checkpoint (torch cannot read it)") from None
    keys = {"model", "optimiser", "schedule", "history", "options", "best"}
    if not isinstance(state, dict) or not keys <= set(state):
        # "delete it" only for what can only be a checkpoint: never for weights or other files
        if isinstance(state, dict) and {"model", "history"} <= set(state):
            problem = "a train-ronin checkpoint of an older curbside version: delete it or give another"
        elif isinstance(state, dict) and state and all(isinstance(v, torch.Tensor) for v in state.values()):
            problem = "holds model weights, not a train-ronin checkpoint: give another"
        else:
            problem = "not a train-ronin checkpoint: give another"
        raise CurbsideInputError(path, f"{problem} --checkpoint")
    if json.loads(state["options"]) != options.schedule_key():
        raise CurbsideInputError(path, "checkpoint of a run with other options (epochs, seed...)")
    if state.get("data") != data_key:
        raise CurbsideInputError(path, "checkpoint of a run on other data (sources or split): delete it "
                                       "or give another --checkpoint")
    return state


def _new_run(train_set: WindowSet, options: TrainOptions, device: torch.device, extra: dict | None,
             ) -> tuple[RoninResNet, torch.optim.Optimizer, torch.optim.lr_scheduler.LRScheduler]:
    """A seeded model normalised for ``train_set``, its optimiser and learning-rate schedule."""
    if device.type == "cpu":
        torch.set_num_threads(options.num_threads)
    _set_determinism(options.seed, device)
    mean, std = normalisation_stats(train_set.features)
    config = RoninConfig.for_arch(options.arch, window=train_set.window, rate_hz=train_set.rate_hz,
                                  feature_mean=mean, feature_std=std,
                                  extra={"train_options": asdict(options), **(extra or {})})
    model = RoninResNet(config).to(device)
    optimiser = torch.optim.Adam(model.parameters(), lr=options.lr, weight_decay=options.weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, options.epochs, eta_min=options.lr / 100)
    return model, optimiser, schedule


def _write_checkpoint(path: str | Path, state: dict) -> None:
    """Write a checkpoint atomically and list it in its folder's marker."""
    with atomic_path(path) as tmp:
        torch.save(state, tmp)
    note_written(path, "localize train-ronin")


def _check_finite(epoch: int, train_loss: float, val_loss: float | None) -> None:
    """Stop a run whose loss is no longer finite, before its checkpoint or weights are written."""
    for name, loss in (("training", train_loss), ("validation", val_loss)):
        if loss is not None and not math.isfinite(loss):
            raise CurbsideInputError(f"epoch {epoch}", f"the {name} loss is {loss}: training diverged; "
                                                       "try a lower --lr (nothing was written)")


def _best_epoch(history: list[dict]) -> dict:
    """The epoch whose weights are kept: the lowest validation loss, else (no validation) the last."""
    scored = [h for h in history if h["val_loss"] is not None]
    return min(scored, key=lambda h: h["val_loss"]) if scored else history[-1]


def fit(train_set: WindowSet, val_set: WindowSet, options: TrainOptions,
        checkpoint: str | Path | None = None, extra: dict | None = None,
        progress: bool = True) -> tuple[RoninResNet, list[dict]]:
    """Train a RoNIN model; return the best-on-validation weights and the history.

    Parameters
    ----------
    train_set, val_set
        Windows of the training and validation recordings (split by recording). Without validation
        windows, the last epoch's weights are kept.
    options
        See :class:`TrainOptions`.
    checkpoint
        Resumable state, written after each epoch (atomically, listed in its folder's marker);
        training resumes from it when it exists. It must come from a run with the same options
        (:meth:`TrainOptions.schedule_key`) on the same windows (:func:`data_fingerprint`).
    extra
        Stored in the config's ``extra`` (data sources, split...).
    progress
        Show tqdm bars (an epoch bar, and a batch bar within each epoch).

    Returns
    -------
    model, history
        The kept weights, on CPU, in evaluation mode, their config's ``extra`` holding
        ``best_epoch``, ``val_loss`` and the whole ``history``; and per epoch ``epoch``,
        ``train_loss``, ``val_loss`` (``None`` without validation windows), ``lr``, ``seconds``.

    Raises
    ------
    CurbsideInputError
        A checkpoint that is unreadable or of another run; a loss that is no longer finite (diverged:
        the checkpoint keeps the last finite epoch).
    """
    if len(train_set) == 0:
        raise CurbsideInputError("training data", "no labelled training windows")
    device = torch.device(options.device)
    model, optimiser, schedule = _new_run(train_set, options, device, extra)
    data_key = data_fingerprint(train_set, val_set)
    history: list[dict] = []
    best_state: dict[str, torch.Tensor] | None = None
    if checkpoint is not None and Path(checkpoint).is_file():
        state = _read_checkpoint(Path(checkpoint), device, options, data_key)
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        schedule.load_state_dict(state["schedule"])
        history, best_state = json.loads(state["history"]), state["best"]
        logger.info("resumed from %s after epoch %d", checkpoint, len(history))
    logger.info("%s: %d parameters, %d train / %d val windows", options.arch, count_parameters(model),
                len(train_set), len(val_set))
    train_b, val_b = WindowBatcher(train_set, device), WindowBatcher(val_set, device)
    n_draw = min(options.windows_per_epoch, len(train_b))
    epochs = tqdm(range(len(history), options.epochs), desc="train-ronin", unit="epoch",
                  initial=len(history), total=options.epochs, disable=None if progress else True)
    for epoch in epochs:
        tic = time.perf_counter()
        train_loss = _train_epoch(model, optimiser, train_b, n_draw, options, epoch, progress)
        lr = optimiser.param_groups[0]["lr"]
        schedule.step()
        val_loss = evaluate_loss(model, val_b, options.val_every) if len(val_b) else None
        _check_finite(epoch + 1, train_loss, val_loss)
        history.append({"epoch": epoch + 1, "train_loss": train_loss, "val_loss": val_loss, "lr": lr,
                        "seconds": time.perf_counter() - tic})
        val_text = "none" if val_loss is None else f"{val_loss:.4f}"
        epochs.set_postfix(train=f"{train_loss:.4f}", val=val_text)
        logger.info("epoch %d: train %.4f val %s (%.0f s)", epoch + 1, train_loss, val_text,
                    history[-1]["seconds"])
        if _best_epoch(history) is history[-1]:
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        if checkpoint is not None:
            _write_checkpoint(checkpoint, {
                "model": model.state_dict(), "optimiser": optimiser.state_dict(),
                "schedule": schedule.state_dict(), "history": json.dumps(history),
                "options": json.dumps(options.schedule_key()), "data": data_key, "best": best_state})
    model.load_state_dict(best_state)
    best = _best_epoch(history)
    model.config.extra.update(best_epoch=best["epoch"], val_loss=best["val_loss"], history=history)
    return model.cpu().eval(), history


def train(train_set: WindowSet, val_set: WindowSet, options: TrainOptions, out: str | Path,
          checkpoint: str | Path | None = None, extra: dict | None = None,
          progress: bool = True) -> list[dict]:
    """Train a RoNIN model (:func:`fit`) and save the kept weights to ``out`` once training is done.

    ``out`` is a ``.pt`` path; the config goes to ``.json`` beside it. Nothing is written there before
    the last epoch, so an interrupted run leaves no weights (only the checkpoint). The output scale
    is not calibrated (see :func:`curbside.localize.ronin.evaluate.calibrate_output_scale`). Other
    parameters and the returned history are those of :func:`fit`.
    """
    model, history = fit(train_set, val_set, options, checkpoint, extra, progress)
    save_weights(model, out)
    return history


def _train_epoch(model: nn.Module, optimiser: torch.optim.Optimizer, train_b: WindowBatcher, n_draw: int,
                 options: TrainOptions, epoch: int, progress: bool) -> float:
    """One epoch over ``n_draw`` windows drawn (seeded by epoch) and randomly yawed; the mean loss."""
    gen = torch.Generator().manual_seed(options.seed * 100_003 + epoch)
    torch.manual_seed(options.seed * 100_003 + epoch)
    device = train_b.features.device
    order = torch.randperm(len(train_b), generator=gen)[:n_draw].to(device)
    angles = (torch.rand(n_draw, generator=gen) * 2 * math.pi).to(device)
    model.train()
    total, seen = 0.0, 0
    bar = tqdm(range(0, n_draw, options.batch_size), desc=f"epoch {epoch + 1}/{options.epochs}",
               disable=None if progress else True, leave=False)
    for lo in bar:
        idx = order[lo : lo + options.batch_size]
        x, y = rotate_yaw(*train_b.batch(idx), angles[lo : lo + options.batch_size])
        loss = nn.functional.mse_loss(model(x), y)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        total += loss.item() * len(idx)
        seen += len(idx)
        bar.set_postfix(loss=f"{total / seen:.4f}")
    return total / seen
