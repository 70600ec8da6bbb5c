"""A tree store's patches as world triangles, decoded from the stored records (own code).

``PatchDecoder.triangles(nodes)`` gives the (t, 9) world triangles (x, y, z per corner) of
the nodes' patches and the node of each, as ``verify.measure`` wants them; on the way it
records each node's vertex extent (for the bounding boxes) and the nodes whose record does not
decode (``bad``). Vertex heights of lattice patches are the store's own terrain heights (what
a renderer of the store draws), read through a chunk cache; records follow the layouts of
``kernels.verify_records``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from approxtree.kernels._jit import readonly
from approxtree.kernels.verify_records import (
    grid_lines,
    index_meshes,
    lattice_points,
    lattice_soup,
    nonregular_lines,
)
from approxtree.verify.zarr_read import ChunkReader

#: Terrain kinds whose patches this decoder reads: lattices over a grid, or point TINs.
GRID_KINDS = ("grid",)
POINT_KINDS = ("tin", "tinpointset")


class UnsupportedTree(Exception):
    """The store holds a tree this decoder cannot read back (say why in not_checked)."""


class _Field:
    """One record field of a strategy: a (k, width) table or flat data plus offsets."""

    def __init__(self, group: Any, name: str, width: int | None) -> None:
        self.width = width
        if width is not None:
            self.table = ChunkReader(group[name])
        else:
            self.data = ChunkReader(group[f"{name}_data"])
            self.offsets = ChunkReader(group[f"{name}_offsets"])

    def get(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flat, offsets (k + 1,)) of the records at ``slots``."""
        if self.width is not None:
            rows = self.table.take(slots)
            return rows.reshape(-1), np.arange(len(slots) + 1, dtype=np.int64) * self.width
        starts = self.offsets.take(slots).astype(np.int64)
        stops = self.offsets.take(slots + 1).astype(np.int64)
        flat = self.data.ranges(starts, stops)
        return flat, np.r_[0, np.cumsum(np.maximum(stops - starts, 0))].astype(np.int64)


