"""Oracles: what would perfect wrong-side detection, a perfect speed scale or a perfect inertial gain?

In urban canyons a phone's fix often lands on the other side of the street (a reflected signal; the
paper's Fig. 3), and the simulator reproduces this (``curbside/evaluate/gnss_model.py``). A
likelihood that knows about it (a mirrored component, a wrong-side detector) can at best do what this
oracle does: it copies each session, drops every fix whose nearest sidewalk segment is the
other side of the same OSM way as the walker's true nearest segment, and runs the methods on the
originals and the copies. If the fused filter's CSA barely moves, wrong-side fixes are not what
limits it, and modelling them is not worth its complexity.

``--oracle speed-scale`` instead divides each copy's ``velocity.csv`` by the walk's simulated speed
scale (``meta.json``), the most a perfect speed-scale estimator could give; ``--oracle inertial``
replaces it with the true walk's velocity (the surveyed path differentiated at the same times), the
most any inertial model could give: what is left is down to GNSS and the map. ``--oracle speed`` keeps
the inertial direction at the true speed, ``--oracle heading`` the inertial speed in the true
direction: which half of the inertial error costs what. ``--oracle stance`` is not an oracle but a rule
a filter could apply: the velocity is zeroed wherever no footstep came within a second (phantom motion
at the kerb), and ``--oracle step-length`` gives each footstep the running median of the last 20
steps' inertial lengths (step-to-step speed noise). ``--oracle resimulate --velocity-set
scale_wander_sd=0`` simulates the same sessions again with one of the phone profile's inertial error
components switched off.

Usage::

    python benchmarks/oracle_fusion.py OUT --map MAP
        [--oracle wrong-side|speed-scale|stance|step-length|speed|heading|inertial|resimulate]
        [--velocity-set FIELD=VALUE ...] [--split tune|test] [--subsets paper6] [--seeds 0 1]

``OUT`` is a working folder (e.g. the one of ``benchmarks/tune_fusion.py``); the sessions of ``--split``
(default ``tune``) are simulated into it on first use. An oracle chooses no parameter, so running it on
the scored ``test`` split bounds what any change to the filter could score there.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
from tune_fusion import run

from curbside.evaluate.groundtruth import groundtruth_at
from curbside.evaluate.simulate import PhoneVelocityErrorModel, SimulationConfig
from curbside.evaluate.subsets import SUBSETS, benchmark_sessions, load_world
from curbside.localize.filter.config import MapConfig
from curbside.localize.raster import load_or_build_raster
from curbside.localize.session import read_session
from curbside.osmseg.mapio import read_map
from curbside.projection import LocalFrame

ORACLES = ("wrong-side", "speed-scale", "stance", "step-length", "speed", "heading", "inertial", "resimulate")
STANCE_GAP_S = 1.0  # no footstep within this long on either side: standing
STEP_WINDOW = 20  # footsteps in the running median of the step length


def way_and_side(segment_ids: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(way, side)`` of each segment index (``w<way>-<k>-<L|R>``; ``""`` for -1, no segment)."""
    names = np.where(index >= 0, segment_ids[np.maximum(index, 0)], "")
    way = np.array([n.split("-", 1)[0] for n in names])
    side = np.array([n.rsplit("-", 1)[-1] if n else "" for n in names])
    return way, side


def wrong_side_fixes(session_dir: Path, raster, segment_ids: np.ndarray) -> np.ndarray:
    """Boolean mask over ``gnss.csv``: the fix is across the walker's own street."""
    session = read_session(session_dir)
    fixes = session.gnss
    frame = LocalFrame(raster.crs)
    fx, fy = frame.to_xy(fixes["lon"].to_numpy(), fixes["lat"].to_numpy())
    tx, ty = groundtruth_at(session.waypoints, fixes["t"].to_numpy(float), frame)
    fix_way, fix_side = way_and_side(segment_ids, raster.segments_at(fx, fy))
    true_way, true_side = way_and_side(segment_ids, raster.segments_at(tx, ty))
    return (fix_way == true_way) & (fix_way != "") & (fix_side != true_side)


