"""Rasterising the map: curbside's vectorised scanline fill against ``rasterio.features.rasterize``.

Issue 8 asks to keep the hand-written rasteriser only if it beats the well-kept library. Both burn the
same class polygons (in precedence order, so the later class wins) into the same ``uint8`` grid of
the whole map at 0.5 m; cells are "inside" when their centre is (rasterio's default
``all_touched=False``). The script times the best of three runs of each, checks that both grids agree
(cells differing only where a polygon boundary passes within floating-point distance of a centre) and
prints the ratio. rasterio is not a dependency of curbside; install it to run this
(``pip install rasterio``).

Usage::

    python benchmarks/bench_raster.py [--map MAP.geojson] [--resolution 0.5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from curbside.localize.raster import CLASS_CODES, rasterize_mask
from curbside.osmseg.mapio import MapLayers, read_map


def grid_of(layers: MapLayers, res: float) -> tuple[float, float, int, int]:
    minx, miny, maxx, maxy = layers.gdf.total_bounds
    x0, y0 = np.floor(minx / res) * res, np.floor(miny / res) * res
    return x0, y0, int(np.ceil((maxx - x0) / res)), int(np.ceil((maxy - y0) / res))


def curbside_codes(layers: MapLayers, res: float) -> np.ndarray:
    x0, y0, cols, rows = grid_of(layers, res)
    codes = np.zeros((rows, cols), np.uint8)
    for cls, code in sorted(CLASS_CODES.items(), key=lambda kv: kv[1]):
        codes[rasterize_mask(np.asarray(layers.layer(cls).geometry.values), x0, y0, res, (rows, cols))] = code
    return codes


def rasterio_codes(layers: MapLayers, res: float) -> np.ndarray:
    from rasterio.features import rasterize
    from rasterio.transform import from_origin

    x0, y0, cols, rows = grid_of(layers, res)
    shapes = [(geom, code) for cls, code in sorted(CLASS_CODES.items(), key=lambda kv: kv[1])
              for geom in layers.layer(cls).geometry.values]
    # rasterio's row 0 is the northern edge; curbside's is the southern one.
    grid = rasterize(shapes, out_shape=(rows, cols), transform=from_origin(x0, y0 + rows * res, res, res),
                     fill=0, dtype="uint8")
    return grid[::-1]


def best_of(fn, *args, rounds: int = 3) -> tuple[float, np.ndarray]:
    best, out = np.inf, None
    for _ in range(rounds):
        t0 = time.perf_counter()
        out = fn(*args)
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", help="map GeoJSON (default: built from the bundled SF extract)")
    parser.add_argument("--resolution", type=float, default=0.5)
    args = parser.parse_args(argv)
    if args.map:
        layers = read_map(args.map)
    else:
        from curbside.osmseg.build import build_map

        layers = build_map()
    ours_s, ours = best_of(curbside_codes, layers, args.resolution)
    theirs_s, theirs = best_of(rasterio_codes, layers, args.resolution)
    differ = int((ours != theirs).sum())
    print(f"map: {len(layers.gdf)} polygons, grid {ours.shape[0]} x {ours.shape[1]} at {args.resolution} m")
    print(f"curbside scanline      {ours_s:7.2f} s")
    print(f"rasterio.rasterize     {theirs_s:7.2f} s")
    print(f"ratio (rasterio / curbside): {theirs_s / ours_s:.2f}; cells that differ: {differ} "
          f"({differ / ours.size:.2e} of the grid)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
