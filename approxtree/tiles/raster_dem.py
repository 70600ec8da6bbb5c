"""raster-dem tiles for MapLibre GL JS (and Mapbox): Terrarium or Terrain-RGB, Web Mercator.

``DemTiles(terrain, encoding)`` makes tile (z, x, y) of Web Mercator XYZ (``schemes``) as a
lossless PNG or WEBP of ``tile_size`` pixels (512 by default, mapterhorn's choice; 256 too):

- every pixel holds h_T at the pixel's centre (``schemes.TileScheme.pixel_centres``; the
  centre carried into the terrain's CRS by pyproj and h_T interpolated there by the sampler
  quantized-mesh tiles use, ``sampling.TileSampler.heights_at``: linear on the grid's
  triangles), rounded to the encoding's
  step, so every decoded height is within half a step of h_T there (``approxtree verify``
  checks it within a step);
- overviews (every zoom from minzoom up) are sampled the same way, at their own pixels'
  centres: a coarser tile is h_T at fewer points, never an average;
- outside the terrain's domain the terrain's edge is carried outward over a band of 1.5
  pixels (at least 2 cells), then 0 m, as in the quantized-mesh tiles; nodata is 0 m, as
  mapterhorn writes it.

Encodings (RGB, alpha-free): Terrarium, h = R·256 + G + B/256 − 32768 (step 1/256 m, range
−32768..32768 m); Terrain-RGB (MapLibre's "mapbox"), h = −10000 + (R·65536 + G·256 + B)·0.1
(step 0.1 m). The default deepest zoom is the first whose pixels are no larger than the
terrain's cell at its centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.tiles.map_tiles import check_zooms, encode_image
from approxtree.tiles.sampling import FILL_HEIGHT, TileSampler
from approxtree.tiles.schemes import SCHEMES, ground_metres

#: Tile side (pixels) by default: mapterhorn's.
DEFAULT_TILE_SIZE = 512


@dataclass(frozen=True)
class DemEncoding:
    """h = q / scale − offset for the 24-bit integer q = R·65536 + G·256 + B."""

    name: str
    #: MapLibre's name of it (the raster-dem source's ``encoding``).
    maplibre: str
    offset: float
    scale: float

    @property
    def range(self) -> tuple[float, float]:
        """Lowest and highest heights the 24 bits hold (m)."""
        return -self.offset, ((1 << 24) - 1) / self.scale - self.offset

    @property
    def step(self) -> float:
        """Height between two consecutive codes (m)."""
        return 1.0 / self.scale

    def encode(self, heights: np.ndarray) -> np.ndarray:
        """(h, w) float64 heights → (h, w, 3) uint8 RGB, each the nearest code (clipped to the
        encoding's range)."""
        q = np.rint((np.asarray(heights, dtype=np.float64) + self.offset) * self.scale)
        q = np.clip(q, 0, (1 << 24) - 1).astype(np.int64)
        return np.stack([q >> 16, (q >> 8) & 255, q & 255], axis=-1).astype(np.uint8)


ENCODINGS = {
    "terrarium": DemEncoding("terrarium", "terrarium", 32768.0, 256.0),
    "terrain-rgb": DemEncoding("terrain-rgb", "mapbox", 10000.0, 10.0),
}


class DemTiles:
    """raster-dem tiles of a georeferenced height grid (a ``map_tiles.MapTiles`` source).

    terrain: a Grid with a CRS (in memory or windowed, e.g. a tree store's); encoding:
    terrarium or terrain-rgb; tile_size: 256 or 512; image_format: png or webp (lossless);
    minzoom, maxzoom (None: the zoom of the terrain's cell).
    """

    def __init__(
        self,
        terrain: Any,
        encoding: str = "terrarium",
        tile_size: int = DEFAULT_TILE_SIZE,
        image_format: str = "png",
        minzoom: int = 0,
        maxzoom: int | None = None,
    ) -> None:
        if encoding not in ENCODINGS:
            raise InvalidParameterError(
                f"Unknown raster-dem encoding {encoding!r}; use terrarium or terrain-rgb."
            )
        if image_format not in ("png", "webp"):
            raise InvalidParameterError(
                f"raster-dem tiles are lossless PNG or WEBP, got {image_format!r} (a lossy "
                "image would change the heights)."
            )
        if tile_size not in (256, 512):
            raise InvalidParameterError(f"tile_size must be 256 or 512, got {tile_size!r}.")
        self.sampler = TileSampler(terrain)
        self.encoding = ENCODINGS[encoding]
        low, high = self.encoding.range
        z_min, z_max = (float(v) for v in terrain.z_range)
        if z_min < low or z_max > high:
            raise InvalidParameterError(
                f"The terrain's heights {z_min:g}..{z_max:g} m leave {encoding}'s range "
                f"{low:g}..{high:g} m; choose the other encoding, or rescale the heights "
                "(--height-scale)."
            )
        self.scheme = SCHEMES["webmercator"]
        self.tile_size = tile_size
        self.image_format = image_format
        d = terrain.domain
        dx, dy = terrain.cell_size
        cx, cy = d.center
        #: Ground size (m) of the terrain's cell and the latitude where it was measured.
        self.cell_metres, self.latitude = ground_metres(terrain.crs, cx, cy, dx, dy)
        self.minzoom = minzoom
        self.maxzoom = (
            maxzoom
            if maxzoom is not None
            else max(self.scheme.zoom_for(self.cell_metres, tile_size, self.latitude), minzoom)
        )
        check_zooms(self.minzoom, self.maxzoom)

    @property
    def footprint(self):
        return self.sampler.footprint

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "raster-dem",
            "encoding": self.encoding.name,
            "maplibre_encoding": self.encoding.maplibre,
            "step": self.encoding.step,
        }

    def heights(self, z: int, x: int, y: int) -> np.ndarray:
        """(size, size) float64 heights of tile (z, x, y)'s pixel centres, as encoded before
        rounding (module docstring)."""
        if not self.scheme.exists(z, x, y):
            raise InvalidParameterError(f"Tile {z}/{x}/{y} is outside Web Mercator's tiling.")
        size = self.tile_size
        out = np.full((size, size), FILL_HEIGHT)
        # The pixels near the terrain only: beyond the edge band every height is FILL_HEIGHT.
        spacing = 360.0 / (1 << z) / size
        band = self.sampler.edge_band(spacing) * self.sampler.cell_degrees
        west, south, east, north = self.footprint.bounds
        widen = band / max(math.cos(math.radians(max(abs(south), abs(north)))), 1e-3) + spacing
        box = (west - widen, south - widen, east + widen, north + widen)
        rows, cols = self.scheme.pixel_span(z, x, y, size, box)
        if rows.start >= rows.stop or cols.start >= cols.stop:
            return out
        lon, lat = self.scheme.pixel_centres(z, x, y, size, rows, cols)
        h, _, _ = self.sampler.heights_at(lon, lat, spacing)
        out[rows, cols] = np.where(np.isnan(h), FILL_HEIGHT, h)
        return out

    def tile(self, z: int, x: int, y: int) -> bytes:
        """Tile (z, x, y): the encoded heights as a lossless PNG or WEBP."""
        rgb = self.encoding.encode(self.heights(z, x, y))
        return encode_image(rgb, self.image_format, lossless=True)
