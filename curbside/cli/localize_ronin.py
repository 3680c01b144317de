"""``localize ronin``, ``localize train-ronin`` and ``localize ronin-eval``: learned inertial odometry."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from curbside import __version__
from curbside.cli.common import seed
from curbside.errors import CurbsideInputError
from curbside.io import OVERWRITE_FILE_HELP, atomic_path, check_output_file, note_written

logger = logging.getLogger(__name__)


def _stream_config(args: argparse.Namespace):
    from curbside.localize.ronin.stream import RoninStreamConfig

    try:
        return RoninStreamConfig(stride=args.stride)
    except ValueError as exc:
        raise CurbsideInputError("--stride", str(exc)) from None


def _ronin(args: argparse.Namespace) -> int:
    out = Path(args.output) if args.output else Path(args.session) / "velocity.csv"
    if out.suffix.lower() != ".csv":
        raise CurbsideInputError(out, "the velocity is a CSV file: name it .csv")
    from curbside.localize.session import COLUMNS, read_session, warn_if_simulated_imu

    session_files = [Path(args.session) / f"{kind}.csv" for kind in COLUMNS if kind != "velocity"]
    inputs = (*session_files, Path(args.session) / "meta.json", *([args.weights] if args.weights else []))
    check_output_file(out, args.overwrite, inputs=inputs)
    from curbside.localize.ronin.infer import load_model, ronin_velocity

    session = read_session(args.session)
    if session.imu is None:
        raise CurbsideInputError(Path(args.session) / "imu.csv", "no such file: RoNIN needs imu.csv")
    imu_path = Path(args.session) / "imu.csv"
    warn_if_simulated_imu(session, str(imu_path))
    velocity = ronin_velocity(session.imu, load_model(args.weights), _stream_config(args),
                              source=str(imu_path), progress=True)
    with atomic_path(out) as tmp:
        velocity.to_csv(tmp, index=False, float_format="%.6f")
    note_written(out, "localize ronin")
    span = velocity["t"].iat[-1] - velocity["t"].iat[0]
    sys.stdout.write(f"{out}: {len(velocity)} velocities over {span:.1f} s\n")
    return 0


def _recordings(args: argparse.Namespace, keep_imu: tuple[str, ...] = ()):
    from curbside.localize.ronin.data import prepare_recordings

    return prepare_recordings(args.ms_indoor, args.ipin, args.ronin_h5, args.prepared, progress=True,
                              keep_imu=keep_imu)


def _train(args: argparse.Namespace) -> int:
    # Before hours of training: the weights and their config beside them.
    from curbside.localize.ronin.infer import config_path_for

    for path in (args.output, config_path_for(args.output)):
        check_output_file(path, args.overwrite)
    import torch

    from curbside.localize.ronin.data import WindowSet
    from curbside.localize.ronin.evaluate import calibrate_output_scale
    from curbside.localize.ronin.infer import load_model
    from curbside.localize.ronin.model import RoninConfig
    from curbside.localize.ronin.train import TrainOptions, save_weights, train

    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise CurbsideInputError("--device", f"{args.device!r} requested but torch sees no CUDA device")
    recordings = _recordings(args)
    options = TrainOptions(arch=args.arch, epochs=args.epochs, windows_per_epoch=args.windows_per_epoch,
                           batch_size=args.batch_size, lr=args.lr, seed=args.seed, device=args.device,
                           num_threads=args.threads)
    shape = RoninConfig()  # RoNIN's one-second windows at 200 Hz, a training window every 10 samples
    sets = {
        split: WindowSet.build([r for r in recordings if r.split == split], shape.window, shape.stride,
                               shape.rate_hz)
        for split in ("train", "val")
    }
    if len(sets["train"]) == 0:
        raise CurbsideInputError("training data", "no labelled training windows")
    extra = {"sources": sorted({r.source for r in recordings}),
             "recordings": {s: sum(r.split == s for r in recordings) for s in ("train", "val", "test")},
             "train_windows": len(sets["train"]), "val_windows": len(sets["val"])}
    history = train(sets["train"], sets["val"], options, args.output, checkpoint=args.checkpoint, extra=extra)
    best = min(history, key=lambda h: h["val_loss"])
    model = load_model(args.output)
    scale = calibrate_output_scale(model, [r for r in recordings if r.split == "val"])
    save_weights(model, args.output)
    sys.stdout.write(f"{args.output}: best epoch {best['epoch']} val MSE {best['val_loss']:.4f} (m/s)^2, "
                     f"output scale {scale:.3f}\n")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from curbside.localize.ronin.evaluate import evaluate_recordings, format_summary
    from curbside.localize.ronin.infer import load_model

    if args.output:
        check_output_file(args.output, args.overwrite, inputs=(args.weights,) if args.weights else ())
    keep = () if args.no_pdr else (args.split,)
    recordings = [r for r in _recordings(args, keep) if r.split == args.split]
    if not recordings:
        raise CurbsideInputError("--split", f"no {args.split!r} recordings in the data given")
    report = evaluate_recordings(recordings, load_model(args.weights), with_pdr=not args.no_pdr,
                                 config=_stream_config(args))
    if args.output:
        with atomic_path(args.output) as tmp:
            tmp.write_text(json.dumps({"generator": f"curbside {__version__}", **report}, indent=1),
                           encoding="utf-8")
    sys.stdout.write(format_summary(report))
    return 0


def _add_data_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ms-indoor", metavar="H5", help="ms-indoor-2020.h5 (Indoor Location Competition 2.0)")
    p.add_argument("--ipin", metavar="H5", help="ipin2023-t3.h5 (IPIN 2023 Track 3 trials)")
    p.add_argument("--ronin-h5", metavar="DIR", help="folder of RoNIN-layout sequences (*/data.hdf5)")
    p.add_argument("--prepared", metavar="NPZ",
                   help="cache of the prepared recordings: read when it exists, else written after reading")


def _add_stride_arg(p: argparse.ArgumentParser) -> None:
    from curbside.localize.ronin.stream import RoninStreamConfig

    default = RoninStreamConfig().stride
    p.add_argument("--stride", type=int, default=default, metavar="N",
                   help=f"200 Hz samples between window starts (default {default}: a velocity every "
                        f"{1000 * default / 200:g} ms)")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``ronin``, ``train-ronin`` and ``ronin-eval``."""
    p = subparsers.add_parser(
        "ronin",
        help="write velocity.csv from a session's imu.csv (RoNIN)",
        description="Estimate the walker's horizontal velocity from the phone IMU with RoNIN (learned "
        "inertial odometry, Herath et al. 2020) and write it as velocity.csv (t, ve, vn in m/s), which "
        "`localize run` then uses instead of running RoNIN itself.",
    )
    p.add_argument("session", metavar="SESSION", help="session folder holding imu.csv")
    p.add_argument("-o", "--output", metavar="CSV", help="output file (default: SESSION/velocity.csv)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    p.add_argument("--weights", metavar="PT", help="weights .pt with its .json (default: the bundled model)")
    _add_stride_arg(p)
    p.set_defaults(func=_ronin)

    p = subparsers.add_parser(
        "train-ronin",
        help="train a RoNIN model from HDF5 datasets",
        description="Train a RoNIN velocity network on IMU recordings with ground-truth motion (Indoor "
        "Location Competition 2.0, IPIN 2023 Track 3, RoNIN-layout HDF5), keep the weights with the best "
        "validation loss and calibrate their output scale on the validation recordings.",
    )
    _add_data_args(p)
    p.add_argument("--arch", choices=["compact", "resnet18"], default="compact",
                   help="network: compact (a small 1-D ResNet that trains on two CPU cores) or resnet18 "
                   "(RoNIN's) (default: %(default)s)")
    p.add_argument("--epochs", type=int, default=12, help="training epochs (default: %(default)s)")
    p.add_argument("--windows-per-epoch", type=int, default=120_000,
                   help="training windows drawn per epoch (default: %(default)s)")
    p.add_argument("--batch-size", type=int, default=256, help="windows per batch (default: %(default)s)")
    p.add_argument("--lr", type=float, default=1e-3,
                   help="Adam learning rate, cosine decay to lr/100 (default: %(default)s)")
    p.add_argument("--seed", type=seed, default=0,
                   help="seed of initialisation, window draws and augmentation (default: %(default)s)")
    p.add_argument("--device", default="cpu", help="torch device: cpu, cuda (default: %(default)s)")
    p.add_argument("--threads", type=int, default=2, help="CPU threads for torch (default: %(default)s)")
    p.add_argument("--checkpoint", metavar="PT", help="resumable checkpoint, written every epoch")
    p.add_argument("-o", "--output", metavar="PT", required=True, help="best weights (config .json beside)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing weights and their config (to train into the same file again)")
    p.set_defaults(func=_train)

    p = subparsers.add_parser(
        "ronin-eval",
        help="RoNIN and PDR figures on held-out recordings",
        description="Score RoNIN weights (and the step-and-heading PDR baseline) on held-out recordings: "
        "ATE, RTE and the error at ground-truth points, per recording and pooled.",
    )
    _add_data_args(p)
    p.add_argument("--weights", metavar="PT", help="weights .pt (default: the bundled model)")
    p.add_argument("--split", default="test", choices=["test", "val", "train"],
                   help="recordings to score (default: %(default)s)")
    p.add_argument("--no-pdr", action="store_true", help="skip the PDR baseline")
    _add_stride_arg(p)
    p.add_argument("-o", "--output", metavar="JSON", help="write the full report here")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    p.set_defaults(func=_evaluate)
