"""Subdivision schemes: how a node's domain D_N is cut into at most d child domains.

- fanout 4 (quadtree): cut across x and y at once; an axis that cannot be cut (one cell wide)
  is left whole, giving two children.
- fanout 2 (k-d tree): cut the longer side, or the other one when the longer cannot be cut.

Cut positions come from the terrain (``GeometryData.split_position``) so that grid children
share their border data lines. The children's rectangles tile the parent exactly.
"""

from __future__ import annotations

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.rect import Rect

FANOUTS = (2, 4)


def _cut(rect: Rect, axis: int, at: float) -> tuple[Rect, Rect]:
    """The halves of ``rect`` on either side of the line axis = at (west/east, south/north)."""
    if axis == 0:
        return Rect(rect.xmin, rect.ymin, at, rect.ymax), Rect(at, rect.ymin, rect.xmax, rect.ymax)
    return Rect(rect.xmin, rect.ymin, rect.xmax, at), Rect(rect.xmin, at, rect.xmax, rect.ymax)


def subdivide(terrain: GeometryData, rect: Rect, fanout: int) -> list[Rect]:
    """Child rectangles of ``rect`` (empty list when it cannot be cut at all).

    Order: quadtree children come south-west, south-east, north-west, north-east.
    """
    if fanout not in FANOUTS:
        raise InvalidParameterError(f"fanout must be one of {FANOUTS}, got {fanout}.")
    cut_x = terrain.split_position(rect, 0)
    cut_y = terrain.split_position(rect, 1)
    if fanout == 2:
        # Cut the longer side first so k-d cells stay close to square.
        order = (0, 1) if rect.width >= rect.height else (1, 0)
        for axis in order:
            at = cut_x if axis == 0 else cut_y
            if at is not None:
                return list(_cut(rect, axis, at))
        return []
    rows = list(_cut(rect, 1, cut_y)) if cut_y is not None else [rect]
    children: list[Rect] = []
    for band in rows:
        children.extend(_cut(band, 0, cut_x) if cut_x is not None else [band])
    return children if len(children) > 1 else []


def subdivide_level(
    terrain: GeometryData, rects: np.ndarray, fanout: int
) -> tuple[np.ndarray, np.ndarray]:
    """The children of every rectangle of a level in one array pass: ``subdivide`` of each.

    rects: (k, 4) float64 (xmin, ymin, xmax, ymax). Returns (child rects (m, 4) float64, in
    the parents' order and each parent's children in ``subdivide``'s order; counts (k,) int64,
    0 for a rectangle that cannot be cut).
    """
    if fanout not in FANOUTS:
        raise InvalidParameterError(f"fanout must be one of {FANOUTS}, got {fanout}.")
    rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    cut_x = terrain.split_positions(rects, 0)
    cut_y = terrain.split_positions(rects, 1)
    has_x, has_y = ~np.isnan(cut_x), ~np.isnan(cut_y)
    # Per parent: does the x cut / the y cut apply (k-d: one axis, quadtree: both).
    if fanout == 2:
        wide = rects[:, 2] - rects[:, 0] >= rects[:, 3] - rects[:, 1]
        use_x = np.where(wide, has_x, has_x & ~has_y)
        use_y = ~use_x & has_y
    else:
        use_x, use_y = has_x, has_y
    counts = (1 + use_x.astype(np.int64)) * (1 + use_y.astype(np.int64))
    counts[counts == 1] = 0
    parent = np.repeat(np.arange(len(rects)), counts)
    starts = np.cumsum(counts) - counts
    j = np.arange(len(parent)) - starts[parent]
    ux, uy = use_x[parent], use_y[parent]
    # Child j's side of each cut: 0 = low (west/south), 1 = high, -1 = that axis left whole;
    # quadtree order SW, SE, NW, NE puts the x side in j's low bit when both axes are cut.
    col = np.where(ux, np.where(uy, j % 2, j), -1)
    row = np.where(uy, np.where(ux, j // 2, j), -1)
    cx, cy = cut_x[parent], cut_y[parent]
    out = rects[parent].copy()
    out[:, 0] = np.where(col == 1, cx, out[:, 0])
    out[:, 2] = np.where(col == 0, cx, out[:, 2])
    out[:, 1] = np.where(row == 1, cy, out[:, 1])
    out[:, 3] = np.where(row == 0, cy, out[:, 3])
    return out, counts
