"""The two tilings of web maps: geographic TMS (CesiumJS) and Web Mercator XYZ (MapLibre).

A ``TileScheme`` says where tile (z, x, y) lies on the globe, where the centres of its pixels
are, which tiles of a zoom meet a footprint, and how deep to go for a given ground size:

- ``geographic``: EPSG:4326, 2 × 1 tiles at zoom 0, each 180 / 2^z degrees square, x from the
  west (−180°), y from the SOUTH (−90°) — Cesium's GeographicTilingScheme with TMS rows (its
  UrlTemplateImageryProvider reads them as ``{reverseY}``), the tiling of quantized-mesh.
- ``webmercator``: EPSG:3857, one tile at zoom 0, x from the west, y from the NORTH, latitudes
  within ±85.0511° — the slippy-map ``{z}/{x}/{y}`` of MapLibre, Leaflet and OpenLayers.

Pixel (row i, column j) of a tile of ``size`` pixels covers [j, j + 1] × [i, i + 1] of the
tile's square, row 0 at the north; its value stands for the point at the pixel's centre
(j + ½, i + ½), GDAL's and mapterhorn's convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from approxtree.errors import InvalidParameterError

#: WGS84 semi-major axis (m): Web Mercator's sphere.
EARTH_RADIUS = 6378137.0
#: Deepest zoom written (tiles of a few metres).
MAX_ZOOM = 24
#: Web Mercator's latitude limit (degrees): the square's north and south edges.
MERCATOR_MAX_LAT = math.degrees(math.atan(math.sinh(math.pi)))
#: Every row or column of a tile.
ALL = slice(None)


@dataclass(frozen=True)
class TileScheme:
    """One of the two tilings (module docstring); ``SCHEMES`` holds both."""

    name: str
    #: Tiles across (x) and down (y) at zoom 0.
    columns: int
    rows: int
    #: Whether row 0 is the north row (XYZ) rather than the south one (TMS).
    north_first: bool

    def count(self, z: int) -> tuple[int, int]:
        """(columns, rows) of tiles at zoom ``z``."""
        return self.columns << z, self.rows << z

    def exists(self, z: int, x: int, y: int) -> bool:
        """Whether (z, x, y) names a tile of this scheme (zoom 0..MAX_ZOOM)."""
        if not 0 <= z <= MAX_ZOOM:
            return False
        nx, ny = self.count(z)
        return 0 <= x < nx and 0 <= y < ny

    def _fraction_north(self, z: int, y: float) -> float:
        """Fraction (0 at the north edge, 1 at the south) of the scheme's square at row y."""
        ny = self.rows << z
        return y / ny if self.north_first else 1.0 - y / ny

    def latitude(self, t: np.ndarray | float) -> np.ndarray:
        """Latitudes (degrees) at fractions ``t`` of the square's height from its north edge."""
        t = np.asarray(t, dtype=np.float64)
        if self.name == "geographic":
            return 90.0 - 180.0 * t
        return np.degrees(np.arctan(np.sinh(math.pi * (1.0 - 2.0 * t))))

    def fraction_of_latitude(self, lat: np.ndarray | float) -> np.ndarray:
        """The inverse of ``latitude``: fractions from the north edge (clipped to 0..1)."""
        lat = np.asarray(lat, dtype=np.float64)
        if self.name == "geographic":
            t = (90.0 - lat) / 180.0
        else:
            phi = np.radians(np.clip(lat, -MERCATOR_MAX_LAT, MERCATOR_MAX_LAT))
            t = (1.0 - np.arcsinh(np.tan(phi)) / math.pi) / 2.0
        return np.clip(t, 0.0, 1.0)

    def bounds(self, z: int, x: int, y: int) -> tuple[float, float, float, float]:
        """(west, south, east, north) degrees of tile (z, x, y)."""
        nx = self.columns << z
        west, east = -180.0 + 360.0 * x / nx, -180.0 + 360.0 * (x + 1) / nx
        a = self._fraction_north(z, y)
        b = self._fraction_north(z, y + 1)
        north, south = (float(v) for v in self.latitude(np.array([min(a, b), max(a, b)])))
        return west, south, east, north

    def pixel_centres(
        self, z: int, x: int, y: int, size: int, rows: slice = ALL, cols: slice = ALL
    ) -> tuple[np.ndarray, np.ndarray]:
        """(lon, lat) degrees, each (r, c) float64, of the centres of the pixels ``rows`` ×
        ``cols`` (default all ``size`` × ``size``) of tile (z, x, y), row 0 at the north."""
        nx, ny = self.count(z)
        i = np.arange(size, dtype=np.float64)[rows] + 0.5
        j = np.arange(size, dtype=np.float64)[cols] + 0.5
        lon = -180.0 + 360.0 * (x + j / size) / nx
        top = y if self.north_first else ny - 1 - y
        lat = self.latitude((top + i / size) / ny)
        return np.broadcast_to(lon, (len(i), len(j))), np.broadcast_to(
            lat[:, None], (len(i), len(j))
        )

    def pixel_span(
        self,
        z: int,
        x: int,
        y: int,
        size: int,
        box: tuple[float, float, float, float],
        margin: int = 1,
    ) -> tuple[slice, slice]:
        """(rows, cols) slices of the pixels of tile (z, x, y) whose centres may lie in the
        lon/lat ``box`` (west, south, east, north), ``margin`` pixels more on each side."""
        nx, ny = self.count(z)
        west, south, east, north = box
        c0 = math.floor((west + 180.0) / 360.0 * nx * size - x * size) - margin
        c1 = math.ceil((east + 180.0) / 360.0 * nx * size - x * size) + margin
        top = y if self.north_first else ny - 1 - y
        r0 = math.floor(float(self.fraction_of_latitude(north)) * ny * size - top * size) - margin
        r1 = math.ceil(float(self.fraction_of_latitude(south)) * ny * size - top * size) + margin
        clip = lambda a: min(max(a, 0), size)  # noqa: E731
        return slice(clip(r0), clip(r1)), slice(clip(c0), clip(c1))

    def tiles_touching(self, footprint, z: int) -> list[tuple[int, int]]:
        """(x, y) of the tiles of zoom ``z`` whose closed lon/lat box meets the footprint (a
        shapely polygon in degrees), in row-major order of their boxes from the north-west."""
        from shapely import box, intersects

        nx, ny = self.count(z)
        west, south, east, north = footprint.bounds
        x0 = min(max(math.floor((west + 180.0) / 360.0 * nx), 0), nx - 1)
        x1 = min(max(math.ceil((east + 180.0) / 360.0 * nx) - 1, x0), nx - 1)
        t0 = float(self.fraction_of_latitude(north)) * ny
        t1 = float(self.fraction_of_latitude(south)) * ny
        r0 = min(max(math.floor(t0), 0), ny - 1)
        r1 = min(max(math.ceil(t1) - 1, r0), ny - 1)
        rows = np.arange(r0, r1 + 1)
        ys = rows if self.north_first else ny - 1 - rows
        grid_x, grid_y = np.meshgrid(np.arange(x0, x1 + 1), ys, indexing="xy")
        xs, ys = grid_x.ravel(), grid_y.ravel()
        edges = [self.bounds(z, int(a), int(b)) for a, b in zip(xs, ys, strict=True)]
        if not edges:
            return []
        w, s, e, n = np.array(edges).T
        keep = intersects(box(w, s, e, n), footprint)
        return [(int(a), int(b)) for a, b in zip(xs[keep], ys[keep], strict=True)]

    def pixel_metres(self, z: int, size: int, lat: float) -> float:
        """Ground size (m) of a pixel of zoom ``z`` at latitude ``lat``, north to south for
        the geographic scheme (its pixels are square in degrees), either way for Web Mercator
        (its pixels are square on the ground)."""
        if self.name == "geographic":
            return math.pi * EARTH_RADIUS / (self.rows << z) / size
        return 2.0 * math.pi * EARTH_RADIUS * math.cos(math.radians(lat)) / (1 << z) / size

    def zoom_for(self, metres: float, size: int, lat: float) -> int:
        """The first zoom whose pixels (at latitude ``lat``) are no larger than ``metres``."""
        for z in range(MAX_ZOOM + 1):
            if self.pixel_metres(z, size, lat) <= metres:
                return z
        return MAX_ZOOM


SCHEMES = {
    "geographic": TileScheme("geographic", 2, 1, north_first=False),
    "webmercator": TileScheme("webmercator", 1, 1, north_first=True),
}


def scheme_named(name: str) -> TileScheme:
    """The TileScheme ``name``; InvalidParameterError naming both otherwise."""
    if name not in SCHEMES:
        raise InvalidParameterError(
            f"Unknown tile scheme {name!r}: use geographic (CesiumJS, TMS) or webmercator "
            "(MapLibre, Leaflet: XYZ)."
        )
    return SCHEMES[name]


def ground_metres(crs: str, x: float, y: float, dx: float, dy: float) -> tuple[float, float]:
    """(metres, latitude): the ground length (geodesic, WGS84) of the shorter of the steps
    (dx, 0) and (0, dy) from (x, y) in ``crs`` — a cell or texel — and the latitude there."""
    from pyproj import Geod, Transformer

    to_lonlat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = to_lonlat.transform(np.array([x, x + dx, x]), np.array([y, y, y + dy]))
    geod = Geod(ellps="WGS84")
    _, _, d = geod.inv(lon[[0, 0]], lat[[0, 0]], lon[[1, 2]], lat[[1, 2]])
    return float(np.min(d)), float(lat[0])
