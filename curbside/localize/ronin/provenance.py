"""Where a RoNIN model and its figures came from: data files, weights, software.

Training and evaluation record their inputs by content (SHA-256), so a model's config, a prepared
cache and an evaluation report each say which files they were made from, and a prepared cache made
from other files than the ones named on the command line is refused instead of silently used.
"""

from __future__ import annotations

import hashlib
import json
import logging
import subprocess
from pathlib import Path

from curbside import __version__
from curbside.cache import content_key, file_digest
from curbside.errors import CurbsideInputError

logger = logging.getLogger(__name__)

#: The command-line option of each data source, in messages.
OPTIONS = {"ms": "--ms-indoor", "ipin": "--ipin", "ronin": "--ronin-h5"}


def source_records(ms_indoor: str | Path | None = None, ipin: str | Path | None = None,
                   ronin_dir: str | Path | None = None) -> list[dict]:
    """One record per given data source: its kind, path and SHA-256.

    Parameters
    ----------
    ms_indoor, ipin
        HDF5 files (``None``: not given).
    ronin_dir
        A folder of RoNIN-layout sequences; its digest covers every ``*/data.hdf5`` below it, by
        relative path and content.

    Returns
    -------
    list of dict
        ``{"source", "path", "sha256"}`` in the order ms, ipin, ronin.

    Raises
    ------
    CurbsideInputError
        A missing file or folder, a folder given for an HDF5 file, a file given for the folder, or a
        ``data.hdf5`` below it that is not a file.
    """
    records = []
    for source, path in (("ms", ms_indoor), ("ipin", ipin)):
        if path is not None:
            _check_h5_file(path, OPTIONS[source])
            records.append({"source": source, "path": str(Path(path).resolve()),
                            "sha256": file_digest(path).hex()})
    if ronin_dir is not None:
        root = Path(ronin_dir)
        files = ronin_sequence_files(root)
        parts = [part for f in files for part in (str(f.relative_to(root)), file_digest(f))]
        records.append({"source": "ronin", "path": str(root.resolve()), "sha256": content_key(*parts)})
    return records


def _check_h5_file(path: str | Path, option: str) -> None:
    """Refuse a missing HDF5 file, or a folder in its place, naming it."""
    if Path(path).is_dir():
        raise CurbsideInputError(path, f"is a folder; {option} takes an HDF5 file")
    if not Path(path).is_file():
        raise CurbsideInputError(path, f"no such file ({option})")


def ronin_sequence_files(root: str | Path) -> list[Path]:
    """The ``*/data.hdf5`` files of a folder of RoNIN-layout sequences, sorted.

    Raises
    ------
    CurbsideInputError
        ``root`` is missing or not a folder, holds no ``data.hdf5``, or one that is not a file.
    """
    root = Path(root)
    if not root.is_dir():
        problem = "is a file; --ronin-h5 takes the folder" if root.exists() else "no such folder"
        raise CurbsideInputError(root, f"{problem} (RoNIN layout: one folder per sequence, */data.hdf5)")
    files = sorted(root.rglob("data.hdf5"))
    if not files:
        raise CurbsideInputError(root, "no */data.hdf5 (RoNIN layout) below this folder")
    for path in files:
        if not path.is_file():
            raise CurbsideInputError(path, "is not a file (a RoNIN sequence's data.hdf5 is an HDF5 file)")
    return files


def _describe(records: list[dict]) -> str:
    return ", ".join(f"{OPTIONS.get(r['source'], r['source'])} {Path(r['path']).name} "
                     f"(sha256 {r['sha256'][:12]})" for r in records) or "no source recorded"


