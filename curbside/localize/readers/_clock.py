"""The units and the continuity of a Sensor Logger export's clocks, checked before they are trusted.

``time`` must be nanoseconds since the UNIX epoch and ``seconds_elapsed`` seconds, as the app writes
them (:func:`check_time_unit`, :func:`check_elapsed`): a column re-saved by another program in other
units would otherwise convert silently into a recording 1e9 times too long or 1000 times too short.
And a stream's rows may come a few samples out of order (sorted later), but not step back in time as
after the phone's clock was set back during the recording (:func:`check_clock_steps`).
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.localize.readers._tidy import clock_step, refuse_text, written

logger = logging.getLogger(__name__)


#: ``|time|`` of a Sensor Logger row, read as ns since the UNIX epoch, lies in this range (1973 to 2286).
EPOCH_NS_RANGE = (1e17, 1e19)


def check_time_unit(table: pd.DataFrame, source: str) -> None:
    """Raise unless ``time`` reads as nanoseconds since the UNIX epoch, as the app writes it.

    The median ``|time|`` tells the unit: today 1.7e18 in ns, 1.7e15 in microseconds, 1.7e12 in
    milliseconds, 1.7e9 in seconds (a column re-saved by another program). A table without numbers in
    ``time`` is left to the clock's other checks.

    Parameters
    ----------
    table
        One CSV of the export, as read.
    source
        The file, for the message.

    Raises
    ------
    CurbsideInputError
        The median ``|time|`` lies outside :data:`EPOCH_NS_RANGE`; the message names the unit it reads as.
    """
    values = pd.to_numeric(table.get("time", pd.Series(dtype=float)), errors="coerce").to_numpy(float)
    values = np.abs(values[np.isfinite(values)])
    if not len(values):
        return
    median = float(np.median(values))
    low, high = EPOCH_NS_RANGE
    if low <= median < high:
        return
    scales = {1e-9: "seconds", 1e-6: "milliseconds", 1e-3: "microseconds"}
    unit = next((name for scale, name in scales.items() if low <= median / scale < high), None)
    reads = f"reads as {unit} since the epoch" if unit else "is no epoch time"
    raise CurbsideInputError(source, f"'time' is not in nanoseconds since the UNIX epoch, as Sensor Logger "
                             f"writes it: its median {median:.3g} {reads} (re-saved by another program?)")


def check_elapsed(table: pd.DataFrame, source: str) -> None:
    """Raise unless ``seconds_elapsed`` advances as ``time`` (ns) does: in seconds.

    Parameters
    ----------
    table
        One CSV of the export, as read (its ``time`` checked by :func:`check_time_unit`).
    source
        The file, for the message.

    Raises
    ------
    CurbsideInputError
        ``seconds_elapsed`` spans less than half or more than twice the seconds ``time`` spans.
    """
    if not {"time", "seconds_elapsed"} <= set(table.columns):
        return
    both = pd.DataFrame({"ns": pd.to_numeric(table["time"], errors="coerce"),
                         "s": pd.to_numeric(table["seconds_elapsed"], errors="coerce")}).dropna()
    span_s = (both["ns"].max() - both["ns"].min()) / 1e9
    if len(both) < 2 or not span_s > 0:
        return
    ratio = float((both["s"].max() - both["s"].min()) / span_s)
    if 0.5 <= ratio <= 2.0:
        return
    scales = {1e3: "milliseconds", 1e6: "microseconds", 1e9: "nanoseconds"}
    unit = next((name for scale, name in scales.items() if 0.5 <= ratio / scale <= 2.0), "another unit")
    raise CurbsideInputError(source, f"'seconds_elapsed' is not in seconds: it spans {ratio:.3g} times what "
                             f"'time' does ({span_s:.1f} s; {unit}?)")


def check_clock_steps(table: pd.DataFrame, source: str, warn_only: bool) -> None:
    """Refuse (``warn_only``: warn about) a block of rows set back in time: the phone's clock stepped back.

    Sensor Logger's times come from the system clock (the app's references say their accuracy relies on
    it, and its optional NTP offset is refreshed every 3 hours); a few rows handed over late, or a block
    of older rows reported late (samples buffered before the start tap), are sorted
    (:func:`~._tidy.tidy_table`), but after a clock step the samples of two stretches of time would
    interleave, or the later stretch come first, once sorted (:func:`~._tidy.clock_step_back`). Exact
    duplicates (cached samples reported twice, dropped later) are not judged.

    Parameters
    ----------
    table
        One CSV of the export, in file order, with ``t`` (s) added.
    source
        The file, for the message.
    warn_only
        Log a WARNING instead of raising (``Location.csv``: a fix out of place costs less than the
        recording, and fixes come at irregular intervals).

    Raises
    ------
    CurbsideInputError
        Unless ``warn_only``: the rows step back in time as after the clock was set back
        (:func:`~._tidy.clock_step_back`).
    """
    t = pd.to_numeric(table["t"], errors="coerce").to_numpy(float)
    step = clock_step(np.where(table.drop(columns="t").duplicated().to_numpy(), np.nan, t))
    if step is None:
        return
    row, back_s, before = step
    clock = clock_column(table)
    now, then = written(table[clock].iat[row]), written(table[clock].iat[before])
    message = (f"time goes back {back_s:.2f} s at data row {row + 1} ({clock!r} {now} after {then} at data "
               f"row {before + 1}): the phone's clock was set back during the recording, and once sorted the "
               "rows after it would interleave with, or precede, those before")
    if warn_only:
        logger.warning("%s: %s; sorted in anyway", source, message)
        return
    raise CurbsideInputError(source, f"{message}; cut the recording there")


def clock_column(table: pd.DataFrame) -> str:
    """The column a table's ``t`` comes from: ``seconds_elapsed``, else (export format 2) ``time``."""
    return "seconds_elapsed" if "seconds_elapsed" in table.columns else "time"


def refuse_clock_text(table: pd.DataFrame, source: str) -> None:
    """Raise when ``time`` or ``seconds_elapsed`` holds text (``abc``, ``N/A``); a blank cell passes (its row
    is dropped later), so does a table without them.

    Raises
    ------
    CurbsideInputError
        ``non-numeric value 'abc' in column 'time' at data row 3`` for the first such cell.
    """
    refuse_text(table, ("time", "seconds_elapsed"), source)
