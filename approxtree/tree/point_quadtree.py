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

Render time (``lod_mesh``): a node is refined while the screen projection error
ρ = λ·δ/d > C (λ = w/φ: viewport width in pixels over the horizontal field of view); the cut
is restricted again; a drawn leaf whose ρ still exceeds C replays its insertion order until
ρ ≤ C or no point is left. Edge midpoints are kept where the drawn neighbour is finer and laid
on the straight edge otherwise, so the mesh is continuous.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.geometry.tin import TIN
from approxtree.kernels.point_quadtree import fan_errors, insert_points, morton_codes

#: Version of the .npz layout written by ``PointQuadtree.save``.
FORMAT_VERSION = 1
#: Finest quadtree level (2^20 cells a side); points sharing a finest cell stay in one leaf.
MAX_DEPTH = 20
# Edge directions: west, east, south, north as (di, dj).
_SIDES = ((-1, 0), (1, 0), (0, -1), (0, 1))


@dataclass
class LODMesh:
    """A view-dependent mesh: vertices (n, 3) world, triangles (m, 3), figures of the cut."""

    vertices: np.ndarray
    triangles: np.ndarray
    nodes: int
    leaves_refined: int
    points_inserted: int


class PointQuadtree:
    """Restricted quadtree over a TIN / TINPointSet with per-leaf insertion orders.

    terrain: the point set; max_points: δ, the most points a leaf holds (>= 1).
    Nodes are keyed (level, i, j): cell i (east), j (north) of the 2^level lattice.
    """

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
        self._errors()
        self._insertion_orders()

    # -- build ---------------------------------------------------------------------------------

    def point_range(self, node: tuple[int, int, int]) -> tuple[int, int]:
        """[start, stop) of the node's points in ``self.points`` (Z-order)."""
        level, i, j = node
        shift = 2 * (MAX_DEPTH - level)
        prefix = int(morton_codes(np.array([i]), np.array([j]), level)[0]) << shift
        lo = int(np.searchsorted(self.codes, prefix, side="left"))
        hi = int(np.searchsorted(self.codes, prefix + (1 << shift), side="left"))
        return lo, hi

    def _split(self, node: tuple[int, int, int]) -> list[tuple[int, int, int]]:
        level, i, j = node
        self.children[node] = True
        kids = [(level + 1, 2 * i + a, 2 * j + b) for b in (0, 1) for a in (0, 1)]
        for k in kids:
            self.children.setdefault(k, False)
        return kids

    def _subdivide(self) -> None:
        # Split while a node holds more than δ points (one level at a time).
        self.children[(0, 0, 0)] = False
        frontier = [(0, 0, 0)]
        while frontier:
            nxt = []
            for node in frontier:
                lo, hi = self.point_range(node)
                if hi - lo > self.max_points and node[0] < MAX_DEPTH:
                    nxt.extend(self._split(node))
            frontier = nxt

    def _ensure(self, node: tuple[int, int, int]) -> list[tuple[int, int, int]]:
        """Make ``node`` exist by splitting its ancestors; returns the nodes split."""
        if node in self.children:
            return []
        level, i, j = node
        parent = (level - 1, i // 2, j // 2)
        split = self._ensure(parent)
        self._split(parent)
        return [*split, parent]

    def _restrict(self) -> None:
        # An internal node's edge neighbours must exist at its level, else a leaf two or more
        # levels coarser would touch its grandchildren. New splits are checked in turn.
        work = [n for n, internal in self.children.items() if internal]
        while work:
            level, i, j = work.pop()
            for di, dj in _SIDES:
                ni, nj = i + di, j + dj
                if 0 <= ni < (1 << level) and 0 <= nj < (1 << level):
                    work.extend(self._ensure((level, ni, nj)))

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

        keys = set()
        for level, i, j in self.children:
            for u in (2 * i, 2 * i + 1, 2 * i + 2):
                for v in (2 * j, 2 * j + 1, 2 * j + 2):
                    keys.add(self._lattice_key(level, u, v))
        key_arr = np.array(sorted(keys), dtype=np.int64)
        unit = self.size / (1 << (MAX_DEPTH + 1))
        xy = np.column_stack([self.x0 + key_arr[:, 0] * unit, self.y0 + key_arr[:, 1] * unit])
        k = min(4, len(self.points))
        _, near = cKDTree(self.points[:, :2]).query(xy, k=k)
        z = self.points[np.asarray(near).reshape(len(xy), k), 2].mean(axis=1)
        self.lattice = {
            (int(a), int(b)): (x, y, h) for (a, b), (x, y), h in zip(key_arr, xy, z, strict=True)
        }

    def lattice_point(self, level: int, u: int, v: int) -> tuple[float, float, float]:
        """World (x, y, z) of half-cell lattice point (u, v) of ``level``."""
        return self.lattice[self._lattice_key(level, u, v)]

    def _fan_z(self, node: tuple[int, int, int]) -> list[float]:
        level, i, j = node
        uv = [(2 * i, 2 * j), (2 * i + 2, 2 * j), (2 * i + 2, 2 * j + 2), (2 * i, 2 * j + 2)]
        return [self.lattice_point(level, u, v)[2] for u, v in uv] + [
            self.lattice_point(level, 2 * i + 1, 2 * j + 1)[2]
        ]

    def _errors(self) -> None:
        nodes = list(self.children)
        ranges = np.array([self.point_range(n) for n in nodes], dtype=np.int64)
        squares = np.array([self.square(n) for n in nodes])
        cz = np.array([self._fan_z(n) for n in nodes])
        p = self.points
        err = fan_errors(
            p[:, 0].copy(),
            p[:, 1].copy(),
            p[:, 2].copy(),
            ranges[:, 0].copy(),
            ranges[:, 1].copy(),
            squares,
            cz,
        )
        self.errors = dict(zip(nodes, err.tolist(), strict=True))

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
        level, i, j = node
        keep = midpoints if keep is None else keep
        lp = self.lattice_point
        sw, se = lp(level, 2 * i, 2 * j), lp(level, 2 * i + 2, 2 * j)
        ne, nw = lp(level, 2 * i + 2, 2 * j + 2), lp(level, 2 * i, 2 * j + 2)
        mids = {
            2: (lp(level, 2 * i + 1, 2 * j), sw, se),
            1: (lp(level, 2 * i + 2, 2 * j + 1), se, ne),
            3: (lp(level, 2 * i + 1, 2 * j + 2), ne, nw),
            0: (lp(level, 2 * i, 2 * j + 1), nw, sw),
        }
        ring = [lp(level, 2 * i + 1, 2 * j + 1)]
        for corner, side in ((sw, 2), (se, 1), (ne, 3), (nw, 0)):
            ring.append(corner)
            if midpoints[side]:
                m, a, b = mids[side]
                ring.append(m if keep[side] else (m[0], m[1], 0.5 * (a[2] + b[2])))
        return np.array(ring, dtype=np.float64)

    def _insertion_orders(self) -> None:
        self.orders: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
        for leaf in self.leaves:
            lo, hi = self.point_range(leaf)
            base = self.boundary(leaf, self.finer_sides(leaf))
            order, errors, _ = insert_points(base, self.points[lo:hi], np.array([-1]), hi - lo)
            self.orders[leaf] = (order, errors)

    # -- render time ---------------------------------------------------------------------------

    def leaf_mesh(
        self, leaf: tuple[int, int, int], k: int, keep: list[bool] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, triangles) of ``leaf`` after replaying its first k insertions."""
        lo, hi = self.point_range(leaf)
        order, _ = self.orders[leaf]
        base = self.boundary(leaf, self.finer_sides(leaf), keep)
        pts = self.points[lo:hi]
        replay = order if len(order) else np.array([-1])
        _, _, tris = insert_points(base, pts, replay if k else np.array([0]), k)
        return np.concatenate([base, pts]), tris

    def lod_mesh(
        self, eye: tuple[float, float, float], fov: float, width: int, tolerance: float = 10.0
    ) -> LODMesh:
        """The view-dependent mesh for an eye position, horizontal field of view (degrees),
        viewport width (pixels) and screen tolerance C (pixels)."""
        lam = width / math.radians(fov)
        e = np.asarray(eye, dtype=np.float64)

        def distance(node) -> float:
            x0, y0, s = self.square(node)
            q = np.clip(e[:2], [x0, y0], [x0 + s, y0 + s])
            z = self.lattice_point(node[0], 2 * node[1] + 1, 2 * node[2] + 1)[2]
            return max(float(np.hypot(*(e[:2] - q)) ** 2 + (e[2] - z) ** 2) ** 0.5, 1e-9)

        drawn: set[tuple[int, int, int]] = set()
        stack = [(0, 0, 0)]
        while stack:
            node = stack.pop()
            if self.children[node] and lam * self.errors[node] / distance(node) > tolerance:
                level, i, j = node
                stack.extend((level + 1, 2 * i + a, 2 * j + b) for a in (0, 1) for b in (0, 1))
            else:
                drawn.add(node)
        drawn = self._restrict_cut(drawn)
        verts, tris = [], []
        offset = inserted = refined = 0
        for node in drawn:
            finer = self.finer_sides(node, drawn)
            if self.is_leaf(node):
                _, errors = self.orders[node]
                budget = tolerance * distance(node) / lam
                k = (
                    int(np.argmax(errors <= budget))
                    if (errors <= budget).any()
                    else len(errors) - 1
                )
                refined += k > 0
                inserted += k
                v, t = self.leaf_mesh(node, k, keep=finer)
            else:
                v = self.boundary(node, finer)
                b = len(v)
                t = np.array([[0, a, a + 1 if a + 1 < b else 1] for a in range(1, b)])
            verts.append(v)
            tris.append(t + offset)
            offset += len(v)
        return LODMesh(np.concatenate(verts), np.concatenate(tris), len(drawn), refined, inserted)

    def _restrict_cut(self, drawn: set) -> set:
        # Split drawn nodes whose edge neighbour's children along the shared edge are refined
        # (leaves two levels apart would meet); splits can ripple, so repeat until stable.
        adjacent = {
            (-1, 0): ((1, 0), (1, 1)),
            (1, 0): ((0, 0), (0, 1)),
            (0, -1): ((0, 1), (1, 1)),
            (0, 1): ((0, 0), (1, 0)),
        }
        changed = True
        while changed:
            changed = False
            for node in sorted(drawn, key=lambda n: -n[0]):
                if node not in drawn or not self.children[node]:
                    continue
                level, i, j = node
                for di, dj in _SIDES:
                    ni, nj = i + di, j + dj
                    kids = [(level + 1, 2 * ni + a, 2 * nj + b) for a, b in adjacent[(di, dj)]]
                    if any(self._subdivided(k, drawn) for k in kids):
                        drawn.discard(node)
                        drawn.update(
                            (level + 1, 2 * i + a, 2 * j + b) for a in (0, 1) for b in (0, 1)
                        )
                        changed = True
                        break
        return drawn

    # -- storage -------------------------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> int:
        """Write the quadtree (terrain, nodes, heights, insertion orders) atomically as .npz;
        returns the file size."""
        from approxtree.io.atomic import atomic_write

        nodes = list(self.children)
        leaves = self.leaves
        lattice = sorted(self.lattice.items())
        _, tarrays = self.terrain.to_record()
        arrays = {
            "header": np.array(
                [FORMAT_VERSION, self.max_points, self.size, self.x0, self.y0], dtype="<f8"
            ),
            "crs": np.array(self.terrain.crs or ""),
            "terrain_vertices": tarrays["vertices"],
            "terrain_triangles": tarrays["triangles"],
            "points": self.points,
            "codes": self.codes,
            "nodes": np.array(nodes, dtype="<i8").reshape(-1, 3),
            "internal": np.array([self.children[n] for n in nodes], dtype=bool),
            "node_errors": np.array([self.errors[n] for n in nodes], dtype="<f8"),
            "lattice_keys": np.array([k for k, _ in lattice], dtype="<i8").reshape(-1, 2),
            "lattice_xyz": np.array([v for _, v in lattice], dtype="<f8").reshape(-1, 3),
            "leaves": np.array(leaves, dtype="<i8").reshape(-1, 3),
            "order_counts": np.array([len(self.orders[n][0]) for n in leaves], dtype="<i8"),
            "orders": np.concatenate([self.orders[n][0] for n in leaves] or [np.zeros(0)]),
            "order_errors": np.concatenate([self.orders[n][1] for n in leaves]),
        }
        with atomic_write(path) as f:
            np.savez(f, **arrays)
        return os.path.getsize(path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> PointQuadtree:
        """Read a quadtree written by ``save``."""
        try:
            with np.load(path, allow_pickle=False) as z:
                a = {k: z[k] for k in z.files}
        except (OSError, ValueError, KeyError) as exc:
            raise StoreError(f"Cannot read point quadtree {path}: {exc}") from exc
        header = a.get("header")
        if header is None or int(header[0]) != FORMAT_VERSION:
            raise StoreError(
                f"{path} is not a point quadtree file of format {FORMAT_VERSION}; rebuild it."
            )
        crs = str(a["crs"]) or None
        terrain = TIN.from_record(
            {"crs": crs}, {"vertices": a["terrain_vertices"], "triangles": a["terrain_triangles"]}
        )
        q = cls(terrain, int(header[1]), _build=False)
        q.size, q.x0, q.y0 = float(header[2]), float(header[3]), float(header[4])
        q.points, q.codes = a["points"], a["codes"]
        nodes = [tuple(int(v) for v in n) for n in a["nodes"]]
        q.children = dict(zip(nodes, a["internal"].tolist(), strict=True))
        q.errors = dict(zip(nodes, a["node_errors"].tolist(), strict=True))
        q.lattice = {
            (int(k[0]), int(k[1])): tuple(float(c) for c in v)
            for k, v in zip(a["lattice_keys"], a["lattice_xyz"], strict=True)
        }
        q.orders = {}
        o = e = 0
        for leaf, n in zip(a["leaves"], a["order_counts"], strict=True):
            n = int(n)
            q.orders[tuple(int(v) for v in leaf)] = (
                a["orders"][o : o + n].astype(np.int64),
                a["order_errors"][e : e + n + 1],
            )
            o, e = o + n, e + n + 1
        return q

    # -- figures -------------------------------------------------------------------------------

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
