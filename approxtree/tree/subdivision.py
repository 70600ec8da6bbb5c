"""Subdivision schemes: how a node's domain D_N is cut into at most d child domains.

- fanout 4 (quadtree): cut across x and y at once; an axis that cannot be cut (one cell wide)
  is left whole, giving two children.
- fanout 2 (k-d tree): cut the longer side, or the other one when the longer cannot be cut.

Cut positions come from the terrain (``GeometryData.split_position``) so that grid children
share their border data lines. The children's rectangles tile the parent exactly.
"""

from __future__ import annotations

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
