"""The unsimplified terrain of an approximation tree, as a tile source of its own.

``Cut(full_resolution=True)`` draws the terrain itself instead of a cut of its tree: the
reference the LOD cut is measured against. A Grid is cut into chunks of CHUNK × CHUNK data
lines that share their border lines (so no cracks and no skirts), each a full-resolution
GridPatch; any other terrain is drawn as the tree's leaves (their patches hold every data
point). A frame selects the chunks whose boxes meet the frustum; a chunk's mesh is built when
uploaded and never kept on the CPU (a chunk is drawn again only from the GPU cache).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.patches.grid import GridPatch
from approxtree.render.cache_keys import CHUNK as CHUNK_KIND
from approxtree.render.cache_keys import MeshKey
from approxtree.render.frame import FramePlan
from approxtree.render.frame_state import FrameState
from approxtree.render.frustum import boxes_in_frustum
from approxtree.render.normal_map import NormalPatches
from approxtree.render.provider import Payload
from approxtree.render.selector import Selection, eye_below_ground

#: Data lines per side of a full-resolution chunk (256 intervals).
CHUNK = 257


class FullResolutionSource:
    """The full-resolution chunks of ``tree``'s terrain (see the module docstring)."""

    def __init__(self, tree: Any) -> None:
        self.tree = tree
        self._chunks: list[tuple[Any, np.ndarray]] | None = None
        self._normals: NormalPatches | None = None

    def chunks(self) -> list[tuple[Any, np.ndarray]]:
        """(patch, bbox (6,)) of every chunk, made on first use."""
        if self._chunks is None:
            terrain, tree = self.tree.terrain, self.tree
            self._chunks = (
                _grid_chunks(terrain)
                if isinstance(terrain, Grid)
                else [(tree.patch(int(i)), tree.bboxes[i]) for i in tree.leaves]
            )
        return self._chunks

    def normal_patches(self, side: int) -> NormalPatches:
        """The normal patches of the chunks (ids as ``chunks()``) within a texture side of
        ``side`` texels, made on first use (again when the side changes)."""
        if self._normals is None or self._normals.max_side != side:
            rects = np.array([b[[0, 1, 3, 4]] for _, b in self.chunks()]).reshape(-1, 4)
            self._normals = NormalPatches(self.tree.terrain, rects, side)
        return self._normals

    def select(self, fs: FrameState) -> Selection:
        """A Selection over the chunks in the frustum (ids index ``chunks()``)."""
        chunks = self.chunks()
        below = eye_below_ground(self.tree, fs)
        if below:
            ids = np.empty(0, dtype=np.int64)
            visible = np.zeros(0, dtype=bool)
        else:
            boxes = np.array([b for _, b in chunks]).reshape(-1, 6)
            visible = boxes_in_frustum(boxes, fs.planes)
            ids = np.flatnonzero(visible)
        stats = {
            "nodes_visited": len(visible),
            "culled": int(np.count_nonzero(~visible)),
            "selected": len(ids),
            "max_alpha": 0.0,
            "max_gamma": 0.0,
        }
        results = np.where(visible, 2, 0).astype(np.uint8)
        return Selection(
            ids,
            np.zeros(len(ids)),
            np.zeros(len(ids)),
            np.arange(len(visible)),
            results,
            below,
            stats,
        )

    def plan(self, selection: Selection) -> FramePlan:
        """The chunks of ``selection``, untextured (the tree's source adds the textures)."""
        meshes = [MeshKey(CHUNK_KIND, int(i)) for i in selection.nodes]
        return FramePlan(selection, meshes, [(None, meshes)])

    def load(self, key: MeshKey) -> Payload:
        """The mesh of a chunk: local vertices relative to the tree's origin, no skirt."""
        patch = self.chunks()[key.item][0]
        verts = patch.vertices
        return Payload.mesh(verts, patch.triangles, np.zeros(len(verts)), self.tree.origin)

    def rect(self, chunk: int) -> Rect:
        """The rectangle a chunk covers (its texture patch's)."""
        b = self.chunks()[chunk][1]
        return Rect(b[0], b[1], b[3], b[4])


def _grid_chunks(terrain: Grid) -> list[tuple[Any, np.ndarray]]:
    """Full-resolution GridPatches over blocks of CHUNK × CHUNK lines of a Grid sharing their
    border lines, blocks without a valid height left out."""
    chunks: list[tuple[Any, np.ndarray]] = []
    rows, cols = terrain.shape
    r_edges = [*range(0, rows - 1, CHUNK - 1), rows - 1]
    c_edges = [*range(0, cols - 1, CHUNK - 1), cols - 1]
    for r0, r1 in itertools.pairwise(r_edges):
        for c0, c1 in itertools.pairwise(c_edges):
            block = terrain.heights[r0 : r1 + 1, c0 : c1 + 1]
            if not np.isfinite(block).any():
                continue
            zr = (float(np.nanmin(block)), float(np.nanmax(block)))
            rect = terrain.rect_of(r0, r1, c0, c1)
            count = int(np.count_nonzero(np.isfinite(block)))
            patch = GridPatch(terrain, rect, (r0, r1, c0, c1, 1, 1), 0.0, zr, count)
            bbox = np.array([rect.xmin, rect.ymin, zr[0], rect.xmax, rect.ymax, zr[1]])
            chunks.append((patch, bbox))
    return chunks
