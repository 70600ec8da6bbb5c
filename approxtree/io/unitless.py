"""Grids read without a CRS whose coordinates look like degrees.

A grid without a CRS is drawn with x, y and z in the same unit. When its extent and cells are
those of longitudes and latitudes (a .npz, PGM or array export of a geographic DEM) and its
heights span many times its width, that reading is almost surely wrong: the terrain would be a
needle thousands of times taller than wide, a sliver no view frames. The reader then warns and
says how to give the CRS.
"""

from __future__ import annotations

import warnings

from approxtree.errors import TerrainDataWarning
from approxtree.geometry import Grid

#: Largest cell (x or y) read as a fraction of a degree: 0.1° is about 11 km.
DEGREE_CELL_LIMIT = 0.1
#: Heights spanning more than this many times the grid's larger side flag degree coordinates.
ASPECT_LIMIT = 10.0


def degree_aspect(grid: Grid) -> float | None:
    """Height span ÷ larger side of ``grid`` when it looks like degrees without a CRS: no CRS,
    within longitudes ±180 and latitudes ±90, cells of at most DEGREE_CELL_LIMIT and that ratio
    above ASPECT_LIMIT. None otherwise."""
    if grid.crs is not None:
        return None
    d = grid.domain
    if not (-180.0 <= d.xmin and d.xmax <= 180.0 and -90.0 <= d.ymin and d.ymax <= 90.0):
        return None
    if max(abs(c) for c in grid.cell_size) > DEGREE_CELL_LIMIT:
        return None
    # The z range last: a windowed raster finds it by a scan of its blocks.
    z_min, z_max = grid.z_range
    side = max(d.xmax - d.xmin, d.ymax - d.ymin)
    if side <= 0.0 or not (z_max - z_min) > ASPECT_LIMIT * side:
        return None
    return (z_max - z_min) / side


def warn_degrees_without_crs(grid: Grid, path: object) -> None:
    """TerrainDataWarning when ``grid`` (read from ``path``) looks like degrees without a CRS."""
    aspect = degree_aspect(grid)
    if aspect is None:
        return
    d = grid.domain
    z_min, z_max = grid.z_range
    cx, cy = (abs(c) for c in grid.cell_size)
    warnings.warn(
        f"{path} has no CRS, and its coordinates look like degrees (cells of {cx:.6g} × "
        f"{cy:.6g}, {d.xmax - d.xmin:.4g} × {d.ymax - d.ymin:.4g} wide, heights spanning "
        f"{z_max - z_min:.6g}): read in one unit it is {aspect:,.0f}× taller than wide and no "
        "view shows it. Give its CRS: --crs EPSG:4326 on the command line, crs='EPSG:4326' to "
        "open_terrain.",
        TerrainDataWarning,
        stacklevel=3,
    )
