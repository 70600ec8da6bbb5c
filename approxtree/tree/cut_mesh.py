"""The mesh of a cut: the geometry patches of a set of nodes as one mesh in world coordinates.

A cut is the set of nodes a frame drew (``frame.selection.nodes`` of an Engine frame drawn by
α and γ or a triangle budget), the tree's leaves (the finest cut, within ε everywhere), or any
set of nodes partitioning the domain. ``cut_mesh(tree, nodes)`` concatenates their patches'
vertices and triangles (each patch's vertices first-to-last, node after node) and records the
node of each face; with ``skirts`` the walls are hung as the renderer and the 3D Tiles writer
hang them (depth ε_T(N) plus the largest error across N's sides, curtains down to a common base
on the terrain's outer border; ``patches.skirts``), and each face says whether it is a wall.

It reads each node's patch once, without keeping it (``tree.read_patch``): memory holds the
cut's mesh, not the patches of the store.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.patches.mesh_objects import MeshConversions
from approxtree.patches.skirts import add_skirts, patches_reach_rect, skirt_base, skirt_depths

if TYPE_CHECKING:
    from approxtree.tree.approximation_tree import ApproximationTree


@dataclass(frozen=True)
class CutMesh(MeshConversions):
    """The patches of a cut as one mesh (``cut_mesh``).

    vertices: (n, 3) float64 world coordinates; triangles: (m, 3) int64 indices,
    counter-clockwise seen from above (walls face outwards); nodes: (m,) int64 node of each
    face; skirt: (m,) bool, True for the faces of a skirt wall. ``to_trimesh()`` and
    ``to_pyvista()`` carry z as point data and "node" (and "skirt", with skirts) as face data.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    nodes: np.ndarray
    skirt: np.ndarray

    def _face_data(self) -> dict[str, np.ndarray]:
        data = {"node": self.nodes}
        if self.skirt.any():
            data["skirt"] = self.skirt
        return data


def cut_mesh(
    tree: ApproximationTree, nodes: np.ndarray | None = None, skirts: bool = False
) -> CutMesh:
    """One mesh of the patches of ``nodes`` (k,) node ids (None: the tree's leaves), with the
    renderer's skirts when ``skirts`` (see the module docstring)."""
    ids = _node_ids(tree, nodes)
    walls = None
    if skirts:
        terrain = tree.terrain
        # Skirts exactly as the renderer hangs them (render/engine.py, tiles/tileset3d.py).
        extents = tree.bboxes[:, 5] - tree.bboxes[:, 2]
        reach = patches_reach_rect(terrain)
        rects = np.asarray(tree.rects, dtype=np.float64) if reach else None
        d = terrain.domain
        walls = (
            skirt_depths(tree.errors, terrain.z_range, extents, rects),
            skirt_base(tree.errors, terrain.z_range, extents),
            (d.xmin, d.ymin, d.xmax, d.ymax),
            reach,
        )
    verts, tris, owners, is_wall = [], [], [], []
    start = 0
    for i in ids.tolist():
        patch = tree.read_patch(i)
        v = np.asarray(patch.vertices, dtype=np.float64).reshape(-1, 3)
        t = np.asarray(patch.triangles, dtype=np.int64).reshape(-1, 3)
        surface = len(t)
        if walls is not None and surface:
            depths, base, domain, reach = walls
            rect = patch.rect.as_tuple() if reach else None
            v, t, _ = add_skirts(v, t, float(depths[i]), domain, base, rect)
        verts.append(v)
        tris.append(t + start)
        owners.append(np.full(len(t), i, dtype=np.int64))
        flags = np.zeros(len(t), dtype=bool)
        flags[surface:] = True
        is_wall.append(flags)
        start += len(v)
    if not ids.size:
        return CutMesh(
            np.empty((0, 3)), np.empty((0, 3), np.int64), np.empty(0, np.int64), np.empty(0, bool)
        )
    return CutMesh(
        np.concatenate(verts), np.concatenate(tris), np.concatenate(owners), np.concatenate(is_wall)
    )


def _node_ids(tree: ApproximationTree, nodes: np.ndarray | None) -> np.ndarray:
    """(k,) int64 node ids of the cut, or InvalidParameterError."""
    if nodes is None:
        return tree.leaves
    ids = np.asarray(nodes)
    if ids.ndim != 1 or (ids.size and ids.dtype.kind not in "iu"):
        raise InvalidParameterError(
            f"nodes must be a 1-D array of node ids (e.g. frame.selection.nodes), got "
            f"{ids.dtype} of shape {ids.shape}."
        )
    ids = ids.astype(np.int64)
    if ids.size and (ids.min() < 0 or ids.max() >= len(tree)):
        raise InvalidParameterError(
            f"node ids must lie in 0..{len(tree) - 1} (the tree has {len(tree)} nodes), got "
            f"{ids.min()}..{ids.max()}."
        )
    return ids
