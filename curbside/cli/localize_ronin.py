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

#: What ``localize ronin`` records as the writer of the velocity files it writes.
RONIN_COMMAND = "localize ronin"


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


def _check_replaceable(out: Path, overwrite: bool) -> None:
    """Refuse to replace, without ``--overwrite``, a velocity file that ``localize ronin`` did not write
    itself: the simulator's stand-in for RoNIN, a conversion's PDR, another command's file, the user's."""
    from curbside.io import writer_of

    if overwrite or not out.is_file():
        return
    writer = writer_of(out)
    if writer != RONIN_COMMAND:
        by = f"by '{writer}'" if writer else "by curbside"
        raise CurbsideInputError(out, f"exists and was written {by}, not by localize ronin; pass --overwrite "
                                      "to replace it, or give another file with -o")


def _ronin(args: argparse.Namespace) -> int:
    from curbside import settings
    from curbside.io import atomic_path, check_output_file, note_written_by
    from curbside.localize.readers import read_any
    from curbside.localize.ronin.familiarity import session_familiarity
    from curbside.localize.ronin.infer import load_model, ronin_velocity
    from curbside.localize.ronin.provenance import weights_record
    from curbside.localize.session import warn_if_simulated_imu

    out, inputs = _ronin_source(args)
    check_output_file(out, args.overwrite, inputs=(*inputs, *([args.weights] if args.weights else [])))
    _check_replaceable(out, args.overwrite)
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
    note_written_by(out, RONIN_COMMAND, inputs=(Path(args.session) / "imu.csv",))
    span = velocity["t"].iat[-1] - velocity["t"].iat[0]
    weights = weights_record(args.weights or settings.ronin_default_weights)
    sys.stdout.write(f"{out}: {len(velocity)} velocities over {span:.1f} s (weights "
                     f"{Path(weights['path']).name}, sha256 {weights['sha256'][:12]})\n")
    sys.stdout.write(f"{out}: {session_familiarity(model, session.imu, config, imu_source).describe()}\n")
    return 0


def _check_data_paths(args: argparse.Namespace) -> None:
    """Refuse ``FILE.h5::TRIAL`` for the options that take a whole dataset file."""
    from curbside.localize.paths import check_whole_file

    for option, path in (("--ms-indoor", args.ms_indoor), ("--ipin", args.ipin)):
        if path:
            check_whole_file(path, option)


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


def _data_inputs(args: argparse.Namespace) -> tuple[Path, ...]:
    """The data files a training or evaluation reads (or, for ``--prepared``, may write): never an output."""
    files = [Path(p) for p in (args.ms_indoor, args.ipin, args.prepared) if p]
    if args.ronin_h5 and Path(args.ronin_h5).is_dir():
        files += sorted(Path(args.ronin_h5).rglob("data.hdf5"))
    return tuple(files)


def _check_not_prepared(outputs: tuple[Path, ...], args: argparse.Namespace) -> None:
    """Refuse an output on the ``--prepared`` path, which the run may write before it (the check of
    existing inputs in :func:`curbside.io.check_output_file` cannot see a file not written yet)."""
    if args.prepared and Path(args.prepared).resolve() in {Path(o).resolve() for o in outputs}:
        raise CurbsideInputError(args.prepared, "is both --prepared and an output of this command: give "
                                                "each its own file")


def _check_train_outputs(args: argparse.Namespace) -> None:
    """Before hours of training: the weights, their config and the checkpoint can be written."""
    from curbside.io import check_output_file
    from curbside.localize.paths import config_path_for

    out = Path(args.output)
    if config_path_for(out) == out:
        raise CurbsideInputError(out, "name the weights .pt: their config goes to a .json beside them")
    _check_not_prepared((out, config_path_for(out)), args)
    for path in (out, config_path_for(out)):
        check_output_file(path, args.overwrite, inputs=_data_inputs(args))
    if args.checkpoint:
        others = {Path(p).resolve() for p in (out, config_path_for(out), args.prepared) if p}
        if Path(args.checkpoint).resolve() in others:
            raise CurbsideInputError(args.checkpoint, "the checkpoint needs a file of its own (not -o, its "
                                                      ".json or --prepared)")
        # An existing checkpoint is read, and must be one of this run's (else an error, before writing).
        check_output_file(args.checkpoint, True, inputs=_data_inputs(args))


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


