"""Verify raster map tiles: raster-dem (Terrarium, Terrain-RGB) and imagery, folder or PMTiles.

Read with none of the writers' code: the TileJSON (``tilejson.json`` of a folder, or a PMTiles
archive's metadata read by the ``pmtiles`` package) lists the tiles by zoom in layer.json's
ranges; Pillow decodes each tile; the tile math (Web Mercator, geographic) and the heights'
decoding are written here from their specifications.

Checks:

- ``tiles``: every tile the TileJSON lists exists (a file, or an archive entry) and decodes
  to a tile_size × tile_size image of the mode its kind needs (RGB for raster-dem); tiles on
  disk that it does not list are counted;
- ``heights`` (raster-dem with a source): at every pixel whose centre lies in the source
  DEM's domain with the three data points of its triangle valid, the decoded height is within the
  encoding's step (1/256 m Terrarium, 0.1 m Terrain-RGB) of h_T there — the pixel's centre
  taken to lon/lat by the tiling's formulas, into the DEM's CRS by pyproj, h_T linear on the
  triangle of data points under it (each cell cut by its diagonal from the north-west data
  point). Pixels outside the domain or over nodata are left out and counted.

Imagery colours are not recomputed (the texture pyramid is checked on its own).
"""

from __future__ import annotations

import io
import json
import math
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import StoreError
from approxtree.verify.measure import world_to_index
from approxtree.verify.report import VerifyReport

#: Decoding of each raster-dem encoding: h = (R·65536 + G·256 + B) / scale − offset.
DECODING = {"terrarium": (256.0, 32768.0), "terrain-rgb": (10.0, 10000.0)}
PMTILES_MAGIC = b"PMTiles"


def read_tilejson(output: Path) -> dict[str, Any]:
    """The TileJSON of a tile folder or of a PMTiles archive (its metadata)."""
    try:
        if output.is_dir():
            return json.loads((output / "tilejson.json").read_text())
        with open(output, "rb") as f:
            from pmtiles.reader import MmapSource, Reader

            return Reader(MmapSource(f)).metadata()
    except (OSError, ValueError, KeyError) as exc:
        raise StoreError(f"{output}: its TileJSON is not readable ({exc}).") from exc


def listed(doc: dict[str, Any]) -> list[tuple[int, int, int]]:
    """(z, x, y) of every tile the TileJSON's ``approxtree.available`` ranges list."""
    out = []
    for z, ranges in enumerate(doc.get("approxtree", {}).get("available") or []):
        for r in ranges:
            for y in range(int(r["startY"]), int(r["endY"]) + 1):
                for x in range(int(r["startX"]), int(r["endX"]) + 1):
                    out.append((z, x, y))
    return out


class _Tiles:
    """Tile bytes by address, from a folder (its TileJSON's template) or a PMTiles archive."""

    def __init__(self, output: Path, doc: dict[str, Any]) -> None:
        self.output = output
        self.template = (doc.get("tiles") or ["{z}/{x}/{y}.png"])[0]
        self._file = None
        if not output.is_dir():
            from pmtiles.reader import MmapSource, Reader

            self._file = open(output, "rb")
            self._reader = Reader(MmapSource(self._file))

    def get(self, z: int, x: int, y: int) -> bytes | None:
        if self._file is None:
            path = self.output / self.template.format(z=z, x=x, y=y)
            return path.read_bytes() if path.is_file() else None
        return self._reader.get(z, x, y)

    def unlisted(self, addresses: list[tuple[int, int, int]]) -> int:
        """Tiles of the folder that the TileJSON does not list (0 for an archive: its
        directory is the list)."""
        if self._file is not None:
            return 0
        ext = self.template.rsplit(".", 1)[-1]
        names = {self.output / self.template.format(z=z, x=x, y=y) for z, x, y in addresses}
        return len({p for p in self.output.rglob(f"*.{ext}")} - names)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()


def verify_map_tiles(output: Path, terrain: Any, report: VerifyReport) -> None:
    """Run the checks of the module docstring on a tile folder or archive."""
    from PIL import Image

    doc = read_tilejson(output)
    meta = doc.get("approxtree") or {}
    kind = meta.get("kind")
    size = int(meta.get("tile_size", 256))
    addresses = listed(doc)
    tiles = _Tiles(output, doc)
    check = report.check("tiles", "every tile the TileJSON lists exists and decodes")
    check.items = len(addresses)
    report.figures["tiles"] = len(addresses)
    report.figures["tiling"] = meta.get("tiling")
    measure = None
    if kind == "raster-dem" and terrain is not None:
        measure = _Heights(terrain, meta, report)
    elif kind == "imagery":
        report.not_checked.append("imagery colours (the texture pyramid is verified on its own)")
    try:
        report.figures["unlisted_tiles"] = tiles.unlisted(addresses)
        for z, x, y in addresses:
            address = f"{z}/{x}/{y}"
            data = tiles.get(z, x, y)
            if data is None:
                check.fail(address, "a tile", "missing")
                continue
            try:
                with Image.open(io.BytesIO(data)) as image:
                    image.load()
                    pixels = np.asarray(image)
                    mode = image.mode
            except Exception as exc:  # Pillow: damaged in any way
                check.fail(address, "decodes", f"{type(exc).__name__}: {exc}"[:120])
                continue
            want = "RGB" if kind == "raster-dem" else None
            if pixels.shape[:2] != (size, size) or (want and mode != want):
                check.fail(address, f"{size}×{size} {want or ''}".strip(), f"{mode} {pixels.shape}")
                continue
            if measure is not None:
                measure.tile(address, z, x, y, pixels)
    finally:
        tiles.close()
    if measure is not None:
        measure.finish()


