"""The one reader of OSM tag values: vectorised parsers shared by osmseg and the simulator.

OSM values are free text: lengths carry units (``"12 m"``, ``"40'"``, ``"6'6\""``, ``"24 ft"``), lists
use ``;``. These helpers turn one tag column of an :class:`~curbside.osmseg.reader.OsmData` table (or
any Series of tag strings) into float64 numbers or boolean masks, with NaN / False where the tag is
absent or unreadable. Every number is parsed into float64 first, so no column of whole numbers can
turn into an integer array that a later unit conversion cannot hold.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

#: Metres per unit of the length units the OSM wiki lists for ``width``, ``height`` and friends
#: (https://wiki.openstreetmap.org/wiki/Map_features/Units); no unit means metres.
LENGTH_UNITS_M: dict[str, float] = {
    "": 1.0, "m": 1.0, "metre": 1.0, "metres": 1.0, "meter": 1.0, "meters": 1.0, "cm": 0.01, "km": 1000.0,
    "ft": 0.3048, "feet": 0.3048, "foot": 0.3048, "'": 0.3048, "in": 0.0254, '"': 0.0254,
    "mi": 1609.344, "nmi": 1852.0,
}  # fmt: skip

# A number (decimal point or comma), an optional unit, optionally inches after feet (6'6"), and
# nothing else before an optional ``;`` list separator.
_LENGTH = (
    r"^\s*(?P<number>[0-9]+(?:[.,][0-9]*)?|[.,][0-9]+)\s*(?P<unit>[a-z]+|'|\")?"
    r"(?:\s*(?P<inches>[0-9]+(?:\.[0-9]*)?)\s*(?:\"|in))?\s*(?:;.*)?$"
)


def column(df: pd.DataFrame, key: str) -> pd.Series:
    """The tag column ``key`` as strings (None where absent), even if the table lacks it."""
    if key in df:
        return df[key]
    return pd.Series([None] * len(df), index=df.index, dtype=object)


def _text(values: pd.Series) -> pd.Series:
    """Tag values as lower-case Python strings (object dtype, NaN where absent)."""
    text = values.astype(object).where(values.notna(), None)
    return text.map(lambda v: str(v).strip().lower() if v is not None else np.nan, na_action="ignore")


def metres(values: pd.Series) -> np.ndarray:
    """Lengths in metres from OSM values such as ``"7"``, ``"7.5 m"``, ``"24'"``, ``"6'6\""``, ``"24 ft"``.

    The first value of a ``;`` list counts. Units are those of :data:`LENGTH_UNITS_M`.

    Returns
    -------
    numpy.ndarray
        float64; NaN for absent, unreadable, unknown-unit or non-positive values.
    """
    if len(values) == 0:
        return np.zeros(0)
    parts = _text(values).astype(object).str.extract(_LENGTH)
    number = pd.to_numeric(parts["number"].str.replace(",", ".", regex=False), errors="coerce")
    unit = parts["unit"].fillna("").map(LENGTH_UNITS_M)
    inches = pd.to_numeric(parts["inches"], errors="coerce").fillna(0.0)
    inch_ok = parts["inches"].isna() | (parts["unit"] == "'")
    out = (
        number.to_numpy(dtype=float, na_value=np.nan) * unit.to_numpy(dtype=float, na_value=np.nan)
        + inches.to_numpy(dtype=float, na_value=np.nan) * LENGTH_UNITS_M["in"]
    )
    out[~inch_ok.to_numpy(dtype=bool) | ~(out > 0) | ~np.isfinite(out)] = np.nan
    return out


def first_number(values: pd.Series) -> np.ndarray:
    """The smallest number in ``;``-separated OSM values (``"0;1;2"`` -> 0); NaN where absent.

    Used for ``layer``, ``level``, ``lanes`` and ``building:levels``; non-finite values count as absent.
    """
    if len(values) == 0:
        return np.zeros(0)
    parts = _text(values).astype(object).str.split(";").explode()
    numbers = pd.to_numeric(parts.str.strip(), errors="coerce").astype(float)
    numbers = numbers.where(np.isfinite(numbers))
    return numbers.groupby(level=0).min().reindex(values.index).to_numpy(dtype=float, na_value=np.nan)


def is_in(values: pd.Series, allowed: Iterable[str]) -> np.ndarray:
    """Boolean mask: the value is one of ``allowed``."""
    return values.isin(list(allowed)).to_numpy()


def yes(values: pd.Series) -> np.ndarray:
    """Boolean mask: the tag is present and not ``no``."""
    return (values.notna() & ~values.isin(["no", "false", "0"])).to_numpy()