def true_velocity(session_dir: Path, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The walker's true east and north velocity (m/s) at times ``t``, from the surveyed path."""
    session = read_session(session_dir)
    frame = LocalFrame.around(float(session.waypoints["lon"].iat[0]), float(session.waypoints["lat"].iat[0]))
    x, y = groundtruth_at(session.waypoints, t, frame)
    return np.gradient(x, t), np.gradient(y, t)


def standing_at(t: np.ndarray, steps_t: np.ndarray) -> np.ndarray:
    """Whether no footstep falls within :data:`STANCE_GAP_S` of each time ``t``."""
    i = np.searchsorted(steps_t, t)
    since = np.where(i > 0, t - steps_t[np.maximum(i - 1, 0)], np.inf)
    until = np.where(i < len(steps_t), steps_t[np.minimum(i, len(steps_t) - 1)] - t, np.inf)
    return (since > STANCE_GAP_S) & (until > STANCE_GAP_S)


def step_length_factor(velocity: pd.DataFrame, steps_t: np.ndarray) -> np.ndarray:
    """Per velocity row: the factor that makes its footstep's length the running median of the last
    :data:`STEP_WINDOW` (causal; 1 outside steps and across pauses over 1.5 s)."""
    t = velocity["t"].to_numpy(float)
    speed = np.hypot(velocity["ve"], velocity["vn"]).to_numpy()
    walked = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    lengths = np.diff(np.interp(steps_t, t, walked))
    factor, recent = np.ones(len(lengths)), []
    for j in np.flatnonzero(np.diff(steps_t) < 1.5):
        recent = [*recent, lengths[j]][-STEP_WINDOW:]
        factor[j] = np.median(recent) / lengths[j] if lengths[j] > 1e-3 else 1.0
    k = np.searchsorted(steps_t, t) - 1  # the footstep interval of each row
    inside = (k >= 0) & (k < len(lengths))
    return np.where(inside, factor[np.clip(k, 0, max(len(lengths) - 1, 0))], 1.0)


def apply_oracle(source: Path, target: Path, oracle: str, raster, segment_ids: np.ndarray) -> str:
    """Write ``source``'s oracle version of its GNSS or velocity file into ``target``; say what changed."""
    if oracle == "wrong-side":
        wrong = wrong_side_fixes(source, raster, segment_ids)
        fixes = pd.read_csv(source / "gnss.csv")
        fixes[~wrong].to_csv(target / "gnss.csv", index=False)
        return f"{wrong.mean():.0%} of fixes across the walker's street"
    velocity = pd.read_csv(source / "velocity.csv")
    if oracle == "stance":
        steps_t = pd.read_csv(source / "steps.csv")["t"].to_numpy(float)
        standing = standing_at(velocity["t"].to_numpy(float), steps_t)
        velocity.loc[standing, ["ve", "vn"]] = 0.0
        change = f"velocity zeroed over {standing.mean():.0%} of the walk (no footstep near)"
    elif oracle == "step-length":
        steps_t = pd.read_csv(source / "steps.csv")["t"].to_numpy(float)
        factor = step_length_factor(velocity, steps_t)
        velocity[["ve", "vn"]] = velocity[["ve", "vn"]].mul(factor, axis=0)
        change = f"step lengths smoothed (factor {factor.min():.2f}-{factor.max():.2f})"
    elif oracle == "speed-scale":
        scale = read_session(source).meta["simulation"]["events"]["speed_scale"]
        velocity[["ve", "vn"]] /= scale
        change = f"velocity divided by {scale:.2f}"
    else:
        east, north = true_velocity(source, velocity["t"].to_numpy(float))
        true, inertial = east + 1j * north, velocity["ve"].to_numpy() + 1j * velocity["vn"].to_numpy()
        if oracle == "speed":  # the inertial direction at the true speed
            out = np.abs(true) * np.exp(1j * np.angle(inertial))
        elif oracle == "heading":  # the inertial speed in the true direction
            out = np.abs(inertial) * np.exp(1j * np.angle(true))
        else:
            out = true
        velocity["ve"], velocity["vn"] = out.real, out.imag
        change = {"speed": "true speed", "heading": "true direction"}.get(oracle, "true velocity")
    velocity.to_csv(target / "velocity.csv", index=False)
    return change


def oracle_copies(
    folders: dict[str, list[Path]], map_path: str, out: Path, oracle: str
) -> dict[str, list[Path]]:
    """Copies of every session under ``out`` with the oracle applied; prints what it changed."""
    config = MapConfig()
    raster = load_or_build_raster(read_map(map_path), config.raster_resolution_m, config.segment_reach_m)
    segment_ids = np.asarray(raster.segment_ids)
    copies: dict[str, list[Path]] = {}
    for subset, paths in folders.items():
        copies[subset] = []
        for path in paths:
            target = out / oracle / subset / path.name
            if target.exists():
                shutil.rmtree(target)
            shutil.copytree(path, target)
            change = apply_oracle(path, target, oracle, raster, segment_ids)
            copies[subset].append(target)
            print(f"{subset}/{path.name}: {change}")
    return copies


def resimulated(
    out: Path, split: str, subsets: list[str], settings: list[str], world
) -> dict[str, list[Path]]:
    """The same sessions simulated again with some phone velocity-error fields changed.

    Every error process is still drawn (times zero where switched off), so the walks, the fixes and the
    other inertial errors are the ones of the sessions as simulated.
    """
    fields = {key: float(value) for key, value in (item.split("=", 1) for item in settings)}
    config = SimulationConfig(profile="phone", velocity=PhoneVelocityErrorModel(**fields))
    return {sub: benchmark_sessions(out / sub, sub, split=split, seeds=3, world=world, config=config)
            for sub in subsets}


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", help="working folder (sessions, oracle copies)")
    parser.add_argument("--map", required=True, help="map GeoJSON (e.g. OUT/map.geojson)")
    parser.add_argument("--oracle", choices=ORACLES, default="wrong-side",
                        help="the error source to remove (module docstring; default: wrong-side)")
    parser.add_argument("--split", choices=("tune", "test"), default="tune",
                        help="an oracle chooses nothing, so it may bound the scored split too")
    parser.add_argument("--subsets", nargs="+", choices=SUBSETS, default=["paper6"],
                        help="benchmark subsets (default: paper6)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="filter seeds (default 0 1)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--velocity-set", nargs="+", default=[], metavar="FIELD=VALUE",
                        help="with --oracle resimulate: phone velocity-model fields to change, e.g. "
                             "scale_wander_sd=0")
    args = parser.parse_args(argv)
    if bool(args.velocity_set) != (args.oracle == "resimulate"):
        parser.error("--velocity-set goes with --oracle resimulate, and only with it")
    fields = {f.name for f in dataclasses.fields(PhoneVelocityErrorModel) if isinstance(f.default, float)}
    for item in args.velocity_set:
        key, _, value = item.partition("=")
        if key not in fields or not _is_number(value):
            parser.error(f"--velocity-set {item!r}: expected FIELD=NUMBER, FIELD one of {sorted(fields)}")
    out = Path(args.out)
    world = load_world()
    folders = {
        sub: benchmark_sessions(
            out / args.split / sub, sub, split=args.split, profile="phone", seeds=3, world=world
        )
        for sub in args.subsets
    }
    if args.oracle == "resimulate":
        copies = resimulated(out / "oracle" / args.split / "resimulate", args.split, args.subsets,
                             args.velocity_set, world)
    else:
        copies = oracle_copies(folders, args.map, out / "oracle" / args.split, args.oracle)
    variants = {"gnss": ["gnss", {}], "paper": ["paper", {}], "fused": ["fused", {}]}
    rows = []
    for label, which in (("as simulated", folders), (f"{args.oracle} oracle", copies)):
        pooled, _, _ = run(which, args.map, variants, tuple(args.seeds), args.workers)
        rows.append(pooled.assign(fixes=label))
    table = pd.concat(rows).pivot(index=["variant", "fixes"], columns="subset")
    pd.set_option("display.width", 200)
    print(table.round(3).to_string())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