def _check_device(name: str) -> None:
    """Refuse a torch device that is misspelt or that this machine lacks, before the data are read."""
    import torch

    try:
        torch.zeros(1, device=torch.device(name))
    # torch raises RuntimeError, ValueError or AssertionError (a build without CUDA), with long messages.
    except Exception:  # noqa: BLE001
        here = "cpu, cuda, cuda:N" if torch.cuda.is_available() else "cpu; torch sees no CUDA device"
        problem = f"{name!r} is not a torch device this machine has ({here})"
        raise CurbsideInputError("--device", problem) from None


def _train(args: argparse.Namespace) -> int:
    _check_data_paths(args)
    _check_train_outputs(args)
    _check_device(args.device)
    try:
        return _train_and_save(args)
    except KeyboardInterrupt:
        # One line and status 130, as `localize: interrupted` (the weights are written only at the end).
        ckpt = args.checkpoint
        resume = (f"rerun the same command to resume from {ckpt}" if ckpt and Path(ckpt).is_file()
                  else "give --checkpoint to make a run resumable" if not ckpt
                  else "no checkpoint written yet")
        sys.stderr.write(f"localize: interrupted: nothing written to {args.output}; {resume}\n")
        return 130


def _train_and_save(args: argparse.Namespace) -> int:
    import datetime

    from curbside.localize.ronin.data import WindowSet
    from curbside.localize.ronin.model import RoninConfig
    from curbside.localize.ronin.train import TrainOptions, fit, save_weights

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
    model, history = fit(sets["train"], sets["val"], options, args.checkpoint,
                         _train_extra(args, recordings, sources, sets))
    ended = datetime.datetime.now(datetime.timezone.utc)
    model.config.extra["trained_utc"] = ended.isoformat(timespec="seconds")  # when the last epoch ended
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
    _check_data_paths(args)
    from curbside import settings
    from curbside.io import atomic_path, check_output_file
    from curbside.localize.paths import config_path_for
    from curbside.localize.ronin.evaluate import evaluate_recordings, format_summary
    from curbside.localize.ronin.infer import load_model
    from curbside.localize.ronin.provenance import software_record, weights_record

    if args.output:
        weights = (Path(args.weights), config_path_for(args.weights)) if args.weights else ()
        _check_not_prepared((Path(args.output),), args)
        check_output_file(args.output, args.overwrite, inputs=(*weights, *_data_inputs(args)))
    config = _stream_config(args)
    model = load_model(args.weights)
    keep = () if args.no_pdr else (args.split,)
    all_recordings, sources = _data(args, keep)
    recordings = [r for r in all_recordings if r.split == args.split]
    if not recordings:
        raise CurbsideInputError(_source_names(args, sources), _no_split(args.split, all_recordings))
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


def _no_split(split: str, recordings: list) -> str:
    """Why ``ronin-eval --split`` finds nothing to score: what the data hold in each split."""
    from curbside.localize.ronin.data import IPIN_TEST_MARK, MS_TEST_FRACTION, MS_VAL_FRACTION

    counts = {s: sum(r.split == s for r in recordings) for s in ("train", "val", "test")}
    held = ", ".join(f"{n} {s}" for s, n in counts.items())
    others = " or ".join(f"--split {s}" for s, n in counts.items() if n)
    rule = (f"IPIN's test trials are its {IPIN_TEST_MARK}s, MS-indoor and RoNIN-layout hold out "
            f"{MS_TEST_FRACTION:.0%} for test and {MS_VAL_FRACTION:.0%} for val")
    return (f"no {split!r} recordings (--split): the data hold {held} recordings ({rule})"
            + (f"; give {others}" if others else ""))


