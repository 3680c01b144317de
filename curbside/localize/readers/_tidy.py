"""What every foreign-format reader does before handing a table to the session model.

Foreign logs are messy in known ways: rows out of time order, exact duplicates written twice, NaN
rows from a sensor that was not ready. These are repaired (sorted, de-duplicated, dropped) and
counted in the log; anything that cannot be repaired (a missing column, text where a number should
be, no rows left, repeated timestamps carrying different values, a value out of its range) raises
:class:`~curbside.errors.CurbsideInputError`. Those errors speak of the user's file, not of the
session: the readers rename its columns to session names (``y`` of ``Gyroscope.csv`` becomes ``gy``)
and hand :func:`tidy_table` the way back (``names``), so a message quotes the file's own header and
the row where the cell is, as a user searching the file finds them.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from os import PathLike

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.localize.session import MAX_GYRO_RADS, STANDARD_GRAVITY, acceleration_unit, non_numeric_value

logger = logging.getLogger(__name__)

#: Cells of a foreign CSV read as blank (no value): empty, or NaN as programs print it. Any other cell
#: that is not a number (``N/A``, ``null``, ``abc``) is text, refused where a number should be; give
#: these to :func:`pandas.read_csv` as ``na_values`` with ``keep_default_na=False`` (pandas would
#: otherwise read ``N/A`` and ``null`` as blanks too).
BLANK_CELLS = ("", "NaN", "nan", "NAN", "-NaN", "-nan")

#: Session columns whose magnitude is bounded: ``{column: (bound, what a larger value is)}``.
_LIMITS = {
    "lat": (90.0, "outside -90..90 (degrees of latitude)"),
    "lon": (180.0, "outside -180..180 (degrees of longitude)"),
    **{axis: (MAX_GYRO_RADS, f"outside -{MAX_GYRO_RADS:g}..{MAX_GYRO_RADS:g} rad/s: rotation rates must be "
              "in rad/s (deg/s?)") for axis in ("gx", "gy", "gz")},
}


def refuse_text(table: pd.DataFrame, columns: Sequence[str], source: str | PathLike[str],
                names: Mapping[str, str] | None = None) -> None:
    """Raise when a cell of ``columns`` holds text that is not a number; blank cells pass.

    Parameters
    ----------
    table
        The table as read, its integer index numbering the file's data rows from 0.
    columns
        Columns to check; those the table lacks are skipped.
    source
        The file, named in the message.
    names
        The file's own name of each column (session name -> header), for the message.

    Raises
    ------
    CurbsideInputError
        ``non-numeric value 'N/A' in column 'latitude' at data row 3``: the first such cell, row by row,
        in the file's words (data rows counted from 1 after the header).
    """
    present = [c for c in columns if c in table.columns]
    try:
        table[present].apply(pd.to_numeric, errors="raise")
    except (ValueError, TypeError):
        names = names or {}
        own = table[present].rename(columns=names)
        raise CurbsideInputError(source, non_numeric_value(own, [names.get(c, c) for c in present])) from None


def written(value: object) -> str:
    """A cell as a file writes it: a float in its shortest form (an ns epoch ``time`` in whole digits)."""
    if isinstance(value, float):  # numpy's too
        value = float(value)
        return f"{value:.0f}" if value.is_integer() and abs(value) >= 1e15 else repr(value)
    return str(value)


def _cell(table: pd.DataFrame, out: pd.DataFrame, column: str, index, own: str) -> str:
    """A value as the source writes it: its own cell when ``table`` holds that column, else the number."""
    return written(table.at[index, own] if own in table.columns else out.at[index, column])


def _check_limits(table: pd.DataFrame, out: pd.DataFrame, source: str | PathLike[str],
                  names: Mapping[str, str], rows: str) -> None:
    """Raise at the first value beyond its :data:`_LIMITS` bound, named as the source names it."""
    bounded = [c for c in out.columns if c in _LIMITS]
    if not bounded:
        return
    beyond = out[bounded].abs().to_numpy() > np.array([_LIMITS[c][0] for c in bounded])
    if beyond.any():
        position, k = np.argwhere(beyond)[0]
        column, index = bounded[k], out.index[position]
        value = _cell(table, out, column, index, names.get(column, column))
        raise CurbsideInputError(source, f"{names.get(column, column)!r} = {value} at {rows} {index + 1} is "
                                 f"{_LIMITS[column][1]}")


def _refuse_infinite(table: pd.DataFrame, out: pd.DataFrame, source: str | PathLike[str],
                     names: Mapping[str, str], rows: str) -> None:
    """Raise at the first infinite value (a sensor or a tool wrote ``inf``), named as the source names it."""
    infinite = np.isinf(out.to_numpy())
    if infinite.any():
        position, k = np.argwhere(infinite)[0]
        column, index = out.columns[k], out.index[position]
        own = names.get(column, column)
        raise CurbsideInputError(source, f"{own!r} = {_cell(table, out, column, index, own)} at {rows} "
                                 f"{index + 1} is not a finite number")


def _refuse_conflicts(table: pd.DataFrame, out: pd.DataFrame, source: str | PathLike[str],
                      names: Mapping[str, str], rows: str) -> None:
    """Raise when two rows share a timestamp with different values (``out``: sorted, no exact duplicates)."""
    same_t = out["t"].duplicated(keep=False).to_numpy()
    if not same_t.any():
        return
    first, second = out.index[np.flatnonzero(same_t)[:2]]
    clock = names.get("t", "t")
    value = _cell(table, out, "t", first, clock)
    raise CurbsideInputError(source, f"conflicting rows share timestamp {clock}={value}: {rows} {first + 1} "
                             f"and {rows} {second + 1} hold different values")


def tidy_table(
    table: pd.DataFrame,
    source: str | PathLike[str],
    required: list[str] | tuple[str, ...],
    nullable: tuple[str, ...] = (),
    names: Mapping[str, str] | None = None,
    rows: str = "data row",
) -> pd.DataFrame:
    """Sort by ``t``, drop exact duplicates and NaN rows, and check what is left.

    Parameters
    ----------
    table
        A table with a ``t`` column (seconds) and the ``required`` columns, already renamed to
        session column names; its integer index numbers the source's rows from 0.
    source
        File (or ``file::trial``) named in log lines and errors.
    required
        Columns that must be present, numeric and finite.
    nullable
        Columns that may hold NaN (e.g. a missing GNSS accuracy, which marks an invalid fix).
    names
        How the source names each session column (e.g. ``{"gy": "y", "t": "seconds_elapsed"}``), for
        errors; a column not in it is named as it is. When ``table`` still holds the source's column,
        errors quote its cell as written (a ``time`` in ns rather than ``t`` in s).
    rows
        What the source's rows are called in errors (``"data row"``: counted from 1 after the header).

    Returns
    -------
    pandas.DataFrame
        The ``required`` columns as float, strictly increasing in ``t``, index reset.

    Raises
    ------
    CurbsideInputError
        A required column is missing or holds text or an infinite value, no row survives, two rows share
        a timestamp with different values, or a latitude, longitude or rotation rate lies beyond its range
        (a rate above 35 rad/s: deg/s); each named as the source names it.
    """
    names = dict(names or {})
    if not (table.index.is_unique and pd.api.types.is_integer_dtype(table.index)):
        table = table.reset_index(drop=True)  # rows are then named by their position
    missing = [names.get(c, c) for c in required if c not in table.columns]
    if missing:
        raise CurbsideInputError(source, f"missing column(s) {missing}")
    refuse_text(table, required, source, names)
    out = table[list(required)].apply(pd.to_numeric, errors="raise").astype(float)
    n_in = len(out)
    strict = [c for c in required if c not in nullable]
    _refuse_infinite(table, out, source, names, rows)
    finite = np.isfinite(out[strict].to_numpy()).all(axis=1)
    if not finite.all():
        logger.info("%s: dropped %d row(s) holding a blank or NaN", source, int((~finite).sum()))
        out = out[finite]
    if len(out) == 0:
        blanks = ", ".join(repr(names.get(c, c)) for c in strict)
        raise CurbsideInputError(source, f"no usable rows (read {n_in}; each has a blank or NaN cell in "
                                 f"{blanks})" if n_in else f"no usable rows (read {n_in})")
    _check_limits(table, out, source, names, rows)
    if not out["t"].is_monotonic_increasing:
        logger.info("%s: rows were out of time order; sorted", source)
        out = out.sort_values("t", kind="stable")
    duplicated = out.duplicated(keep="first")
    if duplicated.any():
        logger.info("%s: dropped %d exact duplicate row(s)", source, int(duplicated.sum()))
        out = out[~duplicated]
    _refuse_conflicts(table, out, source, names, rows)
    return out.reset_index(drop=True)


def accelerometer_ms2(acce: pd.DataFrame, source: str | PathLike[str], block: int = 25) -> pd.DataFrame:
    """Check that ``ax,ay,az`` include gravity and are in m/s^2; convert from g if they are in g.

    The unit is judged by the gravity level (:func:`~curbside.localize.session.acceleration_unit`,
    the check a session folder's ``imu.csv`` gets too, where g is refused): about 9.8 means m/s^2,
    about 1 means g (converted, with a log line), anything else is an error.

    Parameters
    ----------
    acce
        Table with ``ax,ay,az``.
    source
        File named in log lines and errors.
    block
        Samples per block mean (25 = 0.5 s at 50 Hz).

    Returns
    -------
    pandas.DataFrame
        A copy with ``ax,ay,az`` in m/s^2.

    Raises
    ------
    CurbsideInputError
        The gravity level is neither about 1 g nor about 9.8 m/s^2.
    """
    unit, level = acceleration_unit(acce[["ax", "ay", "az"]].to_numpy(float), block)
    out = acce.copy()
    if unit == "m/s^2":
        return out
    if unit == "g":
        logger.info("%s: accelerometer in g (gravity level %.2f); converted to m/s^2", source, level)
        out[["ax", "ay", "az"]] *= STANDARD_GRAVITY
        return out
    raise CurbsideInputError(
        source,
        f"accelerometer gravity level {level:.2f} is neither ~9.8 m/s^2 nor ~1 g "
        "(gravity must be included)",
    )


#: A row may lie this many median sample intervals before the row above it and still be a reordering
#: (sorted silently): a logger hands a few samples over late.
FEW_INTERVALS = 3


def clock_step_back(t: np.ndarray) -> tuple[int, float] | None:
    """The first place where the rows of a table go back in time as a clock set back makes them.

    In file order, a row more than :data:`FEW_INTERVALS` median intervals before the row above it is
    a step back. It is harmless, and sorting puts it right, when fewer than :data:`FEW_INTERVALS`
    rows follow it before the stream resumes where it was (a few rows out of order), or when the rows
    until it resumes lie in a stretch no earlier row falls in (older rows inserted whole: a delayed
    batch, samples from before the start reported late). After the clock is set back the stream never
    resumes, or resumes through rows interleaved with the earlier ones. A table written newest first
    is read from its end.

    Parameters
    ----------
    t
        Times (s) in file order; NaN rows are ignored.

    Returns
    -------
    tuple or None
        ``(row, seconds)``: the index of the first row after the step and how far it lies behind the
        latest earlier row; ``None`` when there is no such step.
    """
    step = clock_step(t)
    return None if step is None else step[:2]


def clock_step(t: np.ndarray) -> tuple[int, float, int] | None:
    """:func:`clock_step_back`, with the index of the latest earlier row (the one the step goes back from)
    as a third member."""
    rows = np.flatnonzero(np.isfinite(t))
    if len(rows) > 1 and np.median(np.diff(t[rows])) < 0:
        rows = rows[::-1]
    times = t[rows]
    steps = np.diff(np.sort(times))
    steps = steps[steps > 0]
    if not len(steps):
        return None
    few_s = FEW_INTERVALS * float(np.median(steps))
    latest = np.maximum.accumulate(times)
    for i in np.flatnonzero(times[1:] < times[:-1] - few_s) + 1:
        resumed = np.flatnonzero(times[i:] >= latest[i - 1] - few_s)
        block = times[i : i + resumed[0]] if len(resumed) else times[i:]
        if len(block) < FEW_INTERVALS:
            continue  # a few rows out of order
        earlier = np.sort(times[:i])
        inside = np.searchsorted(earlier, block.max(), "right") - np.searchsorted(earlier, block.min())
        if len(resumed) and inside == 0:
            continue  # older rows inserted whole: sorted into a stretch of their own
        return int(rows[i]), float(latest[i - 1] - times[i]), int(rows[np.argmax(times[:i])])
    return None


#: A waypoint farther than this (m) from every GNSS fix of its session is taken for a mistake (a tap
#: note such as "3,5" read as a position, a route file of another walk) rather than a surveyed point:
#: GNSS errors, even in urban canyons, stay well below it.
MAX_WAYPOINT_DISTANCE_M = 5000.0

_EARTH_RADIUS_M = 6_371_008.8


def far_from_fixes(waypoints: pd.DataFrame, gnss: pd.DataFrame | None,
                   max_m: float = MAX_WAYPOINT_DISTANCE_M) -> np.ndarray:
    """Which waypoints lie farther than ``max_m`` from every GNSS fix (great-circle distance).

    Parameters
    ----------
    waypoints
        Table with ``lat,lon`` (degrees).
    gnss
        Table with ``lat,lon``; with ``None`` or no rows nothing can be judged and no waypoint is far.
    max_m
        Distance (m).

    Returns
    -------
    numpy.ndarray
        One bool per waypoint row.
    """
    if gnss is None or len(gnss) == 0 or len(waypoints) == 0:
        return np.zeros(len(waypoints), bool)
    lat1 = np.radians(waypoints["lat"].to_numpy(float))[:, None]
    lon1 = np.radians(waypoints["lon"].to_numpy(float))[:, None]
    lat2 = np.radians(gnss["lat"].to_numpy(float))[None, :]
    lon2 = np.radians(gnss["lon"].to_numpy(float))[None, :]
    h = np.sin((lat2 - lat1) / 2) ** 2 + np.cos(lat1) * np.cos(lat2) * np.sin((lon2 - lon1) / 2) ** 2
    nearest = 2 * _EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(h.min(axis=1), 0.0, 1.0)))
    return nearest > max_m


def drop_far_waypoints(waypoints: pd.DataFrame, gnss: pd.DataFrame | None, source: str | PathLike,
                       what: str, fixes: str) -> pd.DataFrame:
    """``waypoints`` without those farther than :data:`MAX_WAYPOINT_DISTANCE_M` from every fix, with one
    WARNING naming them (``what``: how the source calls them, e.g. ``"<wpt>"``; ``fixes``: its fixes)."""
    far = far_from_fixes(waypoints, gnss)
    if far.any():
        listed = ", ".join(f"({lat:.5f}, {lon:.5f}) at t={t:.1f} s"
                           for t, lat, lon in waypoints.loc[far, ["t", "lat", "lon"]].itertuples(index=False))
        logger.warning("%s: dropped %d %s more than %.0f km from every %s: %s", source, int(far.sum()), what,
                       MAX_WAYPOINT_DISTANCE_M / 1000, fixes, listed)
    return waypoints[~far].reset_index(drop=True)