class PatchDecoder:
    """World triangles of a store's patches (module docstring)."""

    def __init__(self, root: Any, meta: dict[str, Any], strategies: np.ndarray, slots: np.ndarray):
        self.terrain_kind = meta.get("terrain_kind")
        self.names = list(meta.get("strategy_names", []))
        self.strategies = strategies
        self.slots = slots
        n = len(strategies)
        self.vmin = np.full((n, 3), np.inf)
        self.vmax = np.full((n, 3), -np.inf)
        #: Nodes whose record did not decode.
        self.bad = np.zeros(n, dtype=bool)
        tattrs = dict(root["terrain"].attrs).get("attrs", {})
        if self.terrain_kind in GRID_KINDS:
            self.transform = [float(v) for v in tattrs["transform"]]
            self.offset = tuple(int(v) for v in tattrs.get("index_offset", (0, 0)))
            self.heights = ChunkReader(root["terrain/heights"])
            self.shape = tuple(int(s) for s in root["terrain/heights"].shape)
        elif self.terrain_kind in POINT_KINDS:
            self.vertices = ChunkReader(root["terrain/vertices"])
            self.n_vertices = int(root["terrain/vertices"].shape[0])
        else:
            raise UnsupportedTree(
                f"patches over a {self.terrain_kind!r} terrain (only trees over a grid or a "
                "point set are read back)"
            )
        self.fields: dict[str, dict[str, _Field]] = {}
        for name in self.names:
            group = root[f"patches/{name}"]
            widths = dict(group.attrs).get("fields", {})
            self.fields[name] = {f: _Field(group, f, w) for f, w in widths.items()}

    # -- world coordinates ---------------------------------------------------------------------

    def _world(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World x, y of full-raster (col, row) indices."""
        a, _, c, _, e, f = self.transform[:6]
        return c + (u + 0.5) * a, f + (v + 0.5) * e

    def _lattice_z(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Store heights at full-raster (row, col) indices, NaN outside the raster."""
        r = rows - self.offset[0]
        c = cols - self.offset[1]
        inside = (r >= 0) & (r < self.shape[0]) & (c >= 0) & (c < self.shape[1])
        z = np.full(len(r), np.nan)
        z[inside] = self.heights.take2d(r[inside], c[inside])
        return z

    def _soup_to_world(self, soup: np.ndarray) -> np.ndarray:
        out = soup.copy()
        for k in range(3):
            out[:, 3 * k], out[:, 3 * k + 1] = self._world(soup[:, 3 * k], soup[:, 3 * k + 1])
        return out

    # -- decoding ------------------------------------------------------------------------------

    def triangles(self, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(soup (t, 9) world, node (t,)) of the patches of ``nodes``."""
        nodes = np.asarray(nodes, dtype=np.int64)
        soups, owners = [], []
        for s, name in enumerate(self.names):
            mine = nodes[self.strategies[nodes] == s]
            if len(mine):
                soup, which = self._strategy(name, mine)
                soups.append(soup)
                owners.append(mine[which])
        unknown = nodes[(self.strategies[nodes] < 0) | (self.strategies[nodes] >= len(self.names))]
        self.bad[unknown] = True
        if not soups:
            return np.zeros((0, 9)), np.zeros(0, dtype=np.int64)
        soup, owner = np.concatenate(soups), np.concatenate(owners)
        self._extents(soup, owner)
        return soup, owner

    def _extents(self, soup: np.ndarray, owner: np.ndarray) -> None:
        """Fold the triangles' corners into their nodes' vertex extents (sorted reductions:
        ``np.minimum.at`` took 4 s on a 1201² tile's 5461 nodes)."""
        if not len(owner):
            return
        corners = soup.reshape(-1, 3, 3)
        lo, hi = corners.min(axis=1), corners.max(axis=1)
        order = np.argsort(owner, kind="stable")
        sorted_owner = owner[order]
        cuts = np.flatnonzero(np.r_[True, sorted_owner[1:] != sorted_owner[:-1]])
        nodes = sorted_owner[cuts]
        self.vmin[nodes] = np.minimum(self.vmin[nodes], np.minimum.reduceat(lo[order], cuts))
        self.vmax[nodes] = np.maximum(self.vmax[nodes], np.maximum.reduceat(hi[order], cuts))

    def _strategy(self, name: str, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Soup and position in ``nodes`` of each triangle, for nodes of one strategy."""
        fields = self.fields[name]
        slots = self.slots[nodes].astype(np.int64)
        if self.terrain_kind in POINT_KINDS:
            return self._point_mesh(nodes, fields["mesh"].get(slots))
        if name == "grid":
            index, _ = fields["index"].get(slots)
            index = index.reshape(-1, 6).astype(np.int64)
            broken = (index[:, 4] < 1) | (index[:, 5] < 1) | (index[:, 1] < index[:, 0])
            broken |= index[:, 3] < index[:, 2]
            index[broken] = (0, 0, 0, 0, 1, 1)
            lines = grid_lines(readonly(index))
            return self._lattice(
                nodes, lines, fields["z"].get(slots) if "z" in fields else None, broken
            )
        if name == "nonregular":
            flat, off = fields["lines"].get(slots)
            lines = nonregular_lines(readonly(flat, np.int64), readonly(off, np.int64))
            empty = (np.diff(lines[1]) < 2) | (np.diff(lines[3]) < 2)
            return self._lattice(nodes, lines, None, empty)
        if "mesh" in fields:
            return self._grid_mesh(nodes, fields["mesh"].get(slots))
        self.bad[nodes] = True
        return np.zeros((0, 9)), np.zeros(0, dtype=np.int64)

    def _lattice(self, nodes, lines, stored_z, broken) -> tuple[np.ndarray, np.ndarray]:
        rows, row_off, cols, col_off = lines
        rr, cc, off = lattice_points(rows, row_off, cols, col_off)
        z = self._lattice_z(rr, cc)
        if stored_z is not None:
            # Coarse grid patches carry their lattice heights; the others read the terrain's.
            flat, zoff = stored_z
            lengths = np.diff(zoff)
            carry = np.flatnonzero(lengths > 0)
            wrong = carry[lengths[carry] != np.diff(off)[carry]]
            broken = broken.copy()
            broken[wrong] = True
            for i in np.setdiff1d(carry, wrong).tolist():
                z[off[i] : off[i + 1]] = flat[zoff[i] : zoff[i + 1]]
        self.bad[nodes[broken]] = True
        soup, which = lattice_soup(rows, row_off, cols, col_off, readonly(z), off)
        keep = ~broken[which]
        return self._soup_to_world(soup[keep]), which[keep]

    def _grid_mesh(self, nodes, record) -> tuple[np.ndarray, np.ndarray]:
        flat, off = record
        verts, vert_off, tris, which, bad = index_meshes(
            readonly(flat, np.int64), readonly(off, np.int64), 2
        )
        self.bad[nodes[bad]] = True
        z = self._lattice_z(verts[:, 0], verts[:, 1])
        uvz = np.column_stack([verts[:, 1].astype(np.float64), verts[:, 0].astype(np.float64), z])
        soup, which = _with_lone_vertices(uvz, tris, which, vert_off)
        return self._soup_to_world(soup), which

    def _point_mesh(self, nodes, record) -> tuple[np.ndarray, np.ndarray]:
        flat, off = record
        verts, vert_off, tris, which, bad = index_meshes(
            readonly(flat, np.int64), readonly(off, np.int64), 1
        )
        index = verts[:, 0]
        outside = (index < 0) | (index >= self.n_vertices)
        if outside.any():
            # A record naming points the terrain does not have: that node's patch is bad.
            hit = np.unique(which[np.isin(tris, np.flatnonzero(outside)).any(axis=1)])
            self.bad[nodes[hit]] = True
            index = np.where(outside, 0, index)
            keep = ~np.isin(which, hit)
            tris, which = tris[keep], which[keep]
        xyz = self.vertices.take(index).astype(np.float64).reshape(-1, 3)
        xyz[outside] = np.nan
        self.bad[nodes[bad]] = True
        return _with_lone_vertices(xyz, tris, which, vert_off)


def _with_lone_vertices(
    xyz: np.ndarray, tris: np.ndarray, which: np.ndarray, vert_off: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(soup, which) of a mesh's triangles, then its vertices in no triangle as lone vertices
    (three equal corners: the writers count a data point that is a vertex as represented).
    xyz: (N, 3) vertices; tris: (T, 3) into them; which: (T,) record; vert_off: (k + 1,)."""
    used = np.zeros(len(xyz), dtype=bool)
    used[tris.ravel()] = True
    lone = np.flatnonzero(~used & np.isfinite(xyz[:, 2]))
    owner = np.repeat(np.arange(len(vert_off) - 1), np.diff(vert_off))
    soup = np.concatenate([xyz[tris].reshape(-1, 9), np.tile(xyz[lone], (1, 3))])
    return soup, np.concatenate([which, owner[lone]])