_RONIN_EXAMPLES = """examples:
  localize ronin walk/                          # writes walk/velocity.csv (t s, ve and vn m/s)
  localize ronin walk/ --weights my.pt          # your model (my.json beside it)
  localize ronin ipin2023-t3.h5::TrainingTrial01_repetition01 -o vel.csv
Then `localize run walk/ ...` tracks with walk/velocity.csv instead of running RoNIN itself."""

_TRAIN_EXAMPLES = """examples:
  localize train-ronin --ms-indoor ms-indoor-2020.h5 --ipin ipin2023-t3.h5 \\
      --prepared cache/prepared.npz --checkpoint cache/compact.ckpt -o my.pt
      # the default schedule: about 8 min on 2 quiet CPU cores, 25 min on a busy machine
  localize train-ronin --prepared cache/prepared.npz --epochs 1 --windows-per-epoch 2000 -o try.pt
      # a smoke test, one short epoch: about 1.5 min on 2 cores for MS-indoor, mostly validation
Give at least one of --ms-indoor, --ipin, --ronin-h5, or an existing --prepared.
Splits are by recording, never by window: MS-indoor and RoNIN-layout 15 % test and
7 % validation; IPIN every repetition04 test, the rest train (no validation).
Ctrl-C exits 130 and writes no weights; with --checkpoint, the same command resumes."""

_EVAL_EXAMPLES = """examples:
  localize ronin-eval --ms-indoor ms-indoor-2020.h5 --ipin ipin2023-t3.h5 -o report.json
  localize ronin-eval --ipin ipin2023-t3.h5 --weights my.pt --no-pdr
The table gives medians over recordings: distance ratio (estimated / true path length),
speed error (m/s), ATE and RTE (m, after the best rotation about the start), raw ATE (m,
no rotation) and the error at the waypoints (m, median and 90th percentile of them all)."""


def _add_data_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ms-indoor", metavar="H5",
                   help="ms-indoor-2020.h5 (Indoor Location Competition 2.0: 870 walks with waypoints)")
    p.add_argument("--ipin", metavar="H5",
                   help="ipin2023-t3.h5 (IPIN 2023 Track 3: 43 trials with waypoints)")
    p.add_argument("--ronin-h5", metavar="DIR",
                   help="folder of RoNIN-layout sequences, one sub-folder each holding data.hdf5")
    p.add_argument("--prepared", metavar="NPZ",
                   help="cache of the prepared recordings (.npz, about 50 MB for both datasets): read when "
                        "it exists (and was made from the files given, if any), else written after reading")