def check_prepared_sources(prepared: str | Path, stored: list[dict] | None, given: list[dict]) -> None:
    """Refuse a prepared cache made from other data than the sources given now.

    Parameters
    ----------
    prepared
        The cache file, for messages.
    stored
        The sources recorded in it (``None``: a cache from before they were recorded).
    given
        :func:`source_records` of the sources on the command line (empty: none given, the cache is
        used as it is).

    Raises
    ------
    CurbsideInputError
        The cache was made from other files (compared by kind and content, not by path).
    """
    if not given:
        return
    if stored is None:
        logger.warning("%s records no sources: it cannot be checked against %s; delete it to prepare "
                       "the data again", prepared, _describe(given))
        return
    key = sorted((r["source"], r["sha256"]) for r in given)
    if key != sorted((r["source"], r["sha256"]) for r in stored):
        raise CurbsideInputError(
            prepared, f"was prepared from {_describe(stored)}, not from {_describe(given)}: delete it "
            "or give another --prepared"
        )


def weights_record(path: str | Path) -> dict:
    """Path and SHA-256 of a weights file, and of the model fields of its JSON config.

    The config's ``extra`` (the training record: data, metrics, provenance) is left out of
    ``config_sha256``, so documenting how weights were made does not read as other weights when a run
    is replayed; a config that is not a JSON object is digested as it is.
    """
    path = Path(path)
    config = path.with_suffix(".json")
    return {"path": str(path.resolve()), "sha256": file_digest(path).hex(),
            "config_sha256": _config_digest(config) if config.is_file() else None}


#: The whole-file ``config_sha256`` of a shipped config in run.json files written before the record
#: digested the model fields alone (and before 3fdb898 added provenance to them), by the model-fields
#: digest of that file, which is the shipped config's now.
_EARLIER_SHIPPED_CONFIGS = {
    "918074a23c242bf16b8b67d18d5127a7f699ab1bfefd1c75ca5eb59515622d31":  # ronin_compact.json
        "0f9370c82d675d706a3de6623ccae0453b6d45d467f4486c3e6075b36a3f558c",
    "644f2f4c21a84bdfc7d0d9d6e43493ffdec288a303766c6dad859d351264347d":  # benchmarks' ronin_ms_only.json
        "fa8eef0d76fd3e9e4014b02659bc3e8ca25c855785f7338fd484be4106614a64",
}  # fmt: skip


def same_config(recorded_sha256: str | None, weights: str | Path) -> bool:
    """Whether a ``config_sha256`` that run.json recorded is that of the config beside ``weights`` now.

    Besides the model-fields digest of :func:`weights_record`, a run.json written before it holds the
    digest of the whole file: the same file, or a shipped config before its provenance was added.

    Parameters
    ----------
    recorded_sha256
        ``inputs.ronin_weights.config_sha256`` of a run.json.
    weights
        The weights ``.pt``; its config is the ``.json`` beside it.

    Returns
    -------
    bool
        ``False`` when the model fields differ, or the config is gone (and a digest was recorded).
    """
    config = Path(weights).with_suffix(".json")
    if not config.is_file():
        return recorded_sha256 is None
    fields = _config_digest(config)
    earlier = _EARLIER_SHIPPED_CONFIGS.get(str(recorded_sha256))
    return recorded_sha256 in (fields, file_digest(config).hex()) or earlier == fields


def _config_digest(config: Path) -> str:
    try:
        fields = json.loads(config.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        fields = None
    if not isinstance(fields, dict):
        return file_digest(config).hex()
    fields.pop("extra", None)
    canonical = json.dumps(fields, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(canonical.encode()).hexdigest()


def software_record() -> dict:
    """Versions of curbside, torch and numpy, and the git commit of the curbside checkout (``None``:
    not a git checkout, or no git)."""
    import numpy as np
    import torch

    return {"curbside": __version__, "torch": torch.__version__, "numpy": np.__version__,
            "git_commit": git_commit()}


def git_commit() -> str | None:
    """``HEAD`` of the git checkout curbside runs from (uncommitted changes are not seen), or ``None``."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True,
                             text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit if out.returncode == 0 and commit else None
