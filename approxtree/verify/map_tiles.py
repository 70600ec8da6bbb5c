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

- ``colours`` (imagery with its texture pyramid, ``--textures``): every pixel against the
  pyramid resampled at the pixel's centre as the imagery tiles' specification says, within
  ``COLOUR_TOLERANCE`` of the tile's format (``_Colours``).
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
from approxtree.verify.level_file import LevelFile
from approxtree.verify.measure import world_to_index
from approxtree.verify.report import VerifyReport

#: Decoding of each raster-dem encoding: h = (R·65536 + G·256 + B) / scale − offset.
DECODING = {"terrarium": (256.0, 32768.0), "terrain-rgb": (10.0, 10000.0)}
PMTILES_MAGIC = b"PMTiles"
#: Spherical radius of Web Mercator and of the tiles' pixel sizes (m).
EARTH_RADIUS = 6378137.0
#: Image format → (mean over a tile, worst) difference of its premultiplied channels (0..255)
#: from the pyramid resampled: rounding (the tile's 8 bits, the pyramid's halvings, here
#: recomputed in float; measured worst 1.7) for PNG; the codec's loss besides for WEBP and
#: JPEG at quality 90, whose worst is ringing at the texture's edge against transparency or
#: black (measured 11 and 77, means below 0.2): for them the mean is the check, the worst
#: only catches a gross error.
COLOUR_TOLERANCE = {"png": (0.5, 3.0), "webp": (2.0, 96.0), "jpeg": (2.0, 128.0)}


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


def verify_map_tiles(
    output: Path, terrain: Any, report: VerifyReport, textures: Any = None
) -> None:
    """Run the checks of the module docstring on a tile folder or archive; ``textures``: the
    texture pyramid (folder, TexturePyramid or DetailTextures) imagery tiles were cut from."""
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
    measure: _Heights | _Colours | None = None
    if kind == "raster-dem" and terrain is not None:
        measure = _Heights(terrain, meta, report)
    elif kind == "imagery" and textures is not None:
        if meta.get("detail_zoom") is not None and drape_folders(textures)[1] is None:
            # Tiles with a detail pyramid laid over: its pixels are not the base's.
            report.not_checked.append(
                f"imagery colours: the tiles lay a detail pyramid over the base from zoom "
                f"{meta['detail_zoom']}; give both (--textures BASE --textures "
                f"DETAIL@{meta['detail_zoom']})"
            )
        else:
            measure = _Colours(textures, meta, report)
    elif kind == "imagery":
        report.not_checked.append("imagery colours: give the texture pyramid (--textures)")
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
        h = self._h_t(*pixel_centres(self.tiling, z, x, y, size))
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


