"""The files of one Sensor Logger recording, from a ``.zip`` or a folder tree, and their clocks.

A recording is the set of CSV files in one folder of the zip or tree that holds at least one of the
export's motion or location files (:data:`MARKERS`). Two recordings in one source (a zip of two
exports, a folder of several days) are never mixed: the source is refused with their names unless
one is chosen as ``SRC::NAME``. Recording names are compared and listed in Unicode NFC, the form a
keyboard types: macOS stores ``ü`` in zips and folders decomposed (``u`` + combining diaeresis, NFD),
which looks the same but would not match the name typed. macOS archive debris (``__MACOSX/``, ``._*``
resource forks) and hidden files are skipped. A CSV re-saved by a spreadsheet with ``;`` separators
(and decimal commas) is read as such, with a warning. Only an empty cell (or ``NaN``) is blank: pandas
would read ``N/A`` or ``null`` as blank too, and a position or time holding them would be dropped
without a word rather than refused as text (:data:`~._tidy.BLANK_CELLS`).

Clocks. Every CSV has ``time`` (ns since the UNIX epoch) and, since export format 3,
``seconds_elapsed`` (s since the start tap). Format-2 exports (2021) have ``time`` only; there the
streams are put on one clock by subtracting a common start, and :func:`check_same_clock` verifies on
``time`` that every stream overlaps the reference stream, which also catches files of two recordings
copied into one folder (their ``seconds_elapsed`` both start near 0; only ``time`` tells them apart).
"""

from __future__ import annotations

import io
import logging
import shlex
import unicodedata
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.localize.readers._tidy import BLANK_CELLS

logger = logging.getLogger(__name__)

#: Files whose presence marks a folder as a Sensor Logger recording (lower-case names).
MARKERS = (
    "accelerometer.csv",
    "totalacceleration.csv",
    "gyroscope.csv",
    "location.csv",
    "orientation.csv",
    "gravity.csv",
    "accelerometeruncalibrated.csv",
    "gyroscopeuncalibrated.csv",
)

#: Separator between a zip or folder and the recording inside it: ``export.zip::2023-06-14_10-00-00``.
RECORDING_SEPARATOR = "::"

#: Streams further apart than this (s) on the ``time`` clock come from different recordings or clocks.
SAME_CLOCK_TOLERANCE_S = 10.0


def _skipped(parts: tuple[str, ...]) -> bool:
    return any(p == "__MACOSX" or p.startswith(".") for p in parts)


def _nfc(name: str) -> str:
    """``name`` in Unicode NFC (composed ``ü``), as typed; macOS names files in NFD (``u`` + ``\u0308``)."""
    return unicodedata.normalize("NFC", name)


def _group(src: Path, names: list[tuple[PurePosixPath, object]]) -> dict[str, dict[str, object]]:
    """Group ``(relative path, handle)`` CSV entries of ``src`` by folder (its name in NFC); keep folders
    holding a marker file.

    Raises
    ------
    CurbsideInputError
        Two folders whose names differ only in their Unicode form (their files would mix).
    """
    folders: dict[str, dict[str, object]] = {}
    spelt: dict[str, set[str]] = {}
    for rel, handle in names:
        if rel.suffix.lower() != ".csv" or _skipped(rel.parts):
            continue
        key = _nfc(rel.parent.as_posix())
        spelt.setdefault(key, set()).add(rel.parent.as_posix())
        folders.setdefault(key, {}).setdefault(_nfc(rel.name.lower()), handle)
    twice = sorted(k for k, forms in spelt.items() if len(forms) > 1 and k in folders)
    if twice:
        raise CurbsideInputError(src, f"holds two folders named {twice[0]!r} that differ only in how their "
                                 "letters are encoded (NFC and NFD Unicode); rename one")
    return {k: files for k, files in folders.items() if any(m in files for m in MARKERS)}


def find_recordings(src: Path) -> dict[str, dict[str, object]]:
    """Recordings in a zip or a folder tree, by folder (``"."`` for the top level).

    Parameters
    ----------
    src
        A ``.zip`` file or a folder.

    Returns
    -------
    dict
        ``{folder: {lower-case file name: Path or zip member name}}``.

    Raises
    ------
    CurbsideInputError
        ``src`` is missing or an unreadable zip.
    """
    if src.is_dir():
        entries = [(PurePosixPath(p.relative_to(src).as_posix()), p) for p in src.rglob("*") if p.is_file()]
        return _group(src, entries)
    if src.is_file():
        try:
            with zipfile.ZipFile(src) as zf:
                entries = [
                    (PurePosixPath(i.filename.replace("\\", "/")), i.filename)  # zips made on Windows
                    for i in zf.infolist()
                    if not i.is_dir()
                ]
        except (zipfile.BadZipFile, OSError) as exc:
            raise CurbsideInputError(src, f"unreadable zip ({exc})") from None
        return _group(src, entries)
    raise CurbsideInputError(src, "no such file or folder")


