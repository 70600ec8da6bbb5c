"""rasterize(): any terrain sampled onto a regular lattice, for steps that need a Grid.

Baking shading textures works on a grid of heights; a TIN or a point cloud (TINPointSet) is
sampled there through its own elevation function h_T (linear on its triangles). Lattice points
outside the triangles (the corners beyond a point cloud's convex hull) are nodata.
"""

from __future__ import annotations

import math

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid

#: Most lattice points rasterize makes (a float64 grid of 1 GB, filled strip by strip).
MAX_LATTICE_POINTS = 2**27
#: Lattice points sampled at a time: h_T's temporaries (locating points in triangles, the
#: grid's bilinear weights) stay a few tens of MB whatever the lattice.
STRIP_POINTS = 2**20


def mean_spacing(terrain: GeometryData) -> float:
    """The mean distance between data points: sqrt(domain area / point count), world units."""
    d = terrain.domain
    area = max(d.width, 0.0) * max(d.height, 0.0)
    spacing = math.sqrt(area / max(terrain.point_count, 1))
    return spacing if spacing > 0 else max(d.width, d.height, 1.0)


def rasterize(terrain: GeometryData, cell_size: float | None = None) -> Grid:
    """The terrain's heights h_T at the points of a square lattice covering its domain.

    cell_size: lattice step in world units (default: the mean point spacing, so the lattice has
    about as many points as the terrain). The lattice's outer points lie on the domain's edges.
    A Grid is returned as it is. Returns a Grid of (rows, cols) heights, NaN (nodata) where h_T
    is undefined.
    """
    if isinstance(terrain, Grid):
        return terrain
    if cell_size is not None and not (math.isfinite(cell_size) and cell_size > 0):
        raise InvalidParameterError(f"cell_size must be a positive number, got {cell_size!r}.")
    step = cell_size or mean_spacing(terrain)
    d = terrain.domain
    # At least 2 × 2 points, step adjusted so the lattice spans the domain exactly.
    cols = max(2, round(d.width / step) + 1)
    rows = max(2, round(d.height / step) + 1)
    if rows * cols > MAX_LATTICE_POINTS:
        raise InvalidParameterError(
            f"Rasterizing the terrain at a cell size of {step:g} makes {rows} × {cols} lattice "
            f"points (at most {MAX_LATTICE_POINTS} allowed); give a larger cell (texel) size."
        )
    dx = d.width / (cols - 1) if d.width > 0 else step
    dy = d.height / (rows - 1) if d.height > 0 else step
    xs = d.xmin + np.arange(cols) * dx
    ys = d.ymax - np.arange(rows) * dy
    # Sampled strip by strip into one array: only the lattice itself grows with its size.
    step_rows = max(1, STRIP_POINTS // cols)
    heights: np.ndarray | None = None
    for r0 in range(0, rows, step_rows):
        strip = terrain.height_at(xs[None, :], ys[r0 : r0 + step_rows, None])
        if heights is None:
            heights = np.empty((rows, cols), dtype=strip.dtype)
        heights[r0 : r0 + step_rows] = strip
    assert heights is not None  # rows >= 2: the loop ran
    # Cell-centre georeference: the top-left corner lies half a step beyond the first point.
    transform = Affine(dx, 0.0, d.xmin - 0.5 * dx, 0.0, -dy, d.ymax + 0.5 * dy)
    return Grid(heights, transform=transform, crs=terrain.crs)
