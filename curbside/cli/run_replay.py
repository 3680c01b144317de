"""What ``localize run`` records in ``run.json`` about its inputs, and what a replay checks against it.

``run.json`` holds every parameter, so ``localize run --config run.json`` repeats a run byte for byte,
but only on the same inputs. The run records a SHA-256 of each session file it could read, of the map
and, when RoNIN made the velocity, of the weights (``inputs``); a replay recomputes them and warns when
any differs, naming the files, since its track will then differ from the recorded one. A replay also
keeps the velocity source the run resolved (``velocity_source``: a run under ``auto`` that read
``velocity.csv`` is replayed from ``velocity.csv``, and fails clearly when the file is gone, rather than
quietly running RoNIN) and ``--save-particles``.
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path
from typing import Any

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import COLUMNS

logger = logging.getLogger(__name__)

#: The files of a session folder a run reads.
SESSION_FILES = tuple(f"{kind}.csv" for kind in COLUMNS) + ("meta.json",)


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes, as hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def input_record(session_path: str, map_path: str | None, velocity_source: str | None) -> dict[str, Any]:
    """``run.json``'s ``inputs``: SHA-256 of the session's files, the map and the RoNIN weights used.

    Parameters
    ----------
    session_path
        A session folder, or a recording file (``FILE.h5::TRIAL``, a Sensor Logger zip, a GPX file).
    map_path
        The map, if any.
    velocity_source
        What made the run's velocity (``file``, ``ronin``, ``pdr``); the weights are recorded for ``ronin``.
    """
    source = Path(str(session_path).partition("::")[0])
    if source.is_dir():
        session = {name: file_sha256(source / name) for name in SESSION_FILES if (source / name).is_file()}
    else:
        session = {source.name: file_sha256(source)} if source.is_file() else {}
    record: dict[str, Any] = {"session_sha256": session}
    if map_path:
        record["map_sha256"] = file_sha256(map_path)
    if velocity_source == "ronin":
        weights = Path(settings.ronin_default_weights)
        record["ronin_weights"] = {"path": str(weights), "sha256": file_sha256(weights)}
    return record


def changed_inputs(recorded: dict[str, Any], session_path: str, map_path: str | None) -> list[str]:
    """The inputs whose bytes differ from those ``recorded`` (``run.json``'s ``inputs``)."""
    now = input_record(session_path, map_path, "ronin" if "ronin_weights" in recorded else None)
    before, after = recorded.get("session_sha256", {}), now["session_sha256"]
    changed = [name for name in sorted(set(before) | set(after)) if before.get(name) != after.get(name)]
    if recorded.get("map_sha256") != now.get("map_sha256"):
        changed.append(f"the map {map_path}" if map_path else "the map (none now)")
    if "ronin_weights" in recorded and recorded["ronin_weights"]["sha256"] != now["ronin_weights"]["sha256"]:
        changed.append(f"the RoNIN weights {now['ronin_weights']['path']}")
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


def check_replayed_inputs(
    info: dict[str, Any], run_json: str, session_path: str, map_path: str | None
) -> None:
    """Raise when a path ``run.json`` names is gone; warn when an input's bytes changed since the run."""
    for key, option in (("session", "SESSION"), ("map", "--map MAP")):
        path = info.get(key)
        if path and path in (session_path, map_path) and not Path(str(path).partition("::")[0]).exists():
            raise CurbsideInputError(
                path, f"no such file or folder (the {key} {run_json} names; give where it is now: {option})"
            )
    recorded = info.get("inputs")
    if not isinstance(recorded, dict):
        return  # written before run.json recorded its inputs
    changed = changed_inputs(recorded, session_path, map_path)
    if changed:
        logger.warning("%s: replaying on inputs that changed since the run (%s): the track will differ from "
                       "the recorded one", run_json, ", ".join(changed))