def _inner_zips(src: Path) -> list[str]:
    """Names of the ``.zip`` files inside a zip (a zip of exports, not yet unpacked)."""
    if not zipfile.is_zipfile(src):
        return []
    with zipfile.ZipFile(src) as zf:
        names = [PurePosixPath(n.replace("\\", "/")).name for n in zf.namelist()]
    return sorted(n for n in names if n.lower().endswith(".zip"))


def require_recordings(src: Path) -> dict[str, dict[str, object]]:
    """:func:`find_recordings`, refusing a source that holds none.

    Raises
    ------
    CurbsideInputError
        ``src`` is missing, an unreadable zip, or holds no recording (a zip of zips says so).
    """
    recordings = find_recordings(src)
    if recordings:
        return recordings
    inner = _inner_zips(src) if src.is_file() else []
    if inner:
        raise CurbsideInputError(src, f"not a Sensor Logger export: it holds zip files ({', '.join(inner)}), "
                                 "not CSVs; unpack them and give the folder, or give each zip")
    raise CurbsideInputError(
        src, "not a Sensor Logger export (no Accelerometer/Gyroscope/Orientation/Location CSV in it)"
    )


def split_recording(src: str | Path) -> tuple[Path, str | None]:
    """Split ``SRC::NAME`` into the zip or folder and the recording name (``None`` without ``::``)."""
    text = str(src)
    if RECORDING_SEPARATOR in text:
        path, name = text.rsplit(RECORDING_SEPARATOR, 1)
        return Path(path), _nfc(name.strip("/")) or "."
    return Path(text), None


def _choose(src: Path, name: str | None, recordings: dict[str, dict[str, object]]) -> str:
    if name is None:
        if len(recordings) == 1:
            return next(iter(recordings))
        listed = ", ".join("(top level)" if k == "." else k for k in sorted(recordings))
        example = sorted(recordings)[0]
        raise CurbsideInputError(
            src,
            f"holds {len(recordings)} recordings ({listed}); pick one as "
            f"{shlex.quote(f'{src}{RECORDING_SEPARATOR}{example}')}",
        )
    if name in recordings:
        return name
    by_leaf = [k for k in recordings if PurePosixPath(k).name == name]
    if len(by_leaf) == 1:
        return by_leaf[0]
    known = ", ".join(sorted(recordings))
    raise CurbsideInputError(f"{src}{RECORDING_SEPARATOR}{name}", f"no such recording; it holds: {known}")


def _looks_like_phyphox(header: str) -> bool:
    return '"Time (s)"' in header or header.startswith("Time (s)")


def _separators(data: bytes) -> tuple[str, str]:
    """Field separator and decimal mark: ``(",", ".")``, or ``(";", ",")`` for a file re-saved by a
    spreadsheet in a locale whose decimal mark is the comma (``(";", ".")`` if its numbers kept dots)."""
    lines = data[:4096].decode("utf-8", errors="replace").lstrip("\ufeff").splitlines()
    if not lines or ";" not in lines[0] or "," in lines[0]:
        return ",", "."
    return ";", ("," if any("," in line for line in lines[1:6]) else ".")


def _decimal_commas(table: pd.DataFrame) -> pd.DataFrame:
    """The cells of a decimal-comma file that pandas left as text (``0,0103``: a text cell in their
    column kept it from converting) as numbers, so that the text cell is the one an error names. Tap
    notes (``text``) are left as written."""
    for column in table.columns:
        if column != "text" and not pd.api.types.is_numeric_dtype(table[column]):
            cells = table[column].astype(object)
            dotted = pd.to_numeric(cells.map(lambda v: v.replace(",", ".") if isinstance(v, str) else v),
                                   errors="coerce")
            table[column] = cells.where(dotted.isna(), dotted)
    return table


