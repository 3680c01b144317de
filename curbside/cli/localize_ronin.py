"""``localize ronin``, ``localize train-ronin`` and ``localize ronin-eval``: learned inertial odometry."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from curbside import __version__
from curbside.cli.common import OVERWRITE_FILE_HELP, positive_float, positive_int, seed
from curbside.errors import CurbsideInputError
from curbside.localize.runconstants import RONIN_STRIDE

logger = logging.getLogger(__name__)


def _stream_config(args: argparse.Namespace):
    from curbside.localize.ronin.stream import RoninStreamConfig

    try:
        return RoninStreamConfig(stride=args.stride)
    except ValueError as exc:
        raise CurbsideInputError("--stride", str(exc)) from None


def _ronin_source(args: argparse.Namespace) -> tuple[Path, list[Path]]:
    """The output file and the input files of ``localize ronin``: a session folder gets
    ``velocity.csv`` in it, any other recording (``FILE.h5::TRIAL``, a Sensor Logger export) needs -o."""
    from curbside.localize.readers import detect_format, split_trial
    from curbside.localize.session import COLUMNS

    is_folder = detect_format(args.session) == "spec"
    if not is_folder and not args.output:
        raise CurbsideInputError(args.session, "not a session folder: name the velocity file with -o CSV")
    out = Path(args.output) if args.output else Path(args.session) / "velocity.csv"
    if out.suffix.lower() != ".csv":
        raise CurbsideInputError(out, "the velocity is a CSV file: name it .csv")
    if is_folder:
        inputs = [Path(args.session) / f"{kind}.csv" for kind in COLUMNS if kind != "velocity"]
        inputs.append(Path(args.session) / "meta.json")
    else:
        path = split_trial(args.session)[0]
        inputs = sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else [path]
    return out, inputs


def _ronin(args: argparse.Namespace) -> int:
    from curbside import settings
    from curbside.io import atomic_path, check_output_file, note_written
    from curbside.localize.readers import read_any
    from curbside.localize.ronin.infer import load_model, ronin_velocity
    from curbside.localize.ronin.provenance import weights_record
    from curbside.localize.session import warn_if_simulated_imu

    out, inputs = _ronin_source(args)
    check_output_file(out, args.overwrite, inputs=(*inputs, *([args.weights] if args.weights else [])))
    config = _stream_config(args)
    model = load_model(args.weights)
    session = read_any(args.session)
    imu_source = session.file_source("imu.csv")
    if session.imu is None:
        raise CurbsideInputError(imu_source, "no IMU data: RoNIN needs imu.csv")
    warn_if_simulated_imu(session, imu_source)
    velocity = ronin_velocity(session.imu, model, config, source=imu_source, progress=True)
    # Full precision (17 digits round-trip): `localize run` on this file then tracks exactly as it
    # does when it runs RoNIN itself; the particle filter turns a 1e-7 m/s difference into another track.
    with atomic_path(out) as tmp:
        velocity.to_csv(tmp, index=False)
    note_written(out, "localize ronin")
    span = velocity["t"].iat[-1] - velocity["t"].iat[0]
    weights = weights_record(args.weights or settings.ronin_default_weights)
    sys.stdout.write(f"{out}: {len(velocity)} velocities over {span:.1f} s (weights "
                     f"{Path(weights['path']).name}, sha256 {weights['sha256'][:12]})\n")
    return 0


def _data(args: argparse.Namespace, keep_imu: tuple[str, ...] = ()):
    """The recordings and the records of their sources (those given, else the prepared file's)."""
    from curbside.localize.ronin.data import prepare_recordings, prepared_sources
    from curbside.localize.ronin.provenance import source_records

    sources = source_records(args.ms_indoor, args.ipin, args.ronin_h5)
    recordings = prepare_recordings(args.ms_indoor, args.ipin, args.ronin_h5, args.prepared, progress=True,
                                    keep_imu=keep_imu, sources=sources)
    if not sources and args.prepared:
        sources = prepared_sources(args.prepared) or []
    return recordings, sources


def _check_train_outputs(args: argparse.Namespace) -> None:
    """Before hours of training: the weights, their config and the checkpoint can be written."""
    from curbside.io import check_output_file
    from curbside.localize.ronin.infer import config_path_for

    out = Path(args.output)
    if config_path_for(out) == out:
        raise CurbsideInputError(out, "name the weights .pt: their config goes to a .json beside them")
    for path in (out, config_path_for(out)):
        check_output_file(path, args.overwrite, inputs=tuple(p for p in (args.prepared,) if p))
    if args.checkpoint:
        others = {Path(p).resolve() for p in (out, config_path_for(out), args.prepared) if p}
        if Path(args.checkpoint).resolve() in others:
            raise CurbsideInputError(args.checkpoint, "the checkpoint needs a file of its own (not -o, its "
                                                      ".json or --prepared)")
        # An existing checkpoint is read, and must be one of this run's (else an error, before writing).
        check_output_file(args.checkpoint, True)


def _train_extra(args: argparse.Namespace, recordings: list, sources: list[dict], sets: dict) -> dict:
    """What the weights' config records about their making (``extra``)."""
    from curbside.localize.ronin import data
    from curbside.localize.ronin.provenance import software_record

    return {
        "sources": sorted({r.source for r in recordings}),
        "data": sources,
        "split": {"rule": "by recording (curbside.localize.ronin.data.split_of)", "salt": data.SPLIT_SALT,
                  "ms_and_ronin_test_fraction": data.MS_TEST_FRACTION,
                  "ms_and_ronin_val_fraction": data.MS_VAL_FRACTION, "ipin_test_mark": data.IPIN_TEST_MARK},
        "recordings": {s: sum(r.split == s for r in recordings) for s in ("train", "val", "test")},
        "train_windows": len(sets["train"]), "val_windows": len(sets["val"]),
        "software": software_record(),
        "arguments": {k: v for k, v in sorted(vars(args).items()) if k not in ("func", "verbose")},
    }


def _train(args: argparse.Namespace) -> int:
    _check_train_outputs(args)
    import torch

    from curbside.localize.ronin.data import WindowSet
    from curbside.localize.ronin.model import RoninConfig
    from curbside.localize.ronin.train import TrainOptions, fit, save_weights

    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise CurbsideInputError("--device", f"{args.device!r} requested but torch sees no CUDA device")
    recordings, sources = _data(args)
    options = TrainOptions(arch=args.arch, epochs=args.epochs, windows_per_epoch=args.windows_per_epoch,
                           batch_size=args.batch_size, lr=args.lr, seed=args.seed, device=args.device,
                           num_threads=args.threads)
    shape = RoninConfig()  # RoNIN's one-second windows at 200 Hz, a training window every 10 samples
    sets = {
        split: WindowSet.build([r for r in recordings if r.split == split], shape.window, shape.stride,
                               shape.rate_hz)
        for split in ("train", "val")
    }
    given = _source_names(args, sources)
    if len(sets["train"]) == 0:
        raise CurbsideInputError(given, "no labelled training windows in the training split")
    if len(sets["val"]) == 0:
        logger.warning("%s: no validation recordings, so the last epoch is kept and the output scale is "
                       "not calibrated (1.0); MS-indoor and RoNIN-layout data hold 7 %% of their "
                       "recordings out for validation, IPIN trials none", given)
    try:
        model, history = fit(sets["train"], sets["val"], options, args.checkpoint,
                             _train_extra(args, recordings, sources, sets))
    except KeyboardInterrupt:
        resume = (f"rerun the same command to resume from {args.checkpoint}" if args.checkpoint
                  else "give --checkpoint to make a run resumable")
        logger.warning("training interrupted: nothing written to %s; %s", args.output, resume)
        raise
    scale = _calibrate(model, [r for r in recordings if r.split == "val"])
    save_weights(model, args.output)
    best = history[model.config.extra["best_epoch"] - 1]
    chosen = (f"best epoch {best['epoch']} of {len(history)}, val MSE {best['val_loss']:.4f} (m/s)^2"
              if best["val_loss"] is not None else f"last epoch {best['epoch']} (no validation)")
    sys.stdout.write(f"{args.output}: {chosen}, output scale {scale:.3f}\n")
    return 0


def _source_names(args: argparse.Namespace, sources: list[dict]) -> str:
    """The data files, for messages."""
    return ", ".join(Path(r["path"]).name for r in sources) or str(args.prepared)


def _calibrate(model, val_recordings: list) -> float:
    """Calibrate the output scale on the validation recordings (1.0 without any), warning when the
    model's distances are off by more than a factor of 2."""
    from curbside.localize.ronin.evaluate import calibrate_output_scale

    scale = calibrate_output_scale(model, val_recordings) if val_recordings else 1.0
    model.config.extra["output_scale_from"] = (
        f"median distance ratio on {len(val_recordings)} validation recordings" if val_recordings
        else "not calibrated: no validation recordings"
    )
    if not 0.5 <= scale <= 2.0:
        logger.warning("output scale %.3f: the model's distances are off by more than a factor of 2 on "
                       "the validation recordings (train longer?)", scale)
    return scale


def _evaluate(args: argparse.Namespace) -> int:
    from curbside import settings
    from curbside.io import atomic_path, check_output_file
    from curbside.localize.ronin.evaluate import evaluate_recordings, format_summary
    from curbside.localize.ronin.infer import load_model
    from curbside.localize.ronin.provenance import software_record, weights_record

    if args.output:
        check_output_file(args.output, args.overwrite, inputs=(args.weights,) if args.weights else ())
    config = _stream_config(args)
    model = load_model(args.weights)
    keep = () if args.no_pdr else (args.split,)
    all_recordings, sources = _data(args, keep)
    recordings = [r for r in all_recordings if r.split == args.split]
    if not recordings:
        raise CurbsideInputError(_source_names(args, sources), f"no {args.split!r} recordings (--split)")
    report = evaluate_recordings(recordings, model, with_pdr=not args.no_pdr, config=config, progress=True)
    trained_on = model.config.extra.get("sources")
    report = {"generator": f"curbside {__version__}",
              "weights": {**weights_record(args.weights or settings.ronin_default_weights),
                          "trained_on": trained_on},
              "split": args.split, "data": sources, "software": software_record(), **report}
    if args.output:
        with atomic_path(args.output) as tmp:
            tmp.write_text(json.dumps(report, indent=1), encoding="utf-8")
    sys.stdout.write(format_summary(report))
    return 0


def _add_data_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ms-indoor", metavar="H5", help="ms-indoor-2020.h5 (Indoor Location Competition 2.0)")
    p.add_argument("--ipin", metavar="H5", help="ipin2023-t3.h5 (IPIN 2023 Track 3 trials)")
    p.add_argument("--ronin-h5", metavar="DIR", help="folder of RoNIN-layout sequences (*/data.hdf5)")
    p.add_argument("--prepared", metavar="NPZ",
                   help="cache of the prepared recordings: read when it exists, else written after reading")


def _add_stride_arg(p: argparse.ArgumentParser) -> None:
    default = RONIN_STRIDE
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
    p.add_argument("session", metavar="SESSION",
                   help="session folder holding imu.csv, or any recording `localize run` reads "
                        "(FILE.h5::TRIAL, a Sensor Logger export; these need -o)")
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
    p.add_argument("--epochs", type=positive_int, default=12, help="training epochs (default: %(default)s)")
    p.add_argument("--windows-per-epoch", type=positive_int, default=120_000,
                   help="training windows drawn per epoch (default: %(default)s)")
    p.add_argument("--batch-size", type=positive_int, default=256,
                   help="windows per batch (default: %(default)s)")
    p.add_argument("--lr", type=positive_float, default=1e-3,
                   help="Adam learning rate, cosine decay to lr/100 (default: %(default)s)")
    p.add_argument("--seed", type=seed, default=0,
                   help="seed of initialisation, window draws and augmentation (default: %(default)s)")
    p.add_argument("--device", default="cpu", help="torch device: cpu, cuda (default: %(default)s)")
    p.add_argument("--threads", type=positive_int, default=2,
                   help="CPU threads for torch (default: %(default)s)")
    p.add_argument("--checkpoint", metavar="PT",
                   help="resumable checkpoint, written every epoch: rerunning the command resumes from it")
    p.add_argument("-o", "--output", metavar="PT", required=True,
                   help="best weights, written when training ends (config .json beside, with the data, "
                        "split, options and history)")
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
