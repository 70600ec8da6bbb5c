"""Verify a Cesium quantized-mesh folder (``approxtree tiles --format quantized-mesh``).

Checks:

- ``tiles``: every tile layer.json's ``available`` lists exists and decodes with the
  quantized-mesh-tile package (gzip or not); tiles on disk that it does not list are counted;
- ``errors``: each tile's true max |TIN − h_T| over the DEM's data points inside the tile
  (cell centres taken to lon/lat by pyproj; the TIN linear in its quantized (u, v), i.e. in
  lon/lat, with the heights CesiumJS decodes) is within its level's error, CesiumJS's
  77 067 m / 2^level — on the deepest level the error the tile's metadata extension records
  (``geometricError``: the leaf error the writer was asked for) when it has one — allowing the
  height quantization's half step. Data points within 1.5 sample spacings of the DEM's outer
  edge are left out (outside the DEM the tiles are sampled at 0 m), and counted.
"""

from __future__ import annotations

import gzip
import json
import math
import struct
import warnings
from functools import lru_cache
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import StoreError
from approxtree.verify.measure import PointMeasure, grid_index_ranges, index_to_world
from approxtree.verify.report import VerifyReport

#: CesiumJS's level-0 geometric error for the geographic tiling (65-sample heightmap, 2 tiles
#: across): maximumRadius · 2π · 0.25 / (65 · 2).
LEVEL_ZERO_ERROR = 6378137.0 * 2.0 * math.pi * 0.25 / (65 * 2)
QMAX = 32767
#: Data points this many sample spacings from the DEM's edge are left out.
EDGE_SPACINGS = 1.5
#: DEM lattice points read at once.
_WINDOW = 1024


def tile_bounds(level: int, x: int, y: int) -> tuple[float, float, float, float]:
    """(west, south, east, north) degrees of a TMS tile of the geographic tiling."""
    size = 180.0 / 2**level
    return -180.0 + x * size, -90.0 + y * size, -180.0 + (x + 1) * size, -90.0 + (y + 1) * size


def listed_tiles(layer: dict[str, Any]) -> list[tuple[int, int, int]]:
    """(level, x, y) of every tile layer.json's ``available`` ranges list."""
    out = []
    for level, ranges in enumerate(layer.get("available") or []):
        for r in ranges:
            for y in range(int(r["startY"]), int(r["endY"]) + 1):
                for x in range(int(r["startX"]), int(r["endX"]) + 1):
                    out.append((level, x, y))
    return out


def decode(raw: bytes, bounds, lighting: bool, water: bool):
    """(tile, metadata dict) of a .terrain file's bytes (gzip or not)."""
    from quantized_mesh_tile.terrain import TerrainTile

    data = gzip.decompress(raw) if raw[:2] == b"\x1f\x8b" else raw
    west, south, east, north = bounds
    tile = TerrainTile(west=west, south=south, east=east, north=north)
    with warnings.catch_warnings():
        # The package skips the metadata extension with a warning; it is read below.
        warnings.simplefilter("ignore")
        tile.fromBytesIO(BytesIO(data), hasLighting=lighting, hasWatermask=water)
    return tile, _metadata(data, tile)


def _metadata(data: bytes, tile: Any) -> dict[str, Any]:
    """The metadata extension's JSON (id 4), found after the edge lists; {} without one."""
    n = len(tile.u)
    wide = n > 65536
    size = 4 if wide else 2
    at = 88 + 4 + 6 * n
    if wide:
        at += (-at) % 4
    at += 4 + size * len(tile.indices)
    for edge in (tile.westI, tile.southI, tile.eastI, tile.northI):
        at += 4 + size * len(edge)
    while at + 5 <= len(data):
        ext_id, length = struct.unpack_from("<BI", data, at)
        at += 5
        if ext_id == 4 and length >= 4:
            (size_json,) = struct.unpack_from("<I", data, at)
            try:
                return json.loads(data[at + 4 : at + 4 + size_json])
            except ValueError:
                return {}
        at += length
    return {}


@lru_cache(maxsize=4)
def _transformer(source: str, target: str):
    from pyproj import Transformer

    return Transformer.from_crs(source, target, always_xy=True)


