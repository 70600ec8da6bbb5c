"""PointQuadtree: quadtree domain decomposition of scattered points with per-leaf insertion
orders (seed 003, "View-dependent LOD of TIN based on quadtree domain decomposition").

Build (pre-processing):

1. the root is the square around the points' domain; a node is split while it holds more than
   δ points (``max_points``); points are sorted in Z-order so every node owns a contiguous run;
2. the quadtree is *restricted*: split leaves until edge-neighbouring leaves differ by at most
   one level (no T-shaped cracks between leaf triangulations);
3. interpolation points — the lattice points used as corners, centres and edge midpoints of the
   nodes — get heights averaged from their 4 nearest data points;
4. each node's error δ(node) is the max |z − fan| over its points (fan: 4 triangles between the
   centre and the corners); each leaf records, at build time, the order in which its points are
   inserted (largest error first) and the error after every insertion.

Render time (``lod_cut``, ``lod_mesh``): a node is refined while the screen projection error
ρ = λ·δ/d > C, λ the pixels per radian of the view, d the distance from the eye to the
node's 3-D box (so δ/d bounds the angle any vertical error segment in the node subtends);
the cut is restricted again (nodes split by the restriction are checked in turn); a drawn
leaf replays its insertion order up to the first prefix whose measured error is within
C·d/λ. Edge midpoints are kept where the drawn neighbour is finer and laid on the straight
edge otherwise (with a zero-area triangle over the edge, so rasterization leaves no pinhole
at the T-junction), so the mesh is continuous. The Engine maps its α to C and draws the
cut (render/point_quadtree_engine.py).

δ(node) of an internal node is the largest error over every fan the node can be drawn as
(with or without each side's midpoint); a drawn leaf's error is measured for its actual
boundary (``leaf_errors``), so every drawn node's ρ is a measured bound, never an estimate.

Storage (``tree.store``): ``save`` writes a tree store (terrain plus the "quadtree" arrays of
``to_sections``); ``load`` reads a store or a legacy .atree file of tree kind "point_quadtree"
(and refuses the ``.npz`` files of earlier versions with a StoreError saying to rebuild).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from approxtree._version import __version__
from approxtree.errors import InvalidParameterError, StoreError
from approxtree.geometry.tin import TIN
from approxtree.kernels.point_quadtree import (
    fan_errors,
    first_within,
    insert_points,
    insertion_orders,
    morton_codes,
    node_meshes,
    range_z_bounds,
)
from approxtree.patches.mesh_objects import MeshConversions
from approxtree.tree import store

#: ``meta["tree_kind"]`` of a point quadtree in a saved tree.
TREE_KIND = "point_quadtree"
#: Version of the "quadtree" section's layout.
SECTION_VERSION = 1
#: Finest quadtree level (2^20 cells a side); points sharing a finest cell stay in one leaf.
MAX_DEPTH = 20
#: Bits of the second coordinate in a finest-lattice code (u << bits | v; u, v <= 2^21).
_LATTICE_BITS = 22
# Counter-clockwise from SW: (corner slot, side after it, its midpoint slot, the side's end
# slots) over the ring slots of ``_ring_codes``; sides are numbered W, E, S, N.
_BOUNDARY = ((0, 2, 5, 0, 1), (1, 1, 6, 1, 2), (2, 3, 7, 2, 3), (3, 0, 8, 3, 0))
# Edge directions: west, east, south, north as (di, dj).
_SIDES = ((-1, 0), (1, 0), (0, -1), (0, 1))


def _encode(level: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(k,) int64 keys of nodes (level, i, j), increasing with (level, i, j)."""
    return (np.asarray(level, np.int64) << 42) | (np.asarray(i, np.int64) << 21) | j


