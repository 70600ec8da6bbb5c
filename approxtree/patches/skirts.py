"""Skirts: vertical walls hanging down from the border of a geometry patch.

Neighbouring patches of different resolution meet on a common border line of their
rectangles, but their border polylines differ in height (a T-junction seen from the side), so
pixels can fall through the vertical gap between them. A skirt closes it.

*Skirt depth.* Along a shared border line both border polylines interpolate data points of
that line (grid patches sample the rectangle's own border rows and columns), and h_T along a
grid line is linear between consecutive data points, so z_N − h_T is piecewise linear with
breaks at data points of D_N, where it is at most ε_T(N). Hence at every border point
|z_A − z_B| <= ε_T(A) + ε_T(B). The wall of the higher patch covers the gap when its depth is
at least that, so each patch gets depth ε_T(N) + ε_max, where ε_max is the largest finite
error in the tree (the neighbour is unknown when the patch is uploaded), plus a small margin
for float32 rounding. The walls sit under the neighbour's surface, so depth testing hides
everything but the gap. Walls end no lower than a common base z_min − ε_max; edges on the
terrain's outer border hang down to that base, so that from outside the domain the terrain
reads as a block whose sides hide the interior walls under the terrain sheet.

*Neighbours only.* When patches reach their rectangles, B can only be a node whose rectangle
touches a side of N's from the outside (at any level), so ε_max is taken per node over those
nodes (``kernels.rect_neighbours``): deep in the tree a wall is as deep as the errors next to
it, not as the coarsest node of the whole tree.

*Node borders only.* Walls close the gap between neighbours, so they hang only from border
edges that lie on the node's rectangle (the lines it shares with its neighbours, or the
domain's outer border). A patch's other border edges run along nodata inside the node: the
terrain has no surface beyond them, and a wall there would read as a gorge into the hole. They
stay open, as in the full-resolution terrain. (Point-set patches do not reach their
rectangle's border; they pass no rectangle and keep walls on every border edge.)

*Infinite errors.* A node whose patch misses data points (ε_T(N) = inf, a coarse patch next
to a hole) is never drawn by an α threshold; for its own walls its error counts as its z
extent (its border and h_T both lie in its z range), and it does not set ε_max: else one hole
anywhere would make every wall of the tree as deep as the terrain's relief.
"""

from __future__ import annotations

import numpy as np

from approxtree.geometry.base import GeometryData
from approxtree.geometry.tin import TIN
from approxtree.kernels import skirt_walls
from approxtree.kernels._jit import readonly
from approxtree.kernels.rect_neighbours import neighbour_max_errors

#: What ``skirt_mesh`` is passed for a rectangle or domain left out.
_NO_RECT = readonly(np.zeros(0))


def border_edges(triangles: np.ndarray) -> np.ndarray:
    """(k, 2) int64 directed edges used by exactly one triangle, interior on their left.

    triangles: (m, 3) vertex indices, counter-clockwise seen from above.
    """
    t = readonly(np.asarray(triangles, dtype=np.int64).reshape(-1, 3))
    if len(t) == 0:
        return np.empty((0, 2), dtype=np.int64)
    return skirt_walls.border_edges(t)