def verify_quantized_mesh(output: Path, terrain: Any, report: VerifyReport) -> None:
    try:
        layer = json.loads((output / "layer.json").read_text())
    except (OSError, ValueError) as exc:
        raise StoreError(f"{output / 'layer.json'} is not readable JSON: {exc}") from exc
    template = (layer.get("tiles") or ["{z}/{x}/{y}.terrain"])[0]
    extensions = set(layer.get("extensions") or [])
    lighting, water = "octvertexnormals" in extensions, "watermask" in extensions
    listed = listed_tiles(layer)
    maxzoom = int(layer.get("maxzoom", max((t[0] for t in listed), default=0)))
    check = report.check("tiles", "every tile layer.json lists exists and decodes")
    check.items = len(listed)
    paths = {}
    for z, x, y in listed:
        paths[(z, x, y)] = output / template.format(z=z, x=x, y=y)
    on_disk = {p.resolve() for p in output.rglob("*.terrain")}
    report.figures["tiles"] = len(listed)
    report.figures["unlisted_tiles"] = len(on_disk - {p.resolve() for p in paths.values()})
    measure = LonLatMeasure(terrain, report) if terrain is not None else None
    if measure is not None:
        measure.set_spacings(paths, lighting, water)
    for (z, x, y), path in paths.items():
        address = f"{z}/{x}/{y}"
        if not path.is_file():
            check.fail(address, "a tile", "missing")
            continue
        try:
            tile, meta = decode(path.read_bytes(), tile_bounds(z, x, y), lighting, water)
        except Exception as exc:  # gzip, struct, the package: damaged in any way
            check.fail(address, "decodes", f"{type(exc).__name__}: {exc}"[:120])
            continue
        if measure is not None:
            measure.tile(address, z, tile_bounds(z, x, y), tile, meta, z == maxzoom)
    if measure is not None:
        measure.finish()


