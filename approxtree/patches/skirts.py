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
from approxtree.kernels.rect_neighbours import neighbour_max_errors


def border_edges(triangles: np.ndarray) -> np.ndarray:
    """(k, 2) int64 directed edges used by exactly one triangle, interior on their left.

    triangles: (m, 3) vertex indices, counter-clockwise seen from above.
    """
    t = np.asarray(triangles, dtype=np.int64)
    if len(t) == 0:
        return np.empty((0, 2), dtype=np.int64)
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    # Undirected edge key lo·n + hi: one 1-D unique instead of a row-wise one.
    n = int(t.max()) + 1
    key = np.minimum(directed[:, 0], directed[:, 1]) * n + np.maximum(
        directed[:, 0], directed[:, 1]
    )
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return directed[counts[inverse] == 1]


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
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    edges = border_edges(t)
    if rect is not None and len(edges):
        edges = edges[_on_rect(v, edges, rect)]
    outer = np.zeros(len(edges), dtype=bool)
    if domain is not None and len(edges):
        outer = _on_rect(v, edges, domain)
        if not np.isfinite(base):
            edges, outer = edges[~outer], outer[~outer]
    flags = np.zeros(len(v), dtype=np.float32)
    if len(edges) == 0:
        return v, t, flags
    # Two bottom vertices per wall quad: outer and interior walls end at different heights.
    k = len(edges)
    low = np.concatenate([v[edges[:, 0]], v[edges[:, 1]]])
    outer2 = np.concatenate([outer, outer])
    low[:, 2] = np.where(outer2, base, np.maximum(low[:, 2] - depth, base))
    a, b = edges[:, 0], edges[:, 1]
    a2 = len(v) + np.arange(k)
    b2 = a2 + k
    # Seen from outside, a is top-left and b top-right: (a', b', b) and (a', b, a) are CCW.
    walls = np.concatenate([np.column_stack([a2, b2, b]), np.column_stack([a2, b, a])])
    return (
        np.concatenate([v, low]),
        np.concatenate([t, walls]),
        np.concatenate([flags, np.ones(2 * k, dtype=np.float32)]),
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
    xmin, ymin, xmax, ymax = rect
    tol = 1e-9 * max(xmax - xmin, ymax - ymin, 1e-300)
    a, b = v[edges[:, 0]], v[edges[:, 1]]
    on = np.zeros(len(edges), dtype=bool)
    for axis, bound in ((0, xmin), (0, xmax), (1, ymin), (1, ymax)):
        on |= (np.abs(a[:, axis] - bound) <= tol) & (np.abs(b[:, axis] - bound) <= tol)
    return on


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
