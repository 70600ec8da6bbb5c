"""Cesium's geographic tiling (TMS, EPSG:4326) and the geometric error of each level.

Level 0 has 2 × 1 tiles of 180°; tile (z, x, y) is 180 / 2^z degrees wide, x counts from the
west (−180°), y from the SOUTH (−90°). The tile address arithmetic itself lives beside the
quantized-mesh reader (``io.quantized_mesh.tile_bounds``); here: which tiles a terrain's
footprint touches, how deep to go, and the error CesiumJS assumes at each level.
"""

from __future__ import annotations

import math

import numpy as np

from approxtree.io.quantized_mesh import tile_bounds

#: WGS84 semi-major axis (CesiumJS's ellipsoid.maximumRadius), metres.
WGS84_A = 6378137.0
#: CesiumJS's levelMaximumGeometricError at level 0 for this tiling:
#: maximumRadius · 2π · 0.25 / (65 · 2) (TerrainProvider.getEstimatedLevelZeroGeometricError-
#: ForAHeightmap with a 65-sample tile and 2 tiles across at level 0), about 77 067 m.
LEVEL_ZERO_ERROR = WGS84_A * 2.0 * math.pi * 0.25 / (65 * 2)
#: Deepest level written (tiles of 0.00004°, a few metres).
MAX_LEVEL = 22


def level_error(level: int) -> float:
    """CesiumJS's geometric error of a tile of ``level`` in metres: every tile of the level is
    built to this error (it is what CesiumJS's screen-space error test assumes)."""
    return LEVEL_ZERO_ERROR / 2**level


def tile_size(level: int) -> float:
    """Width (= height) of a tile of ``level`` in degrees."""
    return 180.0 / 2**level


def tile_range(bounds: tuple[float, float, float, float], level: int) -> tuple[int, int, int, int]:
    """(x0, x1, y0, y1) inclusive: the tiles of ``level`` that the lon/lat box touches."""
    west, south, east, north = bounds
    size = tile_size(level)
    nx, ny = 2 ** (level + 1), 2**level
    x0 = min(max(math.floor((west + 180.0) / size), 0), nx - 1)
    x1 = min(max(math.ceil((east + 180.0) / size) - 1, x0), nx - 1)
    y0 = min(max(math.floor((south + 90.0) / size), 0), ny - 1)
    y1 = min(max(math.ceil((north + 90.0) / size) - 1, y0), ny - 1)
    return x0, x1, y0, y1


def tiles_touching(footprint, level: int) -> list[tuple[int, int]]:
    """(x, y) of the tiles of ``level`` whose closed square meets the footprint (a shapely
    polygon in lon/lat degrees). A tile that misses it has no descendant that meets it, so
    the written tiles form a quadtree at every depth."""
    from shapely import box, intersects

    x0, x1, y0, y1 = tile_range(footprint.bounds, level)
    gx, gy = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1), indexing="ij")
    xs, ys = gx.ravel(), gy.ravel()
    size = tile_size(level)
    squares = box(
        -180.0 + xs * size, -90.0 + ys * size, -180.0 + (xs + 1) * size, -90.0 + (ys + 1) * size
    )
    keep = intersects(squares, footprint)
    return [(int(x), int(y)) for x, y in zip(xs[keep], ys[keep], strict=True)]


def deepest_level(cell_degrees: float, samples: int) -> int:
    """The first level whose sample spacing (tile width / (samples − 1)) is no wider than the
    terrain's cell (in degrees); at most MAX_LEVEL."""
    for level in range(MAX_LEVEL + 1):
        if tile_size(level) / (samples - 1) <= cell_degrees:
            return level
    return MAX_LEVEL


__all__ = [
    "LEVEL_ZERO_ERROR",
    "MAX_LEVEL",
    "deepest_level",
    "level_error",
    "tile_bounds",
    "tile_range",
    "tile_size",
    "tiles_touching",
]