class LonLatMeasure:
    """Tile by tile: the DEM's data points inside the tile against the decoded TIN, linear in
    longitude and latitude (quantized-mesh tiles, 3D Tiles terrain)."""

    def __init__(self, terrain: Any, report: VerifyReport) -> None:
        from approxtree.geometry.grid import Grid

        if not isinstance(terrain, Grid) or not terrain.crs:
            raise StoreError(
                "Quantized-mesh tiles are checked against a georeferenced raster DEM (the one "
                "they were made from); give it with --source."
            )
        self.grid = terrain
        self.report = report
        self.check = report.check(
            "errors", "each tile is within its level's error at the DEM's data points"
        )
        self.spacing: dict[int, float] = {}
        self.left_out = 0
        self.measured = 0
        self.worst_ratio = 0.0
        #: level → [tiles over their error, tiles measured].
        self.per_level: dict[int, list[int]] = {}
        d = terrain.domain
        self.domain = (d.xmin, d.ymin, d.xmax, d.ymax)

    def set_spacings(self, paths, lighting: bool, water: bool) -> None:
        """Each level's sample spacing (degrees): the tile width times the greatest common
        divisor of the level's quantized u, v over 32767."""
        steps: dict[int, int] = {}
        for (z, x, y), path in paths.items():
            if not path.is_file():
                continue
            try:
                tile, _ = decode(path.read_bytes(), tile_bounds(z, x, y), lighting, water)
            except Exception:
                continue
            g = int(np.gcd.reduce(np.r_[QMAX, np.asarray(tile.u), np.asarray(tile.v)]))
            steps[z] = math.gcd(steps.get(z, 0), g)
        self.spacing = {z: 180.0 / 2**z * s / QMAX for z, s in steps.items()}

    def _points(self, bounds, spacing: float) -> np.ndarray:
        """(n, 3) lon, lat, height of the DEM's data points inside the tile, those near the
        DEM's edge left out."""
        west, south, east, north = bounds
        to_dem = _transformer("EPSG:4326", self.grid.crs)
        # The tile's outline, densified, in the DEM's CRS: its bounding index range.
        t = np.linspace(0.0, 1.0, 33)
        lon = np.r_[
            west + (east - west) * t, np.full(33, east), east - (east - west) * t, np.full(33, west)
        ]
        lat = np.r_[
            np.full(33, south),
            south + (north - south) * t,
            np.full(33, north),
            north - (north - south) * t,
        ]
        x, y = to_dem.transform(lon, np.clip(lat, -89.999999, 89.999999))
        x, y = np.asarray(x), np.asarray(y)
        ok = np.isfinite(x) & np.isfinite(y)
        if not ok.any():
            return np.zeros((0, 3))
        rect = np.array([[x[ok].min(), y[ok].min(), x[ok].max(), y[ok].max()]])
        r0, r1, c0, c1 = grid_index_ranges(self.grid, rect)[0]
        r0, c0 = max(0, r0 - 1), max(0, c0 - 1)
        r1, c1 = min(self.grid.shape[0] - 1, r1 + 1), min(self.grid.shape[1] - 1, c1 + 1)
        parts = []
        to_lonlat = _transformer(self.grid.crs, "EPSG:4326")
        for a in range(r0, r1 + 1, _WINDOW):
            for b in range(c0, c1 + 1, _WINDOW):
                rb, cb = min(r1 + 1, a + _WINDOW), min(c1 + 1, b + _WINDOW)
                z = np.asarray(self.grid.heights[a:rb, b:cb], dtype=np.float64)
                rr, cc = np.nonzero(np.isfinite(z))
                if not len(rr):
                    continue
                px, py = index_to_world(self.grid, rr + a, cc + b)
                plon, plat = to_lonlat.transform(px, py)
                plon, plat = np.asarray(plon), np.asarray(plat)
                inside = (plon >= west) & (plon <= east) & (plat >= south) & (plat <= north)
                pts = np.column_stack([plon, plat, z[rr, cc]])[inside]
                near = self._near_edge(pts, EDGE_SPACINGS * spacing)
                self.left_out += int(near.sum())
                parts.append(pts[~near])
        return np.concatenate(parts) if parts else np.zeros((0, 3))

    def _near_edge(self, pts: np.ndarray, reach: float) -> np.ndarray:
        """Points (lon, lat) within ``reach`` degrees (L∞) of leaving the DEM's domain."""
        near = np.zeros(len(pts), dtype=bool)
        if not len(pts) or reach <= 0:
            return near
        to_dem = _transformer("EPSG:4326", self.grid.crs)
        x0, y0, x1, y1 = self.domain
        for dx, dy in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
            x, y = to_dem.transform(
                pts[:, 0] + dx * reach, np.clip(pts[:, 1] + dy * reach, -90, 90)
            )
            x, y = np.asarray(x), np.asarray(y)
            near |= ~((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1))
        return near

    def tile(self, address: str, level: int, bounds, tile: Any, meta: dict, deepest: bool) -> None:
        """Measure one decoded tile (bounds: west, south, east, north) against its level's
        error."""
        west, south, east, north = bounds
        lo, hi = float(tile.header["minimumHeight"]), float(tile.header["maximumHeight"])
        u = np.asarray(tile.u, dtype=np.float64) / QMAX
        v = np.asarray(tile.v, dtype=np.float64) / QMAX
        h = lo + (hi - lo) * np.asarray(tile.h, dtype=np.float64) / QMAX
        verts = np.column_stack([west + (east - west) * u, south + (north - south) * v, h])
        tris = np.asarray(tile.indices, dtype=np.int64).reshape(-1, 3)
        claimed = LEVEL_ZERO_ERROR / 2**level
        if deepest and isinstance(meta.get("geometricError"), (int, float)):
            claimed = float(meta["geometricError"])
        self.mesh(address, level, bounds, verts, tris, claimed, (hi - lo) / (2 * QMAX))

    def mesh(
        self,
        address: str,
        level: int,
        bounds,
        verts: np.ndarray,
        tris: np.ndarray,
        claimed: float,
        allowance: float = 0.0,
    ) -> None:
        """Measure one tile's TIN: verts (n, 3) longitude, latitude, height, tris (m, 3),
        against ``claimed`` (+ ``allowance``)."""
        west, south, east, north = bounds
        hi = float(verts[:, 2].max()) if len(verts) else 0.0
        self.check.items += 1
        pts = self._points((west, south, east, north), self.spacing.get(level, 0.0))
        if not len(pts) or not len(tris):
            return
        found = PointMeasure(pts).errors(
            np.array([[west, south, east, north]]),
            lambda owners: (verts[tris].reshape(-1, 9), np.zeros(len(tris), dtype=np.int64)),
            1e-9 * (east - west),
        )
        measured = float(max(found.err[0], 0.0))
        self.measured += int(found.measured[0])
        counts = self.per_level.setdefault(level, [0, 0])
        counts[1] += 1
        limit = claimed + allowance
        self.worst_ratio = max(self.worst_ratio, measured / limit if limit > 0 else math.inf)
        if measured > limit * (1 + 1e-9) + 1e-9 * (1.0 + abs(hi)):
            counts[0] += 1
            wx, wy = found.worst[0]
            self.check.fail(
                f"tile {address} at ({wx:.6f}, {wy:.6f})", claimed, measured, measured - limit
            )

    def finish(self) -> None:
        self.report.figures["data_points_measured"] = self.measured
        self.report.figures["edge_points_left_out"] = self.left_out
        self.report.figures["worst_error_over_allowed"] = self.worst_ratio
        self.report.figures["tiles_over_per_level"] = {
            str(z): f"{over} of {n}" for z, (over, n) in sorted(self.per_level.items())
        }