def pixel_centres(tiling: str, z: int, x: int, y: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(lon, lat) degrees (size, size) of the pixel centres of tile (z, x, y), row 0 north:
    the geographic tiling (2 × 1 tiles at zoom 0, rows from the south) or Web Mercator XYZ."""
    t = (np.arange(size) + 0.5) / size
    n = 2**z
    if tiling == "geographic":
        lon = -180.0 + 180.0 * (x + t) / n
        lat = -90.0 + 180.0 * (y + 1 - t) / n
    else:
        lon = -180.0 + 360.0 * (x + t) / n
        lat = np.degrees(np.arctan(np.sinh(math.pi * (1.0 - 2.0 * (y + t) / n))))
    return np.meshgrid(lon, lat)


class _Sampler:
    """One texture pyramid resampled as the imagery tiles' specification says
    (docs/guide/publish.md):

    1. the level: the coarsest whose level-0-relative texel (geodesic ground length of a
       level-0 texel at the pyramid's centre, × 2^k) is no larger than the tile's pixel
       (2πR·cos(lat) / 2^z / size for Web Mercator at the tile's middle latitude, πR / 2^z /
       size for the geographic tiling; R = 6378137 m), 0 when none is; where that level's
       texels are still more than twice finer than the pixel, blocks of f × f texels (f a
       power of two) are first averaged, alpha-weighted;
    2. bilinear at the pixel's centre (taken into the pyramid's CRS by pyproj) between the
       four texel centres around it, colours premultiplied by alpha, texels beyond the level
       transparent.
    """

    def __init__(self, folder: Path, tiling: str) -> None:
        try:
            doc = json.loads((folder / "pyramid.json").read_text())
            self.levels = list(doc["levels"])
            self.bands = int(doc["bands"])
            self.crs = doc["crs"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise StoreError(f"{folder}: not a readable texture pyramid ({exc}).") from exc
        if not self.crs:
            raise StoreError(f"{folder}: the texture pyramid has no CRS to place it with.")
        self.folder = folder
        self.tiling = tiling
        t = self.levels[0]["transform"]
        cx = t[2] + t[0] * int(self.levels[0]["width"]) / 2
        cy = t[5] + t[4] * int(self.levels[0]["height"]) / 2
        self.texel_metres = _texel_metres(self.crs, cx, cy, t[0], t[4])
        self._files: dict[int, Any] = {}

    def choices(self, z: int, y: int, size: int) -> list[tuple[int, int]]:
        """(level, block factor) the tile may sample: the rule's, and its neighbour when the
        pixel size lies within 1 % of a boundary."""
        n = 2**z
        if self.tiling == "geographic":
            pixel = math.pi * EARTH_RADIUS / n / size
        else:
            north = math.atan(math.sinh(math.pi * (1 - 2 * y / n)))
            south = math.atan(math.sinh(math.pi * (1 - 2 * (y + 1) / n)))
            pixel = 2 * math.pi * EARTH_RADIUS * math.cos((north + south) / 2) / n / size
        out = []
        log = math.log2(pixel / self.texel_metres)
        for shift in (0.0, -0.01, 0.01):
            ratio = 2 ** (log + shift)
            k = min(max(math.floor(math.log2(ratio)), 0), len(self.levels) - 1) if ratio >= 1 else 0
            rest = ratio / 2**k
            choice = (k, 2 ** math.floor(math.log2(rest)) if rest >= 2 else 1)
            if choice not in out:
                out.append(choice)
        return out

    def _level(self, k: int):
        if k not in self._files:
            # The level's texels as a re-baked pyramid holds them (its deltas read over it).
            self._files[k] = LevelFile(self.folder, self.levels[k])
        return self._files[k]

    def expected(self, k: int, factor: int, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """(r, c, 4) float64 premultiplied RGBA of level k (blocks of ``factor``) bilinear at
        the CRS points (r, c) (the class docstring)."""
        from rasterio.windows import Window

        t = self.levels[k]["transform"]
        width, height = int(self.levels[k]["width"]), int(self.levels[k]["height"])
        # Texel coordinates of the (block-averaged) level, texel centres at integers.
        u = ((px - t[2]) / t[0]) / factor - 0.5
        v = ((py - t[5]) / t[4]) / factor - 0.5
        out = np.zeros((*px.shape, 4))
        ok = np.isfinite(u) & np.isfinite(v)
        if not ok.any():
            return out
        bw, bh = -(-width // factor), -(-height // factor)
        c0 = int(np.clip(np.floor(u[ok].min()), 0, bw - 1))
        c1 = int(np.clip(np.floor(u[ok].max()) + 2, 1, bw))
        r0 = int(np.clip(np.floor(v[ok].min()), 0, bh - 1))
        r1 = int(np.clip(np.floor(v[ok].max()) + 2, 1, bh))
        ds = self._level(k)
        raw = ds.read(
            window=Window(c0 * factor, r0 * factor, (c1 - c0) * factor, (r1 - r0) * factor),
            boundless=True,
            fill_value=0,
        ).astype(np.float64)
        rgba = _as_rgba(raw)
        # Premultiplied; f × f blocks averaged (the alpha-weighted mean, premultiplied).
        rgba[:3] *= rgba[3] / 255.0
        if factor > 1:
            b, h, w = rgba.shape
            rgba = rgba.reshape(b, h // factor, factor, w // factor, factor).mean(axis=(2, 4))
        # One transparent texel around: beyond the level, colours fade to nothing.
        rgba = np.pad(rgba, ((0, 0), (1, 1), (1, 1)))
        uu = u - c0 + 1.0
        vv = v - r0 + 1.0
        inside = ok & (uu >= 0) & (vv >= 0) & (uu <= rgba.shape[2] - 1) & (vv <= rgba.shape[1] - 1)
        uu = np.where(inside, uu, 0.0)
        vv = np.where(inside, vv, 0.0)
        iu = np.minimum(np.floor(uu).astype(np.int64), rgba.shape[2] - 2)
        iv = np.minimum(np.floor(vv).astype(np.int64), rgba.shape[1] - 2)
        du, dv = uu - iu, vv - iv
        for dr, dc, weight in ((0, 0, (1 - dv) * (1 - du)), (0, 1, (1 - dv) * du),
                               (1, 0, dv * (1 - du)), (1, 1, dv * du)):  # fmt: skip
            out += np.moveaxis(rgba[:, iv + dr, iu + dc], 0, -1) * weight[..., None]
        out[~inside] = 0.0
        return out

    def candidates(self, z: int, x: int, y: int, size: int) -> list[np.ndarray]:
        """The (size, size, 4) premultiplied pixels of tile (z, x, y) for each level it may
        sample (``choices``)."""
        lon, lat = pixel_centres(self.tiling, z, x, y, size)
        px, py = _transformer("EPSG:4326", self.crs).transform(lon, lat)
        px, py = np.asarray(px), np.asarray(py)
        return [self.expected(k, f, px, py) for k, f in self.choices(z, y, size)]

    def close(self) -> None:
        for ds in self._files.values():
            ds.close()


def drape_folders(textures: Any) -> tuple[Path, tuple[Path, int] | None]:
    """(base folder, (detail folder, zoom) or None) of ``textures``: a pyramid folder, an open
    TexturePyramid, or a DetailTextures (a detail laid over its base from zoom ``level``)."""
    detail = getattr(textures, "detail", None)
    if detail is not None:
        return Path(textures.base.folder), (Path(detail.folder), int(textures.level))
    return Path(getattr(textures, "folder", textures)), None


class _Colours:
    """Imagery tiles' pixels against the texture pyramid they were cut from, resampled here
    (``_Sampler``); from the detail's zoom on, the detail pyramid's pixels laid over the
    base's (premultiplied Porter-Duff over), as the writer does.

    Compared premultiplied (what a client composites; JPEG has the texture over black), per
    channel 0..255, the tolerance ``tolerance(format)``: rounding of the tile's pixels and of
    the pyramid's own halvings for PNG, the codec's loss for WEBP and JPEG (a mean and a
    worst). A pixel size within 1 % of a level's boundary may have gone either way: the tile
    passes if either level matches.
    """

    def __init__(self, textures: Any, meta: dict[str, Any], report: VerifyReport) -> None:
        base, detail = drape_folders(textures)
        tiling = meta.get("tiling", "webmercator")
        self.base = _Sampler(base, tiling)
        self.detail = None if detail is None else _Sampler(detail[0], tiling)
        self.detail_zoom = 0 if detail is None else detail[1]
        self.format = meta.get("format", "png")
        self.mean_limit, self.worst_limit = COLOUR_TOLERANCE[self.format]
        self.report = report
        over = "" if detail is None else f", the detail's laid over it from zoom {detail[1]}"
        self.check = report.check(
            "colours",
            f"every pixel, premultiplied, within {self.worst_limit} (mean within "
            f"{self.mean_limit}) of the pyramid resampled at its centre{over}",
        )
        self.measured = 0
        self.worst = 0.0
        self.mean_sum = 0.0

    def tile(self, address: str, z: int, x: int, y: int, pixels: np.ndarray) -> None:
        size = pixels.shape[0]
        bands = pixels[None] if pixels.ndim == 2 else np.moveaxis(pixels, -1, 0)
        got = np.moveaxis(_as_rgba(bands.astype(np.float64)), 0, -1)
        got[..., :3] *= got[..., 3:] / 255.0
        wanted = self.base.candidates(z, x, y, size)
        if self.detail is not None and z >= self.detail_zoom:
            # Every pairing of the levels either pyramid may sample: the detail over the base.
            tops = self.detail.candidates(z, x, y, size)
            wanted = [top + low * (1.0 - top[..., 3:] / 255.0) for top in tops for low in wanted]
        # The smallest (worst, mean) difference over the levels the tile may sample.
        found = []
        for i, want in enumerate(wanted):
            if self.format == "jpeg":
                # No alpha in JPEG: the premultiplied colour is the texture over black.
                want[..., 3] = got[..., 3]
            diff = np.abs(got - want)
            found.append((float(diff.max()), float(diff.mean()), i, diff))
        worst, mean, _, diff = min(found, key=lambda f: f[:3])
        self.check.items += 1
        self.measured += size * size
        self.worst = max(self.worst, worst)
        self.mean_sum += mean * size * size
        if worst > self.worst_limit or mean > self.mean_limit:
            r, c, b = np.unravel_index(int(np.argmax(diff)), diff.shape)
            where = f"tile {address} pixel ({r}, {c}) channel {'RGBA'[b]}"
            self.check.fail(where, self.worst_limit, round(worst, 3), round(mean, 3))

    def finish(self) -> None:
        self.base.close()
        if self.detail is not None:
            self.detail.close()
        self.report.figures["pixels_measured"] = self.measured
        self.report.figures["worst_colour_difference"] = self.worst
        self.report.figures["mean_colour_difference"] = self.mean_sum / max(self.measured, 1)


def _as_rgba(bands: np.ndarray) -> np.ndarray:
    """(4, h, w) RGBA of (b, h, w) grey (1), grey + alpha (2), RGB (3) or RGBA (4) bands."""
    b = bands.shape[0]
    grey = bands[0]
    if b == 1:
        return np.stack([grey, grey, grey, np.full_like(grey, 255.0)])
    if b == 2:
        return np.stack([grey, grey, grey, bands[1]])
    if b == 3:
        return np.concatenate([bands, np.full_like(grey, 255.0)[None]])
    return bands[:4].copy()


def _texel_metres(crs: str, x: float, y: float, dx: float, dy: float) -> float:
    """Geodesic ground length (WGS84) of the shorter side of a texel (dx, dy) at (x, y)."""
    from pyproj import Geod

    lon, lat = _transformer(crs, "EPSG:4326").transform(
        np.array([x, x + dx, x]), np.array([y, y, y + dy])
    )
    _, _, d = Geod(ellps="WGS84").inv(lon[[0, 0]], lat[[0, 0]], lon[[1, 2]], lat[[1, 2]])
    return float(np.min(d))
