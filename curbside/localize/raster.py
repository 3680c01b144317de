"""Map layers rasterised once into a grid of class codes, cached on disk, looked up by index math.

The particle filter weighs every particle at every footstep by the class of the map under it. Testing
particles against polygons is far too slow for that (see ``benchmarks/bench_filter.py``), so the map is
rasterised once into a ``uint8`` grid of class codes and a lookup becomes two multiplications, a clip
and a gather.

Each class is burnt with ``rasterio.features.rasterize`` (a cell belongs to a polygon when its centre
does), in precedence order.

Class codes increase with precedence, so the grid is the element-wise maximum of the class masks:
``building`` overrides everything, ``crosswalk`` overrides ``street`` and ``sidewalk``, and
``sidewalk`` overrides ``street`` (a sidewalk drawn over the carriageway edge is walkable). Building
cells also record how deep inside the building they lie: code ``BUILDING + k`` for a cell centre about
``(k + 0.5) * resolution`` metres past the wall (:func:`building_depth_m`; Euclidean distance transform),
so that a map likelihood can soften the walls by a few metres of map error without another lookup.
:attr:`MapRaster.sidewalk_under_buildings` says whether the map's buildings and sidewalks agree: the
share of sidewalk cells a building covers (zero for a map ``osmseg`` built, whose classes are disjoint;
more for a building layer from another source or year laid over the streets), or, if larger, the share
of the mapped sidewalk ways' length inside a building that ``osmseg`` recorded in the map's metadata
(``sidewalk_ways_in_buildings``: a building layer misaligned with the city's mapped footways). Where a
building covers sidewalk or crosswalk cells, the raster also keeps those cells as they would be with the
walkable classes on top (:attr:`MapRaster.walkable_first`), which the filter uses on such a map.

Alongside the class codes, the same grid holds the index of the nearest sidewalk segment of every cell
within the segment reach (25 m by default) of one (-1 farther away), with the ``segment_id``
strings in a lookup array: the filter sums its particle weights per segment with one ``bincount``. The
segments are rasterised (each cell centre inside a sidewalk polygon takes that polygon's index, found
by one vectorised STRtree query over those centres), and the Euclidean distance transform
(:func:`scipy.ndimage.distance_transform_edt` with ``return_indices``) hands every other cell the index
of its nearest labelled cell.

Rasters are cached (:mod:`curbside.cache`, kind ``rasters``) as ``.npz`` files named by a SHA-256 of
the map content (CRS, classes and WKB of every polygon, sidewalk ``segment_id`` strings), the
resolution, the segment reach and the rasteriser version.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
import pyproj
import shapely
from rasterio import features
from rasterio.transform import from_origin
from scipy import ndimage
from tqdm.auto import tqdm

from curbside import cache as disk_cache
from curbside.configio import beyond_memory
from curbside.errors import CurbsideInputError
from curbside.osmseg.mapio import MapLayers

if TYPE_CHECKING:
    import geopandas as gpd

logger = logging.getLogger(__name__)

#: Class codes in order of precedence (a higher code wins where polygons overlap). Codes from
#: ``BUILDING`` up are building cells, ``BUILDING + k`` about ``(k + 0.5)`` cells deep.
FREE, STREET, SIDEWALK, CROSSWALK, BUILDING = 0, 1, 2, 3, 4
#: Largest depth index stored (uint8 codes).
MAX_DEPTH_INDEX = 255 - BUILDING
CLASS_CODES: dict[str, int] = {
    "street": STREET, "sidewalk": SIDEWALK, "crosswalk": CROSSWALK, "building": BUILDING
}

#: Bumped whenever the rasteriser's output changes, so stale cache files are not reused.
RASTER_FORMAT_VERSION = 8
#: Peak memory of :func:`rasterize_map`, bytes per cell: the codes, the class masks, the distance
#: transforms of the building depth and the segment grid (measured: 66-69 on the bundled downtown map
#: at 0.35 and 0.5 m cells).
BYTES_PER_CELL = 70


@dataclass(frozen=True)
class MapRaster:
    """A grid of class codes over a map's extent in its local metric CRS.

    Cell ``(i, j)`` covers ``x0 + j * resolution_m <= x < x0 + (j + 1) * resolution_m`` and the same in
    ``y`` with row ``i`` (row 0 is the southern edge).

    Attributes
    ----------
    codes
        ``(rows, cols)`` ``uint8`` class codes (:data:`FREE`, :data:`STREET`, :data:`SIDEWALK`,
        :data:`CROSSWALK`, and from :data:`BUILDING` up building cells by depth).
    x0, y0
        South-west corner of the grid, metres in :attr:`crs`.
    resolution_m
        Cell size, metres.
    crs
        The map's metric CRS (WKT), for checks when a raster is reused.
    segment_index
        ``(rows, cols)`` ``int16``/``int32`` index into :attr:`segment_ids` of the nearest sidewalk segment of
        each cell, -1 beyond the segment reach; ``None`` for a map without
        sidewalk segments.
    segment_ids
        ``segment_id`` string of each indexed segment (``None`` with :attr:`segment_index`).
    segment_axes
        ``(S, 2)`` unit vector along each segment (its street's direction; :func:`street_axes`).
    sidewalk_under_buildings
        Share of the sidewalk cells that a building polygon also covers (0 without sidewalks), or the
        map metadata's ``sidewalk_ways_in_buildings`` if larger.
    walkable_first_cells, walkable_first_codes
        Flat indices into :attr:`codes` and the codes those cells take when sidewalks and crosswalks win
        over buildings (the covered cells, and the building cells whose depth changes with them);
        ``None`` where no building covers a sidewalk or crosswalk.
    """

    codes: np.ndarray
    x0: float
    y0: float
    resolution_m: float
    crs: str
    segment_index: np.ndarray | None = None
    segment_ids: np.ndarray | None = None
    segment_axes: np.ndarray | None = None
    sidewalk_under_buildings: float = 0.0
    walkable_first_cells: np.ndarray | None = None
    walkable_first_codes: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``."""
        return self.codes.shape

    @cached_property
    def padded_codes(self) -> np.ndarray:
        """:attr:`codes` in a ring of :data:`FREE` cells, flattened (read-only).

        Made once per raster and shared by every :class:`RasterLookup`: the filters of many sessions
        on one map (the live service) hold one copy, not one each.
        """
        padded = np.pad(self.codes, 1, constant_values=FREE).ravel()
        padded.flags.writeable = False
        return padded

    @cached_property
    def walkable_first(self) -> MapRaster:
        """This raster with the map's sidewalks and crosswalks over its buildings where they overlap.

        For a map whose building layer disagrees with its streets (another source or year): the
        walkable layers, drawn against the streets, are taken as right there. Made once and shared; the
        raster itself where nothing overlaps.
        """
        if self.walkable_first_cells is None:
            return self
        codes = self.codes.copy()
        codes.flat[self.walkable_first_cells] = self.walkable_first_codes
        return replace(self, codes=codes, walkable_first_cells=None, walkable_first_codes=None)

    @cached_property
    def padded_segments(self) -> np.ndarray | None:
        """:attr:`segment_index` in a ring of -1, flattened (read-only, shared); ``None`` without it."""
        if self.segment_index is None:
            return None
        padded = np.pad(self.segment_index, 1, constant_values=-1).ravel()
        padded.flags.writeable = False
        return padded

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the grid, metres."""
        rows, cols = self.codes.shape
        return (self.x0, self.y0, self.x0 + cols * self.resolution_m, self.y0 + rows * self.resolution_m)

    def contains(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Whether points lie inside the grid's extent."""
        xmin, ymin, xmax, ymax = self.bounds
        x, y = np.asarray(x, float), np.asarray(y, float)
        return (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)

    def codes_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Class code under each point; :data:`FREE` outside the grid.

        Parameters
        ----------
        x, y
            Metres in :attr:`crs`, any matching shapes.

        Returns
        -------
        numpy.ndarray
            ``uint8`` codes, the shape of ``x``.
        """
        lookup = RasterLookup(self)
        return lookup.codes_at(np.asarray(x, float), np.asarray(y, float))

    def nearest_free(self, x: float, y: float, max_distance_m: float) -> tuple[float, float] | None:
        """Centre of the cell nearest to ``(x, y)`` that is not in a building.

        Searches a square window of half-size ``max_distance_m``; returns ``None`` when every cell in
        it is a building cell. A point outside the grid is returned unchanged (outside is free).
        """
        if not bool(self.contains(x, y)):
            return (x, y)
        res = self.resolution_m
        rows, cols = self.codes.shape
        half = int(np.ceil(max_distance_m / res))
        i0, j0 = int((y - self.y0) // res), int((x - self.x0) // res)
        ilo, ihi = max(i0 - half, 0), min(i0 + half + 1, rows)
        jlo, jhi = max(j0 - half, 0), min(j0 + half + 1, cols)
        ii, jj = np.nonzero(self.codes[ilo:ihi, jlo:jhi] < BUILDING)
        if len(ii) == 0:
            return None
        cx = self.x0 + (jj + jlo + 0.5) * res
        cy = self.y0 + (ii + ilo + 0.5) * res
        k = int(np.argmin((cx - x) ** 2 + (cy - y) ** 2))
        return float(cx[k]), float(cy[k])

    def segments_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index into :attr:`segment_ids` of the nearest sidewalk segment of each point (-1: none).

        Points outside the grid, and every point of a raster without segments, give -1.
        """
        x, y = np.asarray(x, float), np.asarray(y, float)
        if self.segment_index is None:
            return np.full(x.shape, -1, np.int16)
        lookup = RasterLookup(self)
        return lookup.segments_at(x.ravel(), y.ravel()).reshape(x.shape)


class RasterLookup:
    """Index math from points to class codes, with preallocated buffers for a fixed particle count.

    The grid is padded with one ring of :data:`FREE` cells so that clipping an index into the padded
    grid sends every point outside the map to a free cell, without a mask.

    Parameters
    ----------
    raster
        The map raster.
    """

    def __init__(self, raster: MapRaster) -> None:
        rows, cols = raster.codes.shape
        self.raster = raster
        self.padded = raster.padded_codes
        #: Padded nearest-segment grid (-1 in the ring); ``None`` without sidewalk segments.
        self.padded_segments = raster.padded_segments
        self.inv_res = 1.0 / raster.resolution_m
        # Index in the padded grid = (x - (x0 - res)) / res, i.e. x * inv_res - offset.
        self.x_offset = (raster.x0 - raster.resolution_m) * self.inv_res
        self.y_offset = (raster.y0 - raster.resolution_m) * self.inv_res
        self.col_max = cols + 1.5
        self.row_max = rows + 1.5
        self.stride = cols + 2
        #: ``(inv_res, x_offset, y_offset, col_max, row_max, stride)``: what a compiled kernel needs to
        #: index the padded grids (:func:`curbside.localize.filter.kernelmath.cell_index`).
        self.index_grid = (
            self.inv_res, self.x_offset, self.y_offset, self.col_max, self.row_max, self.stride
        )
        self._n = -1

    def _buffers(self, n: int) -> None:
        if n != self._n:
            self._fx = np.empty(n)
            self._fy = np.empty(n)
            self._flat = np.empty(n, dtype=np.intp)
            self._iy = np.empty(n, dtype=np.intp)
            self._codes = np.empty(n, dtype=np.uint8)
            self._n = n

    def flat_indices(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index into the padded, flattened grid of each point of 1-D ``x, y`` (a reused buffer)."""
        self._buffers(len(x))
        fx, fy = self._fx, self._fy
        np.multiply(x, self.inv_res, out=fx)
        fx -= self.x_offset
        np.clip(fx, 0.0, self.col_max, out=fx)  # truncation below is floor for values >= 0
        np.multiply(y, self.inv_res, out=fy)
        fy -= self.y_offset
        np.clip(fy, 0.0, self.row_max, out=fy)
        flat, iy = self._flat, self._iy
        flat[...] = fx
        iy[...] = fy
        iy *= self.stride
        flat += iy
        return flat

    def codes_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Class codes under ``x, y`` (1-D or any shape); a view into a reused buffer for 1-D input."""
        shape = x.shape
        flat = self.flat_indices(x.ravel(), y.ravel())
        np.take(self.padded, flat, out=self._codes)
        return self._codes.reshape(shape)

    def segments_at(self, x: np.ndarray, y: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Nearest-segment index under 1-D ``x, y`` (-1: none), into ``out`` when given.

        Raises
        ------
        ValueError
            The raster has no segment grid.
        """
        if self.padded_segments is None:
            raise ValueError("the map raster has no sidewalk segments")
        return np.take(self.padded_segments, self.flat_indices(x, y), out=out)


def map_hash(layers: MapLayers, resolution_m: float, segment_reach_m: float) -> str:
    """SHA-256 hex digest of a map's content and the raster parameters (the cache key)."""
    digest = hashlib.sha256()
    digest.update(f"v{RASTER_FORMAT_VERSION};res={float(resolution_m)!r};".encode())
    digest.update(f"segment_reach={float(segment_reach_m)!r};".encode())
    digest.update(pyproj.CRS(layers.crs).to_wkt().encode())
    digest.update(repr(sorted(CLASS_CODES.items())).encode())
    for cls in layers.gdf["class"].astype(str):
        digest.update(cls.encode())
    for wkb in shapely.to_wkb(layers.gdf.geometry.values, output_dimension=2):
        digest.update(wkb)
    if "segment_id" in layers.gdf:
        digest.update("\0".join(map(str, layers.gdf["segment_id"].tolist())).encode())
    if "facing_deg" in layers.gdf:
        digest.update(np.asarray(layers.gdf["facing_deg"], dtype=np.float64).tobytes())
    digest.update(f";ways_in_buildings={_recorded_ways_in_buildings(layers)!r}".encode())
    return digest.hexdigest()


def rasterize_mask(
    geoms: np.ndarray, x0: float, y0: float, res: float, shape: tuple[int, int]
) -> np.ndarray:
    """Boolean mask of the cells whose centre lies inside any of ``geoms``.

    ``rasterio.features.rasterize`` (GDAL's scanline burner, cell centres, ``all_touched=False``);
    ``benchmarks/bench_raster.py`` measured it 3x faster than a vectorised numpy scanline fill with
    identical cells on the SF map.

    Parameters
    ----------
    geoms
        Polygons and multipolygons (metres).
    x0, y0
        South-west corner of the grid.
    res
        Cell size.
    shape
        ``(rows, cols)``.

    Returns
    -------
    numpy.ndarray
        ``bool`` array of ``shape``; row 0 is the southern edge.
    """
    rows, cols = shape
    geoms = [g for g in np.asarray(geoms) if g is not None and not g.is_empty]
    if not geoms or rows == 0 or cols == 0:
        return np.zeros(shape, dtype=bool)
    transform = from_origin(x0, y0 + rows * res, res, res)  # rasterio's row 0 is the northern edge
    burnt = features.rasterize(((g, 1) for g in geoms), out_shape=shape, transform=transform, fill=0,
                               dtype="uint8")
    return burnt[::-1].astype(bool)


def long_axes(polygons: np.ndarray) -> np.ndarray:
    """Unit vector along the long side of each polygon's minimum rotated rectangle.

    Parameters
    ----------
    polygons
        Shapely polygons.

    Returns
    -------
    numpy.ndarray
        ``(n, 2)``; ``(1, 0)`` for a degenerate polygon.
    """
    env = shapely.oriented_envelope(polygons)
    coords, owner = shapely.get_coordinates(env, return_index=True)
    first = np.searchsorted(owner, np.arange(len(polygons)))
    has3 = np.bincount(owner, minlength=len(polygons)) >= 3
    first = np.where(has3, first, 0)
    last = len(coords) - 1
    p0, p1, p2 = coords[first], coords[np.minimum(first + 1, last)], coords[np.minimum(first + 2, last)]
    e1, e2 = p1 - p0, p2 - p1
    longer = np.where((np.hypot(*e1.T) >= np.hypot(*e2.T))[:, None], e1, e2)
    norm = np.hypot(*longer.T)
    good = has3 & (norm > 0)
    axis = np.tile([1.0, 0.0], (len(polygons), 1))
    axis[good] = longer[good] / norm[good, None]
    return axis


def street_axes(sidewalks: gpd.GeoDataFrame) -> np.ndarray:
    """Unit vector ``(n, 2)`` along each sidewalk segment's street (x east, y north; sign meaningless).

    A segment that ``osmseg build`` wrote has ``facing_deg``, the bearing from its street to it, so its
    street runs at right angles to it; others take their polygon's long axis (:func:`long_axes`), which
    at a short piece on a corner is the cross street's. Used by the along/across metrics, the street
    heading, the crossing rule and the anisotropic GNSS likelihood.
    """
    axes = long_axes(np.asarray(sidewalks.geometry.values))
    if "facing_deg" in sidewalks:
        facing = np.radians(np.asarray(sidewalks["facing_deg"], dtype=float))
        known = np.isfinite(facing)
        axes[known] = np.column_stack([np.cos(facing[known]), -np.sin(facing[known])])
    return axes


def rasterize_segments(
    layers: MapLayers, x0: float, y0: float, res: float, shape: tuple[int, int], max_distance_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Grid of the nearest sidewalk segment's index of every cell, and the ``segment_id`` lookup array.

    Cells whose centre lies in (or on) a sidewalk polygon take its index (the first polygon where
    several overlap); a polygon too thin to hold a cell centre marks the cell of a point on its
    surface. Every other cell takes the index of the nearest marked cell (Euclidean distance
    transform), or -1 when that is farther than ``max_distance_m``.

    Parameters
    ----------
    layers
        The map, in its local metric CRS.
    x0, y0, res, shape
        The grid: south-west corner, cell size and ``(rows, cols)``.
    max_distance_m
        Reach of a segment, metres.

    Returns
    -------
    tuple of numpy.ndarray or None
        ``(segment_index, segment_ids, segment_axes)``: ``int16`` (``int32`` beyond 32,766 segments) grid of
        ``shape`` and the ``str`` ids; ``None``
        when the map has no sidewalk segment.
    """
    reach = float(max_distance_m)
    sidewalks = layers.layer("sidewalk")
    sidewalks = sidewalks[sidewalks.geometry.notna() & ~sidewalks.geometry.is_empty]
    if len(sidewalks) == 0:
        return None
    geoms = np.asarray(sidewalks.geometry.values)
    ids = sidewalks["segment_id"].astype(str).to_numpy().astype(str)
    rows, cols = shape
    label = np.full(shape, -1, np.int32)
    ii, jj = np.nonzero(rasterize_mask(geoms, x0, y0, res, shape))
    centres = shapely.points(x0 + (jj + 0.5) * res, y0 + (ii + 0.5) * res)
    cell, poly = shapely.STRtree(geoms).query(centres, predicate="intersects")
    # Reversed so that, among overlapping polygons, the first one is written last and wins.
    label[ii[cell[::-1]], jj[cell[::-1]]] = poly[::-1]
    unmarked = np.setdiff1d(np.arange(len(geoms)), label[label >= 0])
    if len(unmarked):
        px, py = shapely.get_coordinates(shapely.point_on_surface(geoms[unmarked])).T
        pj, pi = np.floor((px - x0) / res).astype(np.intp), np.floor((py - y0) / res).astype(np.intp)
        inside = (pi >= 0) & (pi < rows) & (pj >= 0) & (pj < cols)
        free = np.zeros(len(unmarked), bool)
        free[inside] = label[pi[inside], pj[inside]] < 0
        label[pi[free], pj[free]] = unmarked[free]
    if not (label >= 0).any():
        return None
    distance, (ri, ci) = ndimage.distance_transform_edt(label < 0, sampling=res, return_indices=True)
    segment_index = label[ri, ci]
    segment_index[distance > reach] = -1
    # The grid is as large as the class raster: int16 quarters it for maps with < 32,767 segments.
    dtype = np.int16 if len(ids) < np.iinfo(np.int16).max else np.int32
    return segment_index.astype(dtype), ids, street_axes(sidewalks)


def rasterize_map(
    layers: MapLayers, resolution_m: float = 0.5, segment_reach_m: float = 25.0, margin_m: float = 0.0
) -> MapRaster:
    """Rasterise map layers into class codes (no cache; see :func:`load_or_build_raster`).

    Parameters
    ----------
    layers
        The map, in its local metric CRS.
    resolution_m
        Cell size, metres.
    segment_reach_m
        Cells farther than this from every sidewalk segment belong to none.
    margin_m
        Free border added around the map's bounds.

    Returns
    -------
    MapRaster
    """
    res = float(resolution_m)
    if not res > 0:
        raise ValueError(f"raster resolution must be positive, got {res}")
    minx, miny, maxx, maxy = layers.gdf.total_bounds
    x0 = np.floor((minx - margin_m) / res) * res
    y0 = np.floor((miny - margin_m) / res) * res
    cols = int(np.ceil((maxx + margin_m - x0) / res))
    rows = int(np.ceil((maxy + margin_m - y0) / res))
    lacking = beyond_memory(rows * cols * BYTES_PER_CELL)
    if lacking is not None:
        raise CurbsideInputError(
            "filter.map.raster_resolution_m",
            f"{res:g} m cells over the map's {cols * res:.0f} x {rows * res:.0f} m would need {lacking}",
        )
    codes = np.zeros((rows, cols), dtype=np.uint8)
    masks = {}
    for cls, code in tqdm(sorted(CLASS_CODES.items(), key=lambda kv: kv[1]), desc="rasterising map",
                          unit="class", leave=False, disable=None):
        geoms = layers.layer(cls).geometry.values
        masks[code] = rasterize_mask(np.asarray(geoms), x0, y0, res, (rows, cols))
        codes[masks[code]] = code
        logger.debug("rasterised %d %s polygons: %d cells", len(geoms), cls, int(masks[code].sum()))
    n_sidewalk = int(masks[SIDEWALK].sum())
    under_buildings = int(masks[BUILDING][masks[SIDEWALK]].sum()) / n_sidewalk if n_sidewalk else 0.0
    under_buildings = max(under_buildings, _recorded_ways_in_buildings(layers))
    variant = _walkable_first(codes, masks)
    _encode_building_depth(codes)
    cells = None if variant is None else np.flatnonzero(variant != codes)
    segments = rasterize_segments(layers, float(x0), float(y0), res, (rows, cols), segment_reach_m)
    segment_index, segment_ids, segment_axes = segments if segments is not None else (None, None, None)
    return MapRaster(
        codes, float(x0), float(y0), res, pyproj.CRS(layers.crs).to_wkt(), segment_index, segment_ids,
        segment_axes, under_buildings, cells, None if cells is None else variant.ravel()[cells],
    )


def _walkable_first(codes: np.ndarray, masks: dict[int, np.ndarray]) -> np.ndarray | None:
    """``codes`` (not yet depth-encoded) with sidewalks and crosswalks over buildings, depth-encoded, or
    ``None`` where no building covers either."""
    covered = masks[BUILDING] & (masks[SIDEWALK] | masks[CROSSWALK])
    if not covered.any():
        return None
    variant = codes.copy()
    variant[covered] = np.where(masks[CROSSWALK][covered], CROSSWALK, SIDEWALK)
    _encode_building_depth(variant)
    return variant


def _recorded_ways_in_buildings(layers: MapLayers) -> float:
    """The metadata's ``sidewalk_ways_in_buildings`` (``osmseg build``), 0 where absent or not a number."""
    value = layers.meta.get("sidewalk_ways_in_buildings")
    return float(value) if isinstance(value, int | float) and 0 <= value <= 1 else 0.0


def _encode_building_depth(codes: np.ndarray) -> None:
    """Building cells become ``BUILDING + k``: ``k`` whole cells from the nearest free cell, minus one."""
    building = codes == BUILDING
    if not building.any():
        return
    # Outside the grid is free: pad with a free ring so buildings at the edge are shallow there too.
    depth_cells = ndimage.distance_transform_edt(np.pad(building, 1))[1:-1, 1:-1]
    k = np.minimum(np.floor(depth_cells[building]) - 1, MAX_DEPTH_INDEX)
    codes[building] = (BUILDING + k).astype(np.uint8)


def building_depth_m(codes: np.ndarray | int, resolution_m: float) -> np.ndarray:
    """Depth (m) past the wall of building codes (NaN for other codes): ``(k + 0.5) * resolution``."""
    codes = np.asarray(codes)
    return np.where(codes >= BUILDING, (codes.astype(float) - BUILDING + 0.5) * resolution_m, np.nan)


def _arrays(raster: MapRaster) -> dict[str, np.ndarray]:
    """A raster as the arrays of its cache entry (``segment_ids`` is a str array: no pickle)."""
    arrays = {"codes": raster.codes, "x0": np.float64(raster.x0), "y0": np.float64(raster.y0),
              "resolution_m": np.float64(raster.resolution_m), "crs": np.array(raster.crs),
              "sidewalk_under_buildings": np.float64(raster.sidewalk_under_buildings)}
    if raster.walkable_first_cells is not None:
        arrays |= {"walkable_first_cells": raster.walkable_first_cells,
                   "walkable_first_codes": raster.walkable_first_codes}
    if raster.segment_index is not None:
        arrays |= {"segment_index": raster.segment_index, "segment_ids": raster.segment_ids,
                   "segment_axes": raster.segment_axes}
    return arrays


def load_or_build_raster(
    layers: MapLayers, resolution_m: float = 0.5, segment_reach_m: float = 25.0, cache: bool = True
) -> MapRaster:
    """The map's raster from the disk cache (:mod:`curbside.cache`), or rasterised now and stored there.

    Parameters
    ----------
    layers
        The map.
    resolution_m, segment_reach_m
        Cell size and segment reach (see :func:`rasterize_map`).
    cache
        Read and write the ``rasters`` entry named by :func:`map_hash`.

    Returns
    -------
    MapRaster
    """
    res = float(resolution_m)
    if not cache:
        return rasterize_map(layers, res, segment_reach_m)
    arrays = disk_cache.cached_arrays(
        "rasters", map_hash(layers, res, segment_reach_m),
        lambda: _arrays(rasterize_map(layers, res, segment_reach_m)),
        required=("codes", "x0", "y0", "resolution_m", "crs", "sidewalk_under_buildings"),
    )
    return MapRaster(arrays["codes"], float(arrays["x0"]), float(arrays["y0"]), float(arrays["resolution_m"]),
                     str(arrays["crs"]), arrays.get("segment_index"), arrays.get("segment_ids"),
                     arrays.get("segment_axes"), float(arrays["sidewalk_under_buildings"]),
                     arrays.get("walkable_first_cells"), arrays.get("walkable_first_codes"))