def add_skirts(
    vertices: np.ndarray,
    triangles: np.ndarray,
    depth: float,
    domain: tuple[float, float, float, float] | None = None,
    base: float = -np.inf,
    rect: tuple[float, float, float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The patch plus its skirt: (vertices (n', 3), triangles (m', 3), skirt flags (n',)).

    vertices: (n, 3) world; triangles: (m, 3) CCW from above; depth: wall height (z units);
    domain: (xmin, ymin, xmax, ymax) of the terrain; base: lowest z of any wall; rect:
    (xmin, ymin, xmax, ymax) of the node, or None when the patch does not reach it.
    With ``rect``, only border edges on the rectangle's boundary get walls (node borders);
    border edges inside it run along nodata and stay open (see the module docstring).
    Interior border edges hang down to max(z − depth, base). Edges on the domain's outer
    border hang down to ``base`` (a curtain: seen from outside the domain it hides the
    interior walls below the terrain sheet); with an infinite base they get no wall.
    Flags are 0 for the patch's vertices, 1 for the bottom vertices of the walls. The walls
    face outwards (counter-clockwise seen from outside the patch).
    """
    v0 = np.asarray(vertices, dtype=np.float64)
    t0 = np.asarray(triangles, dtype=np.int64)
    if len(t0) == 0:
        return v0, t0, np.zeros(len(v0), dtype=np.float32)
    # Two bottom vertices per wall quad: outer and interior walls end at different heights.
    # Seen from outside, a is top-left and b top-right: (a', b', b) and (a', b, a) are CCW.
    return skirt_walls.skirt_mesh(
        readonly(v0.reshape(-1, 3)),
        readonly(t0.reshape(-1, 3)),
        _NO_RECT if rect is None else readonly(np.asarray(rect, dtype=np.float64)),
        _NO_RECT if domain is None else readonly(np.asarray(domain, dtype=np.float64)),
        float(depth),
        float(base),
    )


def patches_reach_rect(terrain: GeometryData) -> bool:
    """True when the terrain's patches reach their node's rectangle (grids, non-regular grids,
    grid refinements: border data lines are shared), so walls hang from node borders only;
    False for scattered points (TIN, TINPointSet), whose patches stop at their outermost points.
    """
    return not isinstance(terrain, TIN)


def skirt_edge_count(
    vertices: np.ndarray,
    triangles: np.ndarray,
    rect: tuple[float, float, float, float] | None = None,
) -> int:
    """Border edges of a patch that ``add_skirts`` hangs walls from (2 triangles each).

    Counts curtain edges on the domain's border too (they get walls with a finite base).
    """
    v = np.asarray(vertices, dtype=np.float64)
    edges = border_edges(triangles)
    if rect is None or len(edges) == 0:
        return len(edges)
    return int(np.count_nonzero(_on_rect(v, edges, rect)))


def _on_rect(
    v: np.ndarray, edges: np.ndarray, rect: tuple[float, float, float, float]
) -> np.ndarray:
    """(k,) bool: edges (k, 2) whose two ends lie on one side of ``rect`` (xmin, ymin, xmax,
    ymax), up to a relative tolerance for world-coordinate round-off."""
    return skirt_walls.on_rect(
        readonly(v, np.float64),
        readonly(edges, np.int64),
        readonly(np.asarray(rect, dtype=np.float64)),
    )


def _bounded_errors(
    errors: np.ndarray, z_range: tuple[float, float], extents: np.ndarray | None
) -> tuple[np.ndarray, float]:
    """(per-node error bound (n,), ε_max): inf errors replaced by the node's z extent (the
    terrain's relief without ``extents``); ε_max is the largest finite error."""
    relief = max(z_range[1] - z_range[0], 0.0)
    errors = np.asarray(errors, dtype=np.float64)
    finite = np.isfinite(errors)
    fill = np.full(len(errors), relief) if extents is None else np.asarray(extents, np.float64)
    fill = np.where(np.isfinite(fill), np.minimum(fill, relief), relief)
    e = np.where(finite, errors, fill)
    return e, float(errors[finite].max(initial=0.0))


def skirt_base(
    errors: np.ndarray, z_range: tuple[float, float], extents: np.ndarray | None = None
) -> float:
    """Lowest z any wall needs: z_min − max error bound − margin.

    Every patch lies at or above z_min − ε_T(N) at its border points, so clamping the walls
    there keeps the gap argument above intact. extents: (n,) z extent of each node (for
    nodes of infinite error), or None.
    """
    relief = max(z_range[1] - z_range[0], 0.0)
    e, _ = _bounded_errors(errors, z_range, extents)
    return float(z_range[0] - e.max(initial=0.0) - 1e-3 * max(relief, 1.0))


def skirt_depths(
    errors: np.ndarray,
    z_range: tuple[float, float],
    extents: np.ndarray | None = None,
    rects: np.ndarray | None = None,
) -> np.ndarray:
    """(n,) skirt depth of every node: ε_T(N) + ε_max + margin (see the module docstring).

    errors: (n,) ε_T(N), inf where a patch misses data points; extents: (n,) z extent of
    each node (bbox z max − z min), standing in for an infinite ε_T(N); None: the relief.
    rects: (n, 4) node rectangles when patches reach them: ε_max is then taken per node over
    the nodes across its sides only; None: over the whole tree.
    """
    relief = max(z_range[1] - z_range[0], 0.0)
    e, e_max = _bounded_errors(errors, z_range, extents)
    margin = 1e-3 * max(relief, 1.0)
    if rects is None:
        return e + e_max + margin
    across = neighbour_max_errors(
        np.ascontiguousarray(rects, dtype=np.float64),
        np.ascontiguousarray(errors, dtype=np.float64),
    )
    return e + across + margin