def _add_stride_arg(p: argparse.ArgumentParser) -> None:
    default = RONIN_STRIDE
    p.add_argument("--stride", type=int, default=default, metavar="N",
                   help=f"200 Hz samples between the starts of the one-second windows, 1 to 200 (default "
                        f"{default}: a velocity every {1000 * default / 200:g} ms)")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``ronin``, ``train-ronin`` and ``ronin-eval``."""
    _register_ronin(subparsers)
    _register_train(subparsers)
    _register_eval(subparsers)


def _register_ronin(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "ronin",
        help="write velocity.csv from a session's imu.csv (RoNIN)",
        description="Estimate the walker's horizontal velocity from the phone IMU with RoNIN (learned "
        "inertial odometry, Herath et al. 2020) and write it as velocity.csv: one row per one-second "
        "window, t (s, the window's centre), ve and vn (m/s east and north, in the frame of the phone's "
        "orientation), which `localize run` then uses instead of running RoNIN itself.",
        epilog=_RONIN_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("session", metavar="SESSION",
                   help="session folder holding imu.csv, or any recording `localize run` reads "
                        "(FILE.h5::TRIAL, a Sensor Logger export; these need -o)")
    p.add_argument("-o", "--output", metavar="CSV", help="output file (default: SESSION/velocity.csv)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the output file even when localize ronin did not write it (the simulator's "
                        "velocity.csv, yours; never one of the inputs)")
    p.add_argument("--weights", metavar="PT",
                   help="weights .pt, its config .json beside it, as train-ronin writes them (default: the "
                        "bundled model)")
    _add_stride_arg(p)
    p.set_defaults(func=_ronin)


def _register_train(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train-ronin",
        help="train a RoNIN model from HDF5 datasets",
        description="Train a RoNIN velocity network on IMU recordings with ground-truth motion (Indoor "
        "Location Competition 2.0, IPIN 2023 Track 3, RoNIN-layout HDF5), keep the weights with the best "
        "validation loss and calibrate their output scale on the validation recordings. The network "
        "maps one-second windows (200 samples at 200 Hz) of world-frame gyroscope and accelerometer to "
        "the mean horizontal velocity (m/s) over the window.",
        epilog=_TRAIN_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_data_args(p)
    p.add_argument("--arch", choices=["compact", "resnet18"], default="compact",
                   help="network: compact (a small 1-D ResNet that trains on two CPU cores) or resnet18 "
                   "(RoNIN's) (default: %(default)s)")
    p.add_argument("--epochs", type=positive_int, default=12, metavar="N",
                   help="training epochs, at least 1 (default: %(default)s)")
    p.add_argument("--windows-per-epoch", type=positive_int, default=120_000, metavar="N",
                   help="one-second training windows drawn per epoch, all of them when fewer (default: "
                        "%(default)s)")
    p.add_argument("--batch-size", type=positive_int, default=256, metavar="N",
                   help="windows per batch (default: %(default)s)")
    p.add_argument("--lr", type=positive_float, default=1e-3,
                   help="Adam learning rate, cosine decay to lr/100 (default: %(default)s)")
    p.add_argument("--seed", type=seed, default=0, metavar="N",
                   help="seed of initialisation, window draws and augmentation (default: %(default)s)")
    p.add_argument("--device", default="cpu",
                   help="torch device: cpu, cuda, cuda:N (default: %(default)s)")
    p.add_argument("--threads", type=positive_int, default=2, metavar="N",
                   help="CPU threads for torch (default: %(default)s)")
    p.add_argument("--checkpoint", metavar="PT",
                   help="resumable checkpoint, written every epoch: rerunning the command resumes from it")
    p.add_argument("-o", "--output", metavar="PT", required=True,
                   help="best weights, written when training ends, with their config .json beside them "
                        "(data, split, options, history)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the weights or their .json even when curbside did not write them (a "
                        "previous train-ronin -o the same file is replaced without it)")
    p.set_defaults(func=_train)


def _register_eval(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "ronin-eval",
        help="RoNIN and PDR figures on held-out recordings",
        description="Score RoNIN weights (and the step-and-heading PDR baseline) on the held-out "
        "recordings of the given datasets, split as train-ronin splits them: distance ratio, speed "
        "error, ATE, RTE and the error at ground-truth waypoints, per recording (-o) and as medians.",
        epilog=_EVAL_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_data_args(p)
    p.add_argument("--weights", metavar="PT",
                   help="weights .pt, its .json beside it (default: the bundled model)")
    p.add_argument("--split", default="test", choices=["test", "val", "train"],
                   help="recordings to score: test (held out from training), val (chose the epoch and "
                        "the output scale) or train (default: %(default)s)")
    p.add_argument("--no-pdr", action="store_true", help="skip the PDR baseline (faster)")
    _add_stride_arg(p)
    p.add_argument("-o", "--output", metavar="JSON",
                   help="also write the full report: per-recording metrics, weights, data and software")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    p.set_defaults(func=_evaluate)