@dataclass
class LODCut:
    """The drawn nodes of one view (k of them), each with the figures of its mesh.

    rows: (k,) node rows; midpoints, keep: (k, 4) bool per side W, E, S, N (a midpoint
    vertex; it keeps its lattice height, else lies on the straight edge); inserted: (k,)
    points replayed (leaves) or −1 (a coarse node's fan); errors: (k,) measured max
    |z − mesh| over each visible node's points (δ for culled ones); distances: (k,) d
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


class PointQuadtree:
    """Restricted quadtree over a TIN / TINPointSet with per-leaf insertion orders.

    terrain: the point set; max_points: δ, the most points a leaf holds (>= 1).
    Nodes are keyed (level, i, j): cell i (east), j (north) of the 2^level lattice.
    """

    #: What the Engine and the tree file see: a point quadtree, not an approximation tree.
    tree_kind = TREE_KIND

    def __init__(self, terrain: TIN, max_points: int = 50, _build: bool = True) -> None:
        if not isinstance(max_points, int | np.integer) or max_points < 1:
            raise InvalidParameterError(
                f"max_points (δ) must be an integer >= 1, got {max_points!r}."
            )
        self.terrain = terrain
        self.max_points = int(max_points)
        if not _build:
            return
        d = terrain.domain
        self.size = max(d.width, d.height) * (1 + 1e-9) or 1.0
        self.x0, self.y0 = d.xmin, d.ymin
        pts = terrain.vertices
        n = 1 << MAX_DEPTH
        ix = np.clip(((pts[:, 0] - self.x0) / self.size * n).astype(np.int64), 0, n - 1)
        iy = np.clip(((pts[:, 1] - self.y0) / self.size * n).astype(np.int64), 0, n - 1)
        codes = morton_codes(ix, iy, MAX_DEPTH)
        order = np.argsort(codes, kind="stable")
        self.codes = codes[order]
        self.points = np.ascontiguousarray(pts[order])
        self.children: dict[tuple[int, int, int], bool] = {}  # node → is internal
        self._subdivide()
        self._restrict()
        self._heights()
        self._index()
        self._errors()
        self._insertion_orders()

    # -- build ---------------------------------------------------------------------------------

    def point_range(self, node: tuple[int, int, int]) -> tuple[int, int]:
        """[start, stop) of the node's points in ``self.points`` (Z-order)."""
        row = getattr(self, "index", {}).get(node)
        if row is not None:
            lo, hi = self.ranges[row]
        else:
            lo, hi = self._ranges(*(np.array([v], dtype=np.int64) for v in node))[0]
        return int(lo), int(hi)

    def _ranges(self, level: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(k, 2) [start, stop) in ``self.points`` of the nodes (level, i, j), (k,) int64 each."""
        shift = 2 * (MAX_DEPTH - np.asarray(level, dtype=np.int64))
        prefix = morton_codes(np.asarray(i, np.int64), np.asarray(j, np.int64), MAX_DEPTH) << shift
        lo = np.searchsorted(self.codes, prefix, side="left")
        hi = np.searchsorted(self.codes, prefix + (np.int64(1) << shift), side="left")
        return np.column_stack([lo, hi]).astype(np.int64)

    def _subdivide(self) -> None:
        # Split while a node holds more than δ points, one level at a time (arrays per level).
        fi = fj = np.zeros(1, dtype=np.int64)
        level = 0
        #: Per level, (k,) cell codes i << 21 | j of the split nodes (``_restrict`` adds its own).
        self._splits: list[np.ndarray] = []
        while len(fi):
            r = self._ranges(np.full(len(fi), level), fi, fj)
            split = (r[:, 1] - r[:, 0] > self.max_points) & (level < MAX_DEPTH)
            keys = zip([level] * len(fi), fi.tolist(), fj.tolist(), strict=True)
            self.children.update(zip(keys, split.tolist(), strict=True))
            si, sj = fi[split], fj[split]
            self._splits.append((si << 21) | sj)
            fi = np.concatenate([2 * si + a for b in (0, 1) for a in (0, 1)])
            fj = np.concatenate([2 * sj + b for b in (0, 1) for a in (0, 1)])
            level += 1

    def _restrict(self) -> None:
        # Restricted quadtree: an internal node's same-level edge neighbours must exist, i.e.
        # their parents must be internal (else a leaf two or more levels coarser would touch
        # its grandchildren), and so must every ancestor of an internal node. A split made for
        # level L lies at level L − 1, so one pass from the finest level up closes the set.
        need = np.zeros(0, dtype=np.int64)
        new_levels, new_cells = [], []
        for level in range(len(self._splits) - 1, -1, -1):
            have = self._splits[level]
            new = np.setdiff1d(need, have, assume_unique=True)
            new_levels.append(np.full(len(new), level, dtype=np.int64))
            new_cells.append(new)
            cur = np.concatenate([have, new])
            # The parents of the nodes themselves (offset 0) and of their edge neighbours.
            i, j = cur >> 21, cur & ((1 << 21) - 1)
            ni = np.concatenate([i] + [i + di for di, _ in _SIDES])
            nj = np.concatenate([j] + [j + dj for _, dj in _SIDES])
            ok = (ni >= 0) & (nj >= 0) & (ni < (1 << level)) & (nj < (1 << level))
            need = np.unique(((ni[ok] >> 1) << 21) | (nj[ok] >> 1))
            self._splits[level] = cur
        lv = np.concatenate(new_levels) if new_levels else np.zeros(0, dtype=np.int64)
        if len(lv) == 0:
            return
        c = np.concatenate(new_cells)
        i, j = c >> 21, c & ((1 << 21) - 1)
        split = list(zip(lv.tolist(), i.tolist(), j.tolist(), strict=True))
        # The children of the new splits are new nodes, leaves unless split themselves.
        kl = np.repeat(lv + 1, 4)
        ki = (2 * i[:, None] + np.array([0, 1, 0, 1])).ravel()
        kj = (2 * j[:, None] + np.array([0, 0, 1, 1])).ravel()
        kids = zip(kl.tolist(), ki.tolist(), kj.tolist(), strict=True)
        self.children.update(dict.fromkeys(kids, False))
        self.children.update(dict.fromkeys(split, True))

    def is_leaf(self, node: tuple[int, int, int]) -> bool:
        return not self.children[node]

    @property
    def leaves(self) -> list[tuple[int, int, int]]:
        return [n for n, internal in self.children.items() if not internal]

    def square(self, node: tuple[int, int, int]) -> tuple[float, float, float]:
        """(x0, y0, size) of the node's square."""
        level, i, j = node
        s = self.size / (1 << level)
        return self.x0 + i * s, self.y0 + j * s, s

    def _lattice_key(self, level: int, u: int, v: int) -> tuple[int, int]:
        """Lattice point (u, v) at half-cell resolution of ``level`` → finest-lattice key."""
        shift = MAX_DEPTH + 1 - (level + 1)
        return u << shift, v << shift

    def _heights(self) -> None:
        # Corners, centres and edge midpoints of every node, keyed on the finest half-lattice.
        from scipy.spatial import cKDTree

        a = np.array(list(self.children), dtype=np.int64).reshape(-1, 3)
        codes = np.unique(self._ring_codes(a[:, 0], a[:, 1], a[:, 2]))
        ku, kv = codes >> _LATTICE_BITS, codes & ((1 << _LATTICE_BITS) - 1)
        unit = self.size / (1 << (MAX_DEPTH + 1))
        x, y = self.x0 + ku * unit, self.y0 + kv * unit
        k = min(4, len(self.points))
        _, near = cKDTree(self.points[:, :2]).query(np.column_stack([x, y]), k=k)
        z = self.points[np.asarray(near).reshape(len(x), k), 2].mean(axis=1)
        keys = zip(ku.tolist(), kv.tolist(), strict=True)
        xyz = zip(x.tolist(), y.tolist(), z.tolist(), strict=True)
        self.lattice = dict(zip(keys, xyz, strict=True))

    @staticmethod
    def _ring_codes(level: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(k, 9) finest-lattice codes of the corners SW, SE, NE, NW, the centre and the
        midpoints S, E, N, W of nodes (level, i, j)."""
        du = np.array([0, 2, 2, 0, 1, 1, 2, 1, 0], dtype=np.int64)
        dv = np.array([0, 0, 2, 2, 1, 0, 1, 2, 1], dtype=np.int64)
        shift = (MAX_DEPTH - level)[:, None]
        u = (2 * i[:, None] + du) << shift
        v = (2 * j[:, None] + dv) << shift
        return (u << _LATTICE_BITS) | v

    def lattice_point(self, level: int, u: int, v: int) -> tuple[float, float, float]:
        """World (x, y, z) of half-cell lattice point (u, v) of ``level``."""
        return self.lattice[self._lattice_key(level, u, v)]

    def _errors(self) -> None:
        # δ per node: the largest error over every fan it can be drawn as (kernel docstring).
        p = self.points
        err = fan_errors(
            p[:, 0].copy(),
            p[:, 1].copy(),
            p[:, 2].copy(),
            self.ranges[:, 0].copy(),
            self.ranges[:, 1].copy(),
            np.ascontiguousarray(self.squares),
            self._ring_z,
        )
        self.node_errors = err
        self.errors = dict(zip(self.node_keys, err.tolist(), strict=True))

    def _index(self) -> None:
        """Per-node arrays, rows sorted by (level, i, j) so parents precede children.

        node_keys: list of (level, i, j); levels, cells (n, 2) i, j; internal (n,) bool;
        parents (n,) row or −1; child_rows (n, 4) rows of children SW, SE, NW, NE or −1;
        ranges (n, 2) [start, stop) of the points; squares (n, 3) x0, y0, size;
        bboxes (n, 6) xmin, ymin, zmin, xmax, ymax, zmax over the node's points and lattice
        points (every mesh the node is drawn as lies inside); tree_finer (n, 4) bool per side
        W, E, S, N: the same-level neighbour is internal; origin (3,) local origin of GPU
        buffers (domain centre, lowest z); in_domain (n,) bool: the square overlaps the
        terrain's domain.
        """
        self.node_keys = sorted(self.children)
        #: Row of each node key.
        self.index = dict(zip(self.node_keys, range(len(self.node_keys)), strict=True))
        a = np.array(self.node_keys, dtype=np.int64).reshape(-1, 3)
        self.levels = a[:, 0].copy()
        self.cells = a[:, 1:].copy()
        self._keys = _encode(a[:, 0], a[:, 1], a[:, 2])
        self.internal = np.array([self.children[n] for n in self.node_keys], dtype=bool)
        lv, i, j = self.levels, self.cells[:, 0], self.cells[:, 1]
        self.parents = np.where(lv > 0, self._lookup(lv - 1, i // 2, j // 2), -1)
        self.child_rows = np.stack(
            [self._lookup(lv + 1, 2 * i + a, 2 * j + b) for b in (0, 1) for a in (0, 1)], axis=1
        )
        nbs = [self._neighbour(di, dj) for di, dj in _SIDES]
        self.tree_finer = np.stack([(nb >= 0) & self.internal[np.maximum(nb, 0)] for nb in nbs], 1)
        self.ranges = self._ranges(lv, i, j)
        side = self.size / (np.int64(1) << lv)
        self.squares = np.column_stack([self.x0 + i * side, self.y0 + j * side, side])
        # Ring heights through the lattice as sorted codes (one search for all nodes).
        lk = np.array(list(self.lattice), dtype=np.int64).reshape(-1, 2)
        lcodes = (lk[:, 0] << _LATTICE_BITS) | lk[:, 1]
        lxyz = np.array(list(self.lattice.values()), dtype=np.float64).reshape(-1, 3)
        order = np.argsort(lcodes)
        lcodes, lxyz = lcodes[order], lxyz[order]
        ring = self._ring_codes(lv, i, j)
        at = np.minimum(np.searchsorted(lcodes, ring), len(lcodes) - 1)
        if not (lcodes[at] == ring).all():
            raise StoreError("a node's lattice point has no height; rebuild the quadtree.")
        #: (n, 9, 3) the lattice points of ``_ring_codes`` (the very values of ``lattice``).
        self._ring_xyz = lxyz[at]
        self._ring_z = np.ascontiguousarray(self._ring_xyz[..., 2])
        z = range_z_bounds(self.points[:, 2].copy(), self.ranges[:, 0], self.ranges[:, 1])
        zmin = np.minimum(z[:, 0], self._ring_z.min(axis=1))
        zmax = np.maximum(z[:, 1], self._ring_z.max(axis=1))
        sq = self.squares
        self.bboxes = np.column_stack(
            [sq[:, 0], sq[:, 1], zmin, sq[:, 0] + sq[:, 2], sq[:, 1] + sq[:, 2], zmax]
        )
        d = self.terrain.domain
        self.origin = np.array([d.center[0], d.center[1], self.terrain.z_range[0]])
        # The root square reaches past the data's domain on its shorter side; nodes wholly
        # outside hold no data point (their heights are extrapolated).
        b = self.bboxes
        self.in_domain = (b[:, 0] < d.xmax) & (b[:, 3] > d.xmin) & (b[:, 1] < d.ymax)
        self.in_domain &= b[:, 4] > d.ymin
        self._leaf_error_cache: dict[tuple, np.ndarray] = {}
        self._fan_error_cache: dict[tuple, float] = {}

    def _lookup(self, level: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(k,) rows of nodes (level, i, j), −1 where there is no such node."""
        level, i, j = np.broadcast_arrays(level, i, j)
        inside = (i >= 0) & (j >= 0) & (i < (1 << level)) & (j < (1 << level))
        inside &= level <= MAX_DEPTH
        keys = _encode(level, np.where(inside, i, 0), np.where(inside, j, 0))
        idx = np.minimum(np.searchsorted(self._keys, keys), len(self._keys) - 1)
        return np.where(inside & (self._keys[idx] == keys), idx, -1)

    def _neighbour(self, di: int, dj: int, rows: np.ndarray | None = None) -> np.ndarray:
        """(k,) rows of the same-level neighbours across side (di, dj) of ``rows`` (all)."""
        rows = slice(None) if rows is None else rows
        return self._lookup(self.levels[rows], self.cells[rows, 0] + di, self.cells[rows, 1] + dj)

    def __len__(self) -> int:
        return len(self.node_keys)

    def finer_sides(self, node: tuple[int, int, int], drawn: set | None = None) -> list[bool]:
        """Per side (W, E, S, N): is the neighbour finer (in the tree, or in the cut ``drawn``)?"""
        level, i, j = node
        out = []
        for di, dj in _SIDES:
            nb = (level, i + di, j + dj)
            if drawn is None:
                out.append(bool(self.children.get(nb, False)))
            else:
                out.append(self._subdivided(nb, drawn))
        return out

    def _subdivided(self, node: tuple[int, int, int], drawn: set) -> bool:
        """True when the cut ``drawn`` covers ``node`` with finer nodes (a cut partitions the
        domain: an existing node that is neither drawn nor under a drawn one is refined)."""
        if node not in self.children or node in drawn:
            return False
        level, i, j = node
        while level > 0:
            level, i, j = level - 1, i // 2, j // 2
            if (level, i, j) in drawn:
                return False
        return True

    def boundary(
        self, node: tuple[int, int, int], midpoints: list[bool], keep: list[bool] | None = None
    ) -> np.ndarray:
        """(b, 3) centre, then the boundary lattice points counter-clockwise from SW.

        midpoints: per side W, E, S, N whether the edge midpoint is a vertex; keep: per side
        whether it keeps its own height (else it lies on the straight edge).
        """
        keep = midpoints if keep is None else keep
        ring = self._ring_xyz[self.index[node]]
        # Ring slots: 0 SW, 1 SE, 2 NE, 3 NW, 4 centre, 5 S, 6 E, 7 N, 8 W (``_ring_codes``).
        slots, flat = [4], []
        for corner, side, mid, a, b in _BOUNDARY:
            slots.append(corner)
            if midpoints[side]:
                slots.append(mid)
                if not keep[side]:
                    flat.append((len(slots) - 1, a, b))
        out = ring[slots]
        for pos, a, b in flat:
            out[pos, 2] = 0.5 * (ring[a, 2] + ring[b, 2])
        return out

    def _insertion_orders(self) -> None:
        # Every leaf's base ring (centre, then SW, [S], SE, [E], NE, [N], NW, [W] with the
        # midpoints its finer neighbours need) as one array, and one kernel call for all leaves.
        rows = np.flatnonzero(~self.internal)
        slots = np.array([4, 0, 5, 1, 6, 2, 7, 3, 8])
        tf = self.tree_finer[rows]
        on = np.ones(len(rows), dtype=bool)
        mask = np.column_stack([on, on, tf[:, 2], on, tf[:, 1], on, tf[:, 3], on, tf[:, 0]])
        bases = self._ring_xyz[rows][:, slots][mask]
        base_start = np.concatenate([[0], np.cumsum(mask.sum(axis=1))]).astype(np.int64)
        r = self.ranges[rows]
        orders, errors = insertion_orders(
            np.ascontiguousarray(bases), base_start, self.points, r[:, 0].copy(), r[:, 1].copy()
        )
        counts = (r[:, 1] - r[:, 0]).tolist()
        self.orders: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
        o = e = 0
        for row, n in zip(rows.tolist(), counts, strict=True):
            self.orders[self.node_keys[row]] = (orders[o : o + n], errors[e : e + n + 1])
            o, e = o + n, e + n + 1
        self._order_error_table()

    def _order_error_table(self) -> None:
        """The recorded errors of all leaves in one array: leaf row r owns order_errors[
        error_start[r] : error_start[r] + its point count + 1] (internal rows own nothing)."""
        counts = np.where(self.internal, 0, self.ranges[:, 1] - self.ranges[:, 0] + 1)
        self.error_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        leaves = np.flatnonzero(~self.internal)
        self.order_errors = np.concatenate([self.orders[self.node_keys[r]][1] for r in leaves])
        # The recorded orders alike: leaf row r owns order_flat[order_start[r]:] (its count).
        counts = np.where(self.internal, 0, self.ranges[:, 1] - self.ranges[:, 0])
        self.order_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        self.order_flat = np.concatenate(
            [np.zeros(0, dtype=np.int64)] + [self.orders[self.node_keys[r]][0] for r in leaves]
        ).astype(np.int64)

    # -- render time ---------------------------------------------------------------------------

    def leaf_mesh(
        self, leaf: tuple[int, int, int], k: int, keep: list[bool] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, triangles) of ``leaf`` after replaying its first k insertions."""
        lo, hi = self.point_range(leaf)
        order, _ = self.orders[leaf]
        base = self.boundary(leaf, self.tree_finer[self.index[leaf]].tolist(), keep)
        pts = self.points[lo:hi]
        replay = order if len(order) else np.array([-1])
        _, _, tris = insert_points(base, pts, replay if k else np.array([0]), k)
        return np.concatenate([base, pts]), tris

    def leaf_errors(self, leaf: tuple[int, int, int], keep: tuple[bool, ...]) -> np.ndarray:
        """(n + 1,) measured max |z − mesh| over the leaf's points after 0..n insertions of its
        recorded order, for the boundary whose midpoints keep their heights per ``keep``."""
        tree_keep = tuple(self.tree_finer[self.index[leaf]].tolist())
        keep = tuple(bool(k) and t for k, t in zip(keep, tree_keep, strict=True))
        if keep == tree_keep:
            return self.orders[leaf][1]
        key = (leaf, keep)
        errors = self._leaf_error_cache.get(key)
        if errors is None:
            lo, hi = self.point_range(leaf)
            order = self.orders[leaf][0]
            base = self.boundary(leaf, list(tree_keep), list(keep))
            replay = order if len(order) else np.array([-1])
            _, errors, _ = insert_points(base, self.points[lo:hi], replay, hi - lo)
            self._leaf_error_cache[key] = errors
        return errors

    def fan_error(self, node: tuple[int, int, int], midpoints: tuple[bool, ...]) -> float:
        """Measured max |z − fan| over the node's points for the fan with ``midpoints``."""
        key = (node, tuple(bool(m) for m in midpoints))
        err = self._fan_error_cache.get(key)
        if err is None:
            lo, hi = self.point_range(node)
            base = self.boundary(node, list(key[1]))
            err = float(insert_points(base, self.points[lo:hi], np.array([-1]), 0)[1][0])
            self._fan_error_cache[key] = err
        return err

    def lod_cut(
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
        e = np.asarray(eye, dtype=np.float64)
        sc = np.ones(3) if scale is None else np.asarray(scale, dtype=np.float64)
        box = self.bboxes
        d = np.linalg.norm((e - np.clip(e, box[:, :3], box[:, 3:])) * sc, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.where(d > 0, lam * self.node_errors / d, np.inf)
        rho[self.node_errors == 0] = 0.0
        want = self.internal & (rho > tolerance)
        if visible is not None:
            want &= np.asarray(visible, dtype=bool)
        # Traversal from the root, level by level (rows are sorted by level).
        reached = np.zeros(len(self), dtype=bool)
        reached[0] = True
        bounds = np.searchsorted(self.levels, np.arange(self.levels[-1] + 2))
        for level in range(1, int(self.levels[-1]) + 1):
            rows = np.arange(bounds[level], bounds[level + 1])
            p = self.parents[rows]
            reached[rows] = reached[p] & want[p]
        refined = reached & want
        drawn = reached & ~want
        self._restrict_rows(drawn, refined, want)
        rows = np.flatnonzero(drawn)
        cut_finer = np.stack(
            [refined[np.maximum(nb, 0)] & (nb >= 0) for nb in self._side_rows(rows)], axis=1
        )
        midpoints = np.where(self.internal[rows, None], cut_finer, self.tree_finer[rows])
        inserted = np.where(self.internal[rows], -1, 0)
        errors = self.node_errors[rows].copy()
        vis = np.ones(len(rows), dtype=bool) if visible is None else np.asarray(visible)[rows]
        budgets = tolerance * d[rows] / lam
        # A visible leaf with the boundary it was recorded with replays up to its first prefix
        # within C·d/λ (one kernel call for all of them).
        recorded = vis & ~self.internal[rows] & (cut_finer == self.tree_finer[rows]).all(axis=1)
        r = rows[recorded]
        inserted[recorded], errors[recorded] = first_within(
            self.order_errors,
            self.error_start[r],
            self.ranges[r, 1] - self.ranges[r, 0] + 1,
            budgets[recorded],
        )
        # The others, beside a drawn neighbour of another level: a leaf whose midpoint lies on
        # the coarser neighbour's straight edge, or a coarse node's fan; their errors are
        # measured for that boundary on first use.
        for k in np.flatnonzero(vis & ~recorded).tolist():
            node = self.node_keys[rows[k]]
            if self.internal[rows[k]]:
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

    def _side_rows(self, rows: np.ndarray) -> list[np.ndarray]:
        return [self._neighbour(di, dj, rows) for di, dj in _SIDES]

    def _restrict_rows(self, drawn: np.ndarray, refined: np.ndarray, want: np.ndarray) -> None:
        """Restrict the cut in place: split drawn nodes next to neighbours refined twice along
        the shared edge (leaves two levels apart would meet), and nodes the splits put in the
        cut that ask for refinement themselves; repeat until stable."""
        # Children of the west, east, south, north neighbour that touch the shared edge.
        adjacent = ((1, 0, 1, 1), (0, 0, 0, 1), (0, 1, 1, 1), (0, 0, 1, 0))
        while True:
            cand = np.flatnonzero(drawn & self.internal)
            if len(cand) == 0:
                return
            lv, i, j = self.levels[cand], self.cells[cand, 0], self.cells[cand, 1]
            split = want[cand].copy()
            for (di, dj), (a0, b0, a1, b1) in zip(_SIDES, adjacent, strict=True):
                ni, nj = i + di, j + dj
                for a, b in ((a0, b0), (a1, b1)):
                    kid = self._lookup(lv + 1, 2 * ni + a, 2 * nj + b)
                    split |= (kid >= 0) & refined[np.maximum(kid, 0)]
            if not split.any():
                return
            s = cand[split]
            drawn[s] = False
            refined[s] = True
            drawn[self.child_rows[s].ravel()] = True

    def node_mesh(
        self,
        node: tuple[int, int, int],
        midpoints: tuple[bool, ...],
        keep: tuple[bool, ...],
        inserted: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (n, 3) world, triangles (m, 3)) of one drawn node of a cut.

        inserted: points replayed (a leaf), or −1 for a coarse node's fan. A midpoint laid on
        the straight edge (not kept) gets a zero-area triangle over its edge: the coarser
        neighbour's edge then meets this mesh edge for edge on screen (no T-junction pinhole).
        """
        v, _, t, _ = self.node_meshes(
            np.array([self.index[node]]), np.array([midpoints]), np.array([keep]), [inserted]
        )
        return v, t

    def node_meshes(
        self,
        rows: np.ndarray,
        midpoints: np.ndarray,
        keep: np.ndarray,
        inserted: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The meshes of k drawn nodes (``node_mesh`` of each, in one kernel call).

        rows: (k,) node rows; midpoints, keep: (k, 4) bool; inserted: (k,) as in ``LODCut``.
        Returns (vertices (V, 3) world, vertex_start (k + 1,), triangles (T, 3) int64,
        triangle_start (k + 1,)): node m's vertices are vertices[vertex_start[m]:
        vertex_start[m + 1]] and its triangles, indexing them from 0,
        triangles[triangle_start[m]:triangle_start[m + 1]].
        """
        k = len(rows)
        return node_meshes(
            self._ring_xyz,
            self.points,
            self.ranges,
            self.order_flat,
            self.order_start,
            np.asarray(rows, dtype=np.int64).reshape(k),
            np.ascontiguousarray(np.asarray(midpoints, dtype=np.bool_).reshape(k, 4)),
            np.ascontiguousarray(np.asarray(keep, dtype=np.bool_).reshape(k, 4)),
            np.asarray(inserted, dtype=np.int64).reshape(k),
        )

    def lod_mesh(
        self, eye: tuple[float, float, float], fov: float, width: int, tolerance: float = 10.0
    ) -> LODMesh:
        """The view-dependent mesh for an eye position, horizontal field of view (degrees),
        viewport width (pixels) and screen tolerance C (pixels): λ = width / fov."""
        cut = self.lod_cut(eye, width / math.radians(fov), tolerance)
        verts, vstart, tris, tstart = self.node_meshes(
            cut.rows, cut.midpoints, cut.keep, cut.inserted
        )
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

    # -- storage -------------------------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> int:
        """Write the quadtree (terrain, nodes, heights, insertion orders) atomically as a tree
        store at ``path`` (``tree.store``); returns the bytes stored. A .atree path is an
        InvalidParameterError (that format is read only)."""
        return store.save(self, path)

    def to_sections(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """(meta, arrays) of the quadtree for a tree store (terrain apart)."""
        leaves = [self.node_keys[r] for r in np.flatnonzero(~self.internal)]
        lattice = sorted(self.lattice.items())
        arrays = {
            "header": np.array([self.max_points, self.size, self.x0, self.y0], dtype="<f8"),
            "points": self.points,
            "codes": self.codes,
            "nodes": np.array(self.node_keys, dtype="<i8").reshape(-1, 3),
            "internal": self.internal,
            "node_errors": self.node_errors,
            "lattice_keys": np.array([k for k, _ in lattice], dtype="<i8").reshape(-1, 2),
            "lattice_xyz": np.array([v for _, v in lattice], dtype="<f8").reshape(-1, 3),
            "order_counts": np.array([len(self.orders[n][0]) for n in leaves], dtype="<i8"),
            "orders": np.concatenate([self.orders[n][0] for n in leaves]).astype("<i8"),
            "order_errors": np.concatenate([self.orders[n][1] for n in leaves]),
        }
        meta = {
            "library": f"approxtree {__version__}",
            "tree_kind": TREE_KIND,
            "section_version": SECTION_VERSION,
            "terrain_kind": self.terrain.kind,
        }
        return meta, arrays

    @classmethod
    def load(cls, path: str | os.PathLike) -> PointQuadtree:
        """Read a quadtree written by ``save``, or a legacy .atree file of tree kind
        "point_quadtree" (every checksum verified)."""
        return cls.from_source(store.open_store(path))

    @classmethod
    def from_source(cls, source: store.TreeSource) -> PointQuadtree:
        """The quadtree of a saved tree opened by ``tree.store.open_store`` (every array read
        and checked now)."""
        if source.tree_kind != TREE_KIND:
            raise StoreError(
                f"{source.location} holds an approximation tree, not a point quadtree; open it "
                "with ApproximationTree.load or approxtree.load_tree."
            )
        source.verify()
        return cls.from_sections(
            source.meta, source.terrain(), source.quadtree_arrays(), source.location
        )

    @classmethod
    def from_sections(
        cls, meta: dict[str, Any], terrain: TIN, raw: dict[str, np.ndarray], path: str
    ) -> PointQuadtree:
        """The quadtree of ``to_sections``'s meta and arrays over ``terrain`` (``path``: the
        saved tree's location, for messages)."""
        if meta.get("section_version") != SECTION_VERSION:
            raise StoreError(
                f"{path} has point quadtree layout {meta.get('section_version')!r}; this "
                f"approxtree reads {SECTION_VERSION}. Rebuild it with this version."
            )
        a = {k: np.array(v) for k, v in raw.items()}
        try:
            return cls._from_arrays(terrain, a)
        except (KeyError, ValueError, IndexError) as exc:
            raise StoreError(
                f"{path} holds a malformed point quadtree ({exc}); rebuild it."
            ) from exc

    @classmethod
    def _from_arrays(cls, terrain: TIN, a: dict[str, np.ndarray]) -> PointQuadtree:
        header = a["header"]
        q = cls(terrain, int(header[0]), _build=False)
        q.size, q.x0, q.y0 = float(header[1]), float(header[2]), float(header[3])
        q.points, q.codes = a["points"].astype(np.float64), a["codes"].astype(np.int64)
        nodes = [tuple(int(v) for v in n) for n in a["nodes"]]
        q.children = dict(zip(nodes, a["internal"].astype(bool).tolist(), strict=True))
        q.lattice = {
            (int(k[0]), int(k[1])): tuple(float(c) for c in v)
            for k, v in zip(a["lattice_keys"], a["lattice_xyz"], strict=True)
        }
        q._index()
        q.node_errors = a["node_errors"].astype(np.float64)
        if len(q.node_errors) != len(q):
            raise ValueError("one error per node expected")
        q.errors = dict(zip(q.node_keys, q.node_errors.tolist(), strict=True))
        q.orders = {}
        o = e = 0
        leaves = [q.node_keys[r] for r in np.flatnonzero(~q.internal)]
        for leaf, n in zip(leaves, a["order_counts"].tolist(), strict=True):
            q.orders[leaf] = (
                a["orders"][o : o + n].astype(np.int64),
                a["order_errors"][e : e + n + 1],
            )
            o, e = o + n, e + n + 1
        q._order_error_table()
        return q

    # -- figures -------------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        """Figures of the built quadtree (``approxtree build --kind point-quadtree``)."""
        leaves = ~self.internal
        counts = self.ranges[leaves, 1] - self.ranges[leaves, 0]
        return {
            "tree_kind": TREE_KIND,
            "nodes": len(self),
            "leaves": int(leaves.sum()),
            "depth": int(self.levels.max()),
            "points": len(self.points),
            "max_points": self.max_points,
            "max_leaf_points": int(counts.max()),
            "interpolation_points": self.interpolation_point_count(),
            "root_error": float(self.node_errors[0]),
        }

    def interpolation_point_count(self) -> int:
        """N_C: distinct lattice points of the leaves' initial triangulations."""
        keys = set()
        for leaf in self.leaves:
            level, i, j = leaf
            finer = self.finer_sides(leaf)
            uv = [(2 * i + a, 2 * j + b) for a in (0, 2) for b in (0, 2)] + [(2 * i + 1, 2 * j + 1)]
            mids = [
                (2 * i, 2 * j + 1),
                (2 * i + 2, 2 * j + 1),
                (2 * i + 1, 2 * j),
                (2 * i + 1, 2 * j + 2),
            ]
            uv += [m for m, f in zip(mids, finer, strict=True) if f]
            keys.update(self._lattice_key(level, u, v) for u, v in uv)
        return len(keys)