@lru_cache(maxsize=4)
def _transformer(source: str, target: str):
    from pyproj import Transformer

    return Transformer.from_crs(source, target, always_xy=True)


class _Heights:
    """Decoded raster-dem heights against h_T at the pixels' centres."""

    def __init__(self, terrain: Any, meta: dict[str, Any], report: VerifyReport) -> None:
        from approxtree.geometry.grid import Grid

        if not isinstance(terrain, Grid) or not terrain.crs:
            raise StoreError(
                "raster-dem tiles are checked against a georeferenced raster DEM (the one they "
                "were made from); give it with --source."
            )
        encoding = meta.get("encoding")
        if encoding not in DECODING:
            raise StoreError(f"The TileJSON names an unknown raster-dem encoding {encoding!r}.")
        self.scale, self.offset = DECODING[encoding]
        self.step = 1.0 / self.scale
        self.tiling = meta.get("tiling", "webmercator")
        self.grid = terrain
        self.report = report
        self.check = report.check(
            "heights",
            f"every decoded height is within the {encoding} step ({self.step:g} m) of h_T at "
            "the pixel's centre",
        )
        self.measured = 0
        self.left_out = 0
        self.worst = 0.0

    def _centres(self, z: int, x: int, y: int, size: int) -> tuple[np.ndarray, np.ndarray]:
        """(lon, lat) degrees (size, size) of the pixel centres, row 0 north."""
        t = (np.arange(size) + 0.5) / size
        if self.tiling == "geographic":
            n = 2**z
            lon = -180.0 + 180.0 * (x + t) / n
            lat = -90.0 + 180.0 * (y + 1 - t) / n
        else:
            n = 2**z
            lon = -180.0 + 360.0 * (x + t) / n
            lat = np.degrees(np.arctan(np.sinh(math.pi * (1.0 - 2.0 * (y + t) / n))))
        return np.meshgrid(lon, lat)

    def _h_t(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """h_T at lon/lat points (NaN outside the domain or in a triangle touching nodata)."""
        px, py = _transformer("EPSG:4326", self.grid.crs).transform(lon, lat)
        fr, fc = world_to_index(self.grid, np.asarray(px), np.asarray(py))
        rows, cols = self.grid.shape
        out = np.full(fr.shape, np.nan)
        ok = np.isfinite(fr) & np.isfinite(fc)
        ok &= (fr >= 0) & (fr <= rows - 1) & (fc >= 0) & (fc <= cols - 1)
        if not ok.any():
            return out
        r = np.minimum(np.floor(fr[ok]).astype(np.int64), rows - 2)
        c = np.minimum(np.floor(fc[ok]).astype(np.int64), cols - 2)
        # The four data points around each centre, read by index (a windowed DEM reads only
        # the blocks they fall in).
        corners = np.asarray(
            self.grid.heights[np.concatenate([r, r, r + 1, r + 1]), np.concatenate([c, c + 1] * 2)],
            dtype=np.float64,
        ).reshape(4, -1)
        z00, z01, z10, z11 = corners
        a, b = fr[ok] - r, fc[ok] - c
        # h_T is linear on the two triangles of each cell, cut by the diagonal from (r, c) to
        # (r + 1, c + 1): (00, 01, 11) where b >= a, else (00, 11, 10).
        upper = z00 + b * (z01 - z00) + a * (z11 - z01)
        lower = z00 + a * (z10 - z00) + b * (z11 - z10)
        out[ok] = np.where(b >= a, upper, lower)
        return out

    def tile(self, address: str, z: int, x: int, y: int, pixels: np.ndarray) -> None:
        size = pixels.shape[0]
        rgb = pixels.astype(np.float64)
        decoded = (rgb[..., 0] * 65536 + rgb[..., 1] * 256 + rgb[..., 2]) / self.scale - self.offset
        h = self._h_t(*self._centres(z, x, y, size))
        known = np.isfinite(h)
        self.left_out += int(size * size - known.sum())
        if not known.any():
            return
        err = np.abs(decoded[known] - h[known])
        self.measured += int(known.sum())
        i = int(np.argmax(err))
        worst = float(err[i])
        self.worst = max(self.worst, worst)
        self.check.items += 1
        # The step, and float64 round-off of heights of this size.
        if worst > self.step + 1e-9 * (1.0 + float(np.abs(h[known]).max())):
            r, c = np.argwhere(known)[i]
            self.check.fail(f"tile {address} pixel ({r}, {c})", self.step, worst, worst - self.step)

    def finish(self) -> None:
        self.report.figures["pixels_measured"] = self.measured
        self.report.figures["pixels_left_out"] = self.left_out
        self.report.figures["worst_height_error"] = self.worst
        self.report.figures["step"] = self.step
