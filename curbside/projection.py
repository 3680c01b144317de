"""Local metric coordinates: the UTM zone of an area, and WGS84 <-> UTM transforms.

All metric work (buffers, areas, particle motion) happens in the local UTM CRS; WGS84 is used only
when reading and writing files.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pyproj
from pyproj.aoi import AreaOfInterest
from pyproj.database import query_utm_crs_info

WGS84 = pyproj.CRS.from_epsg(4326)


def utm_crs_for(lon: float, lat: float) -> pyproj.CRS:
    """Return the WGS84 UTM CRS whose zone contains the point ``(lon, lat)``.

    Parameters
    ----------
    lon, lat
        Degrees, WGS84.

    Returns
    -------
    pyproj.CRS
        E.g. EPSG:32610 for San Francisco.
    """
    # The database query costs ~0.1 s; points 1 km apart share a zone, so cache on a 0.01 degree grid.
    return pyproj.CRS.from_epsg(_utm_epsg(round(lon, 2), round(lat, 2)))


@lru_cache(maxsize=256)
def _utm_epsg(lon: float, lat: float) -> int:
    infos = query_utm_crs_info(datum_name="WGS 84", area_of_interest=AreaOfInterest(lon, lat, lon, lat))
    return int(infos[0].code)


class LocalFrame:
    """Forward and inverse transforms between WGS84 lon/lat and one UTM CRS.

    Parameters
    ----------
    crs
        The metric CRS. Build one with :func:`utm_crs_for` or :meth:`LocalFrame.around`.
    """

    def __init__(self, crs: pyproj.CRS) -> None:
        self.crs = crs
        self._fwd = pyproj.Transformer.from_crs(WGS84, crs, always_xy=True)
        self._inv = pyproj.Transformer.from_crs(crs, WGS84, always_xy=True)

    @classmethod
    def around(cls, lon: float, lat: float) -> LocalFrame:
        """The frame of the UTM zone containing ``(lon, lat)``."""
        return cls(utm_crs_for(lon, lat))

    def to_xy(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 degrees to metres east/north in this CRS (vectorised)."""
        x, y = self._fwd.transform(np.asarray(lon, float), np.asarray(lat, float))
        return np.asarray(x), np.asarray(y)

    def to_lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Metres in this CRS to WGS84 degrees (vectorised)."""
        lon, lat = self._inv.transform(np.asarray(x, float), np.asarray(y, float))
        return np.asarray(lon), np.asarray(lat)