@dataclass
class Export:
    """The CSV files of one recording, readable by name.

    Attributes
    ----------
    src
        The zip or folder it came from.
    folder
        The recording's folder inside ``src`` (``"."`` for the top level).
    label
        How errors and logs name it: ``src`` or ``src::folder``.
    """

    src: Path
    folder: str
    label: str
    _files: dict[str, object] = field(default_factory=dict, repr=False)
    _told_separators: bool = field(default=False, repr=False)

    @property
    def name(self) -> str:
        """A session name: the recording's folder, else the file or folder name of ``src``."""
        if self.folder != ".":
            return PurePosixPath(self.folder).name
        return self.src.stem if self.src.is_file() else self.src.name

    def has(self, name: str) -> bool:
        """Whether the recording has the file ``name`` (case-insensitive)."""
        return name.lower() in self._files

    def source(self, name: str) -> str:
        """How messages name the recording's file ``name``: as the user finds it, its path on disk or
        inside the zip (``export.zip/2023-11-14_22-13-20/Gyroscope.csv``)."""
        handle = self._files.get(name.lower())
        if handle is None:
            return f"{self.label}/{name}"
        return str(handle) if isinstance(handle, Path) else f"{self.src}/{handle}"

    def _bytes(self, name: str) -> bytes:
        handle = self._files[name.lower()]
        if isinstance(handle, Path):
            return handle.read_bytes()
        with zipfile.ZipFile(self.src) as zf:
            return zf.read(str(handle))

    def read(self, name: str) -> pd.DataFrame | None:
        """Read ``name`` as a table: ``None`` when absent, an empty table when the file has no rows.

        Raises
        ------
        CurbsideInputError
            The file is not CSV, or is a phyphox export rather than Sensor Logger's.
        """
        if not self.has(name):
            return None
        source = self.source(name)
        data = self._bytes(name)
        if _looks_like_phyphox(data[:200].decode("utf-8", errors="replace")):
            raise CurbsideInputError(source, "is a phyphox export ('Time (s)' columns), not Sensor Logger's")
        sep, decimal = _separators(data)
        if sep != "," and not self._told_separators:
            self._told_separators = True  # one line per export, not per file
            commas = " and decimal commas" if decimal == "," else ""
            logger.warning("%s uses ';' separators%s (re-saved by a spreadsheet?); read as such, and so is "
                           "any other such file of %s", source, commas, self.label)
        try:
            table = pd.read_csv(io.BytesIO(data), skipinitialspace=True, sep=sep, decimal=decimal,
                                keep_default_na=False, na_values=list(BLANK_CELLS))
        except pd.errors.EmptyDataError:
            return pd.DataFrame()
        except (pd.errors.ParserError, UnicodeDecodeError) as exc:
            raise CurbsideInputError(source, f"malformed CSV ({str(exc).splitlines()[0]})") from None
        table.columns = [str(c).strip() for c in table.columns]
        return _decimal_commas(table) if decimal == "," else table


def open_export(src: str | Path) -> Export:
    """Open the one recording in ``src`` (a zip or folder, optionally ``SRC::NAME``).

    Raises
    ------
    CurbsideInputError
        Missing or unreadable source, no recording in it, several recordings and none named, or an
        unknown name.
    """
    path, name = split_recording(src)
    recordings = require_recordings(path)
    folder = _choose(path, name, recordings)
    label = str(path) if len(recordings) == 1 and name is None else f"{path}{RECORDING_SEPARATOR}{folder}"
    return Export(src=path, folder=folder, label=label, _files=recordings[folder])


def epoch_s(table: pd.DataFrame) -> np.ndarray | None:
    """The ``time`` column as UNIX seconds, or ``None`` when the table has no usable ``time``."""
    if "time" not in table.columns:
        return None
    values = pd.to_numeric(table["time"], errors="coerce").to_numpy(float)
    return values / 1e9 if np.isfinite(values).any() else None


def check_same_clock(streams: dict[str, pd.DataFrame], reference: str, label: str) -> None:
    """Raise unless every stream's ``time`` span overlaps the reference stream's (within a tolerance).

    Parameters
    ----------
    streams
        Tables by file name, as read (with ``time`` in ns where the export has it).
    reference
        The file whose span the others must overlap (the accelerometer's when there is one).
    label
        The export, for the message.

    Raises
    ------
    CurbsideInputError
        Two streams lie apart in time: two recordings mixed in one folder, or different clocks.
    """
    ref = epoch_s(streams[reference])
    if ref is None:
        return
    r0, r1 = np.nanmin(ref), np.nanmax(ref)
    for name, table in streams.items():
        t = epoch_s(table)
        if name == reference or t is None:
            continue
        t0, t1 = np.nanmin(t), np.nanmax(t)
        if t1 < r0 - SAME_CLOCK_TOLERANCE_S or t0 > r1 + SAME_CLOCK_TOLERANCE_S:
            gap_s = max(r0 - t1, t0 - r1)
            gap = f"{gap_s / 86400:.1f} days" if gap_s > 86400 else f"{gap_s:.0f} s"
            raise CurbsideInputError(
                label,
                f"{name} and {reference} do not overlap in time ({gap} apart on their 'time' clock): "
                "files of different recordings, or different clocks",
            )
