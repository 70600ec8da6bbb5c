"""PointQuadtree: quadtree domain decomposition of scattered points with per-leaf insertion
orders (seed 003, "View-dependent LOD of TIN based on quadtree domain decomposition").

Build (pre-processing):

1. the root is the square around the points' domain; a node is split while it holds more than
   δ points (``max_points``); points are sorted in Z-order so every node owns a contiguous run;
2. the quadtree is *restricted*: split leaves until edge-neighbouring leaves differ by at most
   one level (no T-shaped cracks between leaf triangulations);
3. interpolation points — the lattice points used as corners, centres and edge midpoints of the
   nodes — get heights averaged from their 4 nearest data points;
4. each node's error δ(node) is the max ``|z − fan|`` over its points (fan: 4 triangles between the
   centre and the corners); each leaf records, at build time, the order in which its points are
   inserted (largest error first) and the error after every insertion.

The quadtree holds structure and build only. Render time — the view-dependent cut (a node
refined while its screen projection error ρ = λ·δ/d exceeds the tolerance C, the cut
restricted again, leaves replaying a prefix of their insertion order) and the meshes of its
drawn nodes — lives in render/lod_cut.py; the Engine draws it through its tile source
(render/point_quadtree_source.py). δ(node) of an internal node is the largest error over every
fan the node can be drawn as (with or without each side's midpoint), so the cut's screen
errors are measured bounds, never estimates.

Storage (``tree.store``): ``save`` writes a tree store (terrain plus the "quadtree" arrays of
``to_sections``); ``load`` reads a store or a legacy .atree file of tree kind "point_quadtree"
(and refuses the ``.npz`` files of earlier versions with a StoreError saying to rebuild).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.geometry.tin import TIN
from approxtree.kernels.point_quadtree import (
    fan_errors,
    insertion_orders,
    morton_codes,
    range_z_bounds,
)
from approxtree.tree import quadtree_store, store
from approxtree.tree.quadtree_store import TREE_KIND

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
        self.lattice: dict[tuple[int, int], tuple[float, float, float]] = dict(
            zip(keys, xyz, strict=True)
        )

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
        sel: slice | np.ndarray = slice(None) if rows is None else rows
        return self._lookup(self.levels[sel], self.cells[sel, 0] + di, self.cells[sel, 1] + dj)

    def __len__(self) -> int:
        return len(self.node_keys)

    def finer_sides(self, node: tuple[int, int, int]) -> list[bool]:
        """Per side (W, E, S, N): is the neighbour in the tree finer than ``node``?"""
        level, i, j = node
        return [bool(self.children.get((level, i + di, j + dj), False)) for di, dj in _SIDES]

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

    # -- storage -------------------------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> int:
        """Write the quadtree (terrain, nodes, heights, insertion orders) atomically as a tree
        store at ``path`` (``tree.store``); returns the bytes stored. A .atree path is an
        InvalidParameterError (that format is read only)."""
        return store.save(self, path)

    def to_sections(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """(meta, arrays) of the quadtree for a tree store (terrain apart; ``quadtree_store``)."""
        return quadtree_store.to_sections(self)

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
        terrain = source.terrain()
        if not isinstance(terrain, TIN):
            raise StoreError(
                f"{source.location} holds a point quadtree over a {terrain.kind}, not a TIN; "
                "rebuild it."
            )
        return cls.from_sections(source.meta, terrain, source.quadtree_arrays(), source.location)

    @classmethod
    def from_sections(
        cls, meta: dict[str, Any], terrain: TIN, raw: dict[str, np.ndarray], path: str
    ) -> PointQuadtree:
        """The quadtree of ``to_sections``'s meta and arrays over ``terrain`` (``path``: the
        saved tree's location, for messages)."""
        arrays = quadtree_store.checked_arrays(meta, raw, path)
        q = cls(terrain, quadtree_store.max_points(arrays), _build=False)
        quadtree_store.fill(q, arrays, path)
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
        keys: set[tuple[int, int]] = set()
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
