"""Vectorised readers of OSM tag columns shared by the derivation stages.

OSM values are free text: numbers carry units (``"12 m"``, ``"40'"``), lists use ``;``. These helpers
turn one tag column of an :class:`~curbside.osmseg.reader.OsmData` table into numbers or masks, with
NaN / False where the tag is absent or unreadable.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

_FEET_M = 0.3048


def column(df: pd.DataFrame, key: str) -> pd.Series:
    """The tag column ``key`` as strings (None where absent), even if the table lacks it."""
    if key in df:
        return df[key]
    return pd.Series([None] * len(df), index=df.index, dtype=object)


def metres(values: pd.Series) -> np.ndarray:
    """Lengths in metres from OSM values such as ``"7"``, ``"7.5 m"``, ``"24'"``, ``"24 ft"``.

    Returns NaN for absent, unreadable or non-positive values.
    """
    text = values.astype("string").str.strip().str.lower()
    number = pd.to_numeric(text.str.extract(r"^([0-9]*\.?[0-9]+)", expand=False), errors="coerce")
    feet = text.str.contains(r"'|ft|feet", regex=True, na=False)
    out = number.where(~feet, number * _FEET_M).to_numpy(dtype=float, na_value=np.nan)
    out[~(out > 0)] = np.nan
    return out


def first_number(values: pd.Series) -> np.ndarray:
    """The smallest number in ``;``-separated OSM values (``"0;1;2"`` -> 0); NaN where absent."""
    parts = values.astype("string").str.split(";").explode()
    numbers = pd.to_numeric(parts.str.strip(), errors="coerce")
    return numbers.groupby(level=0).min().reindex(values.index).to_numpy(dtype=float, na_value=np.nan)


def is_in(values: pd.Series, allowed) -> np.ndarray:
    """Boolean mask: the value is one of ``allowed``."""
    return values.isin(list(allowed)).to_numpy()


def yes(values: pd.Series) -> np.ndarray:
    """Boolean mask: the tag is present and not ``no``."""
    return (values.notna() & ~values.isin(["no", "false", "0"])).to_numpy()
