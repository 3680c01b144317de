"""What ``localize run`` records in ``run.json`` about its inputs, and what a replay checks against it.

``run.json`` holds every parameter, so ``localize run --config run.json`` repeats a run byte for byte,
but only on the same inputs. The run records a SHA-256 of each session file it could read, of the map
and, when RoNIN made the velocity, of the weights and their config (``inputs``); a replay recomputes them
and warns when any differs, naming the files, since its track will then differ from the recorded one. A
replay runs RoNIN with the weights the run used (``localize run --ronin-weights``; the bundled model's,
as installed now, when the run used it), and stops with an error naming them when they are gone. A replay
also
keeps the velocity source the run resolved (``velocity_source``: a run under ``auto`` that read
``velocity.csv`` is replayed from ``velocity.csv``, and fails clearly when the file is gone, rather than
quietly running RoNIN) and ``--save-particles``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

from curbside import settings
from curbside.errors import CurbsideInputError

if TYPE_CHECKING:
    from curbside.localize.runconfig import RunConfig

logger = logging.getLogger(__name__)


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes, as hex."""
    from curbside.cache import file_digest

    return file_digest(path).hex()


def input_record(session_path: str, map_path: str | None) -> dict[str, Any]:
    """``run.json``'s ``inputs``: SHA-256 of the session's files and of the map (see :func:`add_weights`).

    Parameters
    ----------
    session_path
        A session folder (the files in it, a Sensor Logger export's CSVs included; not its sub-folders,
        which may hold runs, nor hidden files such as the output marker), or a recording file
        (``FILE.h5::TRIAL``, a Sensor Logger zip, a GPX file).
    map_path
        The map, if any.
    """
    source = Path(str(session_path).partition("::")[0])
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.is_file() and not p.name.startswith("."))
        session = {p.name: file_sha256(p) for p in files}
    else:
        session = {source.name: file_sha256(source)} if source.is_file() else {}
    record: dict[str, Any] = {"session_sha256": session}
    if map_path:
        record["map_sha256"] = file_sha256(map_path)
    return record


def ronin_weights_record(weights: str | Path | None) -> dict[str, Any]:
    """``run.json``'s record of RoNIN weights (default: the bundled ones): path, SHA-256 of the weights
    and of their config, and whether they are the bundled model's."""
    from curbside.localize.ronin.provenance import weights_record

    bundled = Path(settings.ronin_default_weights).resolve()
    path = Path(weights or bundled)
    return {**weights_record(path), "bundled": path.resolve() == bundled}


def add_weights(record: dict[str, Any], velocity_source: str | None,
                weights: str | Path | None = None) -> dict[str, Any]:
    """``record`` with the RoNIN weights' record (:func:`ronin_weights_record`; default: the bundled
    ones) when RoNIN made the run's velocity."""
    if velocity_source != "ronin":
        return record
    return {**record, "ronin_weights": ronin_weights_record(weights)}


def recorded_weights(info: dict[str, Any], run_json: str) -> str | None:
    """The RoNIN weights a replay runs with: those ``run.json`` records, ``None`` for the bundled model
    (as installed now: a run.json from another installation names another path for it).

    Raises
    ------
    CurbsideInputError
        The recorded weights, or their config, are gone.
    """
    inputs = info.get("inputs")
    record = inputs.get("ronin_weights") if isinstance(inputs, dict) else None
    if not isinstance(record, dict) or record.get("bundled", True):  # earlier run.json: always bundled
        return None
    path = str(record.get("path"))
    for file in (Path(path), Path(path).with_suffix(".json")):
        if not file.is_file():
            raise CurbsideInputError(
                file, f"no such file (the RoNIN weights {run_json} was run with; give where they are now: "
                "--ronin-weights PT, with its .json beside it)"
            )
    return path


def changed_inputs(recorded: dict[str, Any], now: dict[str, Any], map_path: str | None,
                   weights: str | Path | None = None) -> list[str]:
    """The inputs whose bytes differ between ``recorded`` (``run.json``'s ``inputs``) and ``now``, the
    RoNIN weights being ``weights`` (default: the bundled ones)."""
    before, after = recorded.get("session_sha256", {}), now["session_sha256"]
    changed = [name for name in sorted(set(before) | set(after)) if before.get(name) != after.get(name)]
    if recorded.get("map_sha256") != now.get("map_sha256"):
        changed.append(f"the map {map_path}" if map_path else "the map (none now)")
    if "ronin_weights" in recorded:
        from curbside.localize.ronin.provenance import same_config

        was, used = recorded["ronin_weights"], ronin_weights_record(weights)
        # earlier run.json: no config, or the whole config file's digest
        other_config = "config_sha256" in was and not same_config(was["config_sha256"], used["path"])
        if ("sha256" in was and was["sha256"] != used["sha256"]) or other_config:
            changed.append(f"the RoNIN weights {used['path']}")
    return changed


def replay_config(info: dict[str, Any], config: RunConfig, run_json: str, mode: str | None,
                  velocity_source: str | None) -> RunConfig:
    """The configuration of a replay: the recorded one, its resolved velocity source kept.

    Raises
    ------
    CurbsideInputError
        ``mode`` differs from the recorded run's: the parameters are that mode's, not ``mode``'s.
    """
    if mode is not None and mode != config.mode:
        raise CurbsideInputError(
            "--mode", f"{mode} with --config: {run_json} holds a {config.mode} run's parameters; run --mode "
            f"{mode} without --config (with --set for what you would keep)"
        )
    resolved = info.get("velocity_source")
    unpinned = velocity_source is None and config.engine.velocity_source == "auto"
    if unpinned and resolved in ("file", "ronin", "pdr"):
        config = config.with_overrides({"engine.velocity_source": resolved})
    return config


def check_replayed_paths(
    info: dict[str, Any], run_json: str, session_path: str, map_path: str | None
) -> None:
    """Raise when a path ``run.json`` names, and the replay uses, is gone (before the input is read)."""
    for key, option in (("session", "SESSION"), ("map", "--map MAP")):
        path = info.get(key)
        if path and path in (session_path, map_path) and not Path(str(path).partition("::")[0]).exists():
            raise CurbsideInputError(
                path, f"no such file or folder (the {key} {run_json} names; give where it is now: {option})"
            )


def check_replayed_inputs(
    info: dict[str, Any], run_json: str, map_path: str | None, now: dict[str, Any],
    weights: str | Path | None = None,
) -> None:
    """Warn when an input's bytes differ from ``now`` (:func:`input_record` of the replay's inputs) or
    from ``weights`` (the RoNIN weights of the replay; default: the bundled ones) since the run."""
    recorded = info.get("inputs")
    if not isinstance(recorded, dict):
        return  # written before run.json recorded its inputs
    changed = changed_inputs(recorded, now, map_path, weights)
    if changed:
        logger.warning("%s: replaying on inputs that changed since the run (%s): the track will differ from "
                       "the recorded one", run_json, ", ".join(changed))
