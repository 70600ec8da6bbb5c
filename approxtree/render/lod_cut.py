"""The view-dependent cut of a PointQuadtree (seed 003) and the meshes of its drawn nodes.

Render-time selection, kept apart from the quadtree's structure and build
(tree/point_quadtree.py), as selector.py is for approximation trees:

1. ``LodSelector.cut``: a node is refined while the screen projection error ρ = λ·δ/d > C, λ
   the pixels per radian of the view (``pixels_per_radian``), d the distance from the eye to
   the node's 3-D box (so δ/d bounds the angle any vertical error segment in the node
   subtends). Nodes outside the frustum are never refined.
2. The cut is restricted again (``_restrict_rows``): a drawn node next to a neighbour refined
   twice along the shared edge is split, and the nodes the splits put in the cut are checked
   in turn, until stable (leaves two levels apart never meet).
3. A drawn leaf replays its recorded insertion order up to the first prefix whose measured
   error is within C·d/λ. Edge midpoints are kept where the drawn neighbour is finer and laid
   on the straight edge otherwise (with a zero-area triangle over the edge, so rasterization
   leaves no pinhole at the T-junction), so the mesh is continuous.
4. ``node_meshes``: the meshes of the drawn nodes, built in one kernel call.

δ(node) of an internal node is the largest error over every fan the node can be drawn as; a
drawn node beside a neighbour of another level is measured for its actual boundary
(``leaf_errors``, ``fan_error``, remembered per selector), so every drawn node's ρ is a
measured bound, never an estimate. ``lod_mesh`` is the whole cut of one view as one mesh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from approxtree.kernels.point_quadtree import first_within, insert_points
from approxtree.kernels.point_quadtree import node_meshes as _node_meshes_kernel
from approxtree.patches.mesh_objects import MeshConversions
from approxtree.render.frame_state import FrameState

# Edge directions: west, east, south, north as (di, dj) (the tree's side order).
_SIDES = ((-1, 0), (1, 0), (0, -1), (0, 1))

#: A node key (level, i, j) of the quadtree.
Node = tuple[int, int, int]


@dataclass
class LODCut:
    """The drawn nodes of one view (k of them), each with the figures of its mesh.

    rows: (k,) node rows; midpoints, keep: (k, 4) bool per side W, E, S, N (a midpoint
    vertex; it keeps its lattice height, else lies on the straight edge); inserted: (k,)
    points replayed (leaves) or −1 (a coarse node's fan); errors: (k,) measured max
    ``|z − mesh|`` over each visible node's points (δ for culled ones); distances: (k,) d
    (display units); visible: (k,) inside the frustum; nodes_visited: nodes the traversal
    reached; refined: rows of the nodes replaced by their children (ancestors of the cut).
    """

    rows: np.ndarray
    midpoints: np.ndarray
    keep: np.ndarray
    inserted: np.ndarray
    errors: np.ndarray
    distances: np.ndarray
    visible: np.ndarray
    nodes_visited: int
    refined: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))

    def screen_errors(self, lam: float) -> np.ndarray:
        """(k,) ρ = λ·error/d of each drawn node (pixels; inf at d = 0 with an error)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.where(self.distances > 0, lam * self.errors / self.distances, np.inf)
        return np.where(self.errors == 0, 0.0, rho)


@dataclass
class LODMesh(MeshConversions):
    """A view-dependent mesh: vertices (n, 3) world, triangles (m, 3), figures of the cut;
    face_nodes: (m,) int64 node row of each face. ``to_trimesh()``/``to_pyvista()`` carry z
    and "node" (the face's node row)."""

    vertices: np.ndarray
    triangles: np.ndarray
    nodes: int
    leaves_refined: int
    points_inserted: int
    face_nodes: np.ndarray | None = None

    def _face_data(self) -> dict[str, np.ndarray]:
        return {} if self.face_nodes is None else {"node": self.face_nodes}


def pixels_per_radian(fs: FrameState) -> float:
    """λ: the largest screen pixels per radian of view angle over the image (at its corner).

    An angle δθ at angle θ off the view axis spans up to f·δθ/cos²θ pixels (f the focal
    length in pixels), largest at the image corner: λ = f·(1 + t²), t the tangent of the
    corner's angle.
    """
    w, h = fs.viewport
    t2 = ((0.5 * w) ** 2 + (0.5 * h) ** 2) / fs.focal_px**2
    return float(fs.focal_px * (1.0 + t2))


class LodSelector:
    """The cuts of one PointQuadtree (see the module docstring); remembers the errors it
    measured for boundaries other than the recorded ones, from view to view."""

    def __init__(self, tree: Any) -> None:
        self.tree = tree
        self._leaf_error_cache: dict[tuple, np.ndarray] = {}
        self._fan_error_cache: dict[tuple, float] = {}

    def cut(
        self,
        eye: tuple[float, float, float] | np.ndarray,
        lam: float,
        tolerance: float,
        scale: np.ndarray | None = None,
        visible: np.ndarray | None = None,
    ) -> LODCut:
        """The restricted cut for an eye (world), λ (pixels per radian), tolerance C (pixels).

        scale: (3,) display scale applied to eye-to-box offsets (d in display units);
        visible: (n,) bool per node row, False for nodes outside the frustum (never refined).
        """
        q = self.tree
        e = np.asarray(eye, dtype=np.float64)
        sc = np.ones(3) if scale is None else np.asarray(scale, dtype=np.float64)
        box = q.bboxes
        d = np.linalg.norm((e - np.clip(e, box[:, :3], box[:, 3:])) * sc, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.where(d > 0, lam * q.node_errors / d, np.inf)
        rho[q.node_errors == 0] = 0.0
        want = q.internal & (rho > tolerance)
        if visible is not None:
            want &= np.asarray(visible, dtype=bool)
        # Traversal from the root, level by level (rows are sorted by level).
        reached = np.zeros(len(q), dtype=bool)
        reached[0] = True
        bounds = np.searchsorted(q.levels, np.arange(q.levels[-1] + 2))
        for level in range(1, int(q.levels[-1]) + 1):
            rows = np.arange(bounds[level], bounds[level + 1])
            p = q.parents[rows]
            reached[rows] = reached[p] & want[p]
        refined = reached & want
        drawn = reached & ~want
        self._restrict_rows(drawn, refined, want)
        rows = np.flatnonzero(drawn)
        cut_finer = np.stack(
            [refined[np.maximum(nb, 0)] & (nb >= 0) for nb in self._side_rows(rows)], axis=1
        )
        midpoints = np.where(q.internal[rows, None], cut_finer, q.tree_finer[rows])
        inserted = np.where(q.internal[rows], -1, 0)
        errors = q.node_errors[rows].copy()
        vis = np.ones(len(rows), dtype=bool) if visible is None else np.asarray(visible)[rows]
        budgets = tolerance * d[rows] / lam
        # A visible leaf with the boundary it was recorded with replays up to its first prefix
        # within C·d/λ (one kernel call for all of them).
        recorded = vis & ~q.internal[rows] & (cut_finer == q.tree_finer[rows]).all(axis=1)
        r = rows[recorded]
        inserted[recorded], errors[recorded] = first_within(
            q.order_errors,
            q.error_start[r],
            q.ranges[r, 1] - q.ranges[r, 0] + 1,
            budgets[recorded],
        )
        # The others, beside a drawn neighbour of another level: a leaf whose midpoint lies on
        # the coarser neighbour's straight edge, or a coarse node's fan; their errors are
        # measured for that boundary on first use.
        for k in np.flatnonzero(vis & ~recorded).tolist():
            node = q.node_keys[rows[k]]
            if q.internal[rows[k]]:
                errors[k] = self.fan_error(node, tuple(midpoints[k]))
                continue
            errs = self.leaf_errors(node, tuple(cut_finer[k]))
            within = errs <= budgets[k]
            inserted[k] = int(np.argmax(within)) if within.any() else len(errs) - 1
            errors[k] = errs[inserted[k]]
        return LODCut(
            rows,
            midpoints,
            cut_finer & midpoints,
            inserted,
            errors,
            d[rows],
            vis,
            int(reached.sum()),
            np.flatnonzero(refined),
        )

    # -- measured errors of other boundaries ---------------------------------------------------

    def leaf_errors(self, leaf: Node, keep: tuple[bool, ...]) -> np.ndarray:
        """(n + 1,) measured max ``|z − mesh|`` over the leaf's points after 0..n insertions of its
        recorded order, for the boundary whose midpoints keep their heights per ``keep``."""
        q = self.tree
        tree_keep = tuple(q.tree_finer[q.index[leaf]].tolist())
        keep = tuple(bool(k) and t for k, t in zip(keep, tree_keep, strict=True))
        if keep == tree_keep:
            return q.orders[leaf][1]
        key = (leaf, keep)
        errors = self._leaf_error_cache.get(key)
        if errors is None:
            lo, hi = q.point_range(leaf)
            order = q.orders[leaf][0]
            base = q.boundary(leaf, list(tree_keep), list(keep))
            replay = order if len(order) else np.array([-1])
            _, errors, _ = insert_points(base, q.points[lo:hi], replay, hi - lo)
            self._leaf_error_cache[key] = errors
        return errors

    def fan_error(self, node: Node, midpoints: tuple[bool, ...]) -> float:
        """Measured max ``|z − fan|`` over the node's points for the fan with ``midpoints``."""
        key = (node, tuple(bool(m) for m in midpoints))
        err = self._fan_error_cache.get(key)
        if err is None:
            q = self.tree
            lo, hi = q.point_range(node)
            base = q.boundary(node, list(key[1]))
            err = float(insert_points(base, q.points[lo:hi], np.array([-1]), 0)[1][0])
            self._fan_error_cache[key] = err
        return err

    # -- restriction ---------------------------------------------------------------------------

    def _side_rows(self, rows: np.ndarray) -> list[np.ndarray]:
        return [self.tree._neighbour(di, dj, rows) for di, dj in _SIDES]

    def _restrict_rows(self, drawn: np.ndarray, refined: np.ndarray, want: np.ndarray) -> None:
        """Restrict the cut in place: split drawn nodes next to neighbours refined twice along
        the shared edge (leaves two levels apart would meet), and nodes the splits put in the
        cut that ask for refinement themselves; repeat until stable."""
        q = self.tree
        # Children of the west, east, south, north neighbour that touch the shared edge.
        adjacent = ((1, 0, 1, 1), (0, 0, 0, 1), (0, 1, 1, 1), (0, 0, 1, 0))
        while True:
            cand = np.flatnonzero(drawn & q.internal)
            if len(cand) == 0:
                return
            lv, i, j = q.levels[cand], q.cells[cand, 0], q.cells[cand, 1]
            split = want[cand].copy()
            for (di, dj), (a0, b0, a1, b1) in zip(_SIDES, adjacent, strict=True):
                ni, nj = i + di, j + dj
                for a, b in ((a0, b0), (a1, b1)):
                    kid = q._lookup(lv + 1, 2 * ni + a, 2 * nj + b)
                    split |= (kid >= 0) & refined[np.maximum(kid, 0)]
            if not split.any():
                return
            s = cand[split]
            drawn[s] = False
            refined[s] = True
            drawn[q.child_rows[s].ravel()] = True


# -- meshes ------------------------------------------------------------------------------------


def node_meshes(
    tree: Any,
    rows: npt.ArrayLike,
    midpoints: npt.ArrayLike,
    keep: npt.ArrayLike,
    inserted: npt.ArrayLike,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The meshes of k drawn nodes of a PointQuadtree's cut (``node_mesh`` of each, in one
    kernel call).

    rows: (k,) node rows; midpoints, keep: (k, 4) bool; inserted: (k,) as in ``LODCut``.
    Returns (vertices (V, 3) world, vertex_start (k + 1,), triangles (T, 3) int64,
    triangle_start (k + 1,)): node m's vertices are vertices[vertex_start[m]:
    vertex_start[m + 1]] and its triangles, indexing them from 0,
    triangles[triangle_start[m]:triangle_start[m + 1]].
    """
    k = np.size(rows)
    return _node_meshes_kernel(
        tree._ring_xyz,
        tree.points,
        tree.ranges,
        tree.order_flat,
        tree.order_start,
        np.asarray(rows, dtype=np.int64).reshape(k),
        np.ascontiguousarray(np.asarray(midpoints, dtype=np.bool_).reshape(k, 4)),
        np.ascontiguousarray(np.asarray(keep, dtype=np.bool_).reshape(k, 4)),
        np.asarray(inserted, dtype=np.int64).reshape(k),
    )


def node_mesh(
    tree: Any,
    node: Node,
    midpoints: tuple[bool, ...],
    keep: tuple[bool, ...],
    inserted: int,
) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3) world, triangles (m, 3)) of one drawn node of a cut.

    inserted: points replayed (a leaf), or −1 for a coarse node's fan. A midpoint laid on
    the straight edge (not kept) gets a zero-area triangle over its edge: the coarser
    neighbour's edge then meets this mesh edge for edge on screen (no T-junction pinhole).
    """
    v, _, t, _ = node_meshes(
        tree, np.array([tree.index[node]]), np.array([midpoints]), np.array([keep]), [inserted]
    )
    return v, t


def leaf_mesh(
    tree: Any, leaf: Node, k: int, keep: list[bool] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of ``leaf`` after replaying its first k insertions (the per-node
    Python path, kept as the reference of ``node_meshes``)."""
    lo, hi = tree.point_range(leaf)
    order, _ = tree.orders[leaf]
    base = tree.boundary(leaf, tree.tree_finer[tree.index[leaf]].tolist(), keep)
    pts = tree.points[lo:hi]
    replay = order if len(order) else np.array([-1])
    _, _, tris = insert_points(base, pts, replay if k else np.array([0]), k)
    return np.concatenate([base, pts]), tris


def lod_mesh(
    tree: Any, eye: tuple[float, float, float], fov: float, width: int, tolerance: float = 10.0
) -> LODMesh:
    """The view-dependent mesh of a PointQuadtree for an eye position, horizontal field of
    view (degrees), viewport width (pixels) and screen tolerance C (pixels): λ = width / fov."""
    cut = LodSelector(tree).cut(eye, width / math.radians(fov), tolerance)
    verts, vstart, tris, tstart = node_meshes(tree, cut.rows, cut.midpoints, cut.keep, cut.inserted)
    # Node-local triangle indices → indices into all the vertices.
    tris = tris + np.repeat(vstart[:-1], np.diff(tstart))[:, None]
    return LODMesh(
        verts,
        tris,
        len(cut.rows),
        int((cut.inserted > 0).sum()),
        int(cut.inserted[cut.inserted > 0].sum()),
        face_nodes=np.repeat(np.asarray(cut.rows, dtype=np.int64), np.diff(tstart)),
    )
