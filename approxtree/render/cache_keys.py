"""Keys of the GPU cache and of the provider's CPU cache: one small type per kind of entry.

A mesh is keyed by ``MeshKey`` (what it draws), a texture patch by ``TextureKey`` (the window of
the pyramid level it holds: two nodes with the same window share one entry). Callers tell them
apart by type (``isinstance``), never by position in a tuple. Both are NamedTuples: hashed and
compared in C, as the plain tuples they replace, since a frame looks up thousands of them.
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import partial
from itertools import repeat
from typing import Any, NamedTuple

#: MeshKey.kind of a tree node's patch (with its skirts): item is the node id.
NODE = "node"
#: MeshKey.kind of a full-resolution chunk (render/full_resolution.py): item is the chunk.
CHUNK = "chunk"
#: MeshKey.kind of a point-quadtree node as one cut draws it: item is the node row, shape
#: (midpoints, keep, inserted) (render/point_quadtree_source.py).
LOD = "lod"


class MeshKey(NamedTuple):
    """One mesh: ``kind`` (NODE, CHUNK or LOD), ``item`` (node id, chunk, or node row) and,
    for a point-quadtree node, ``shape``: the boundary and insertions it is drawn with."""

    kind: str
    item: int
    shape: tuple = ()

    @property
    def node(self) -> int | None:
        """The tree node this mesh draws (None for a full-resolution chunk)."""
        return None if self.kind == CHUNK else self.item


def node_keys(nodes: Iterable[int]) -> list[MeshKey]:
    """The MeshKeys of tree nodes (NODE), one per id of ``nodes``: made in C (``map`` over
    ``tuple.__new__``), since a paging frame makes thousands (4x faster than a loop)."""
    items = nodes.tolist() if hasattr(nodes, "tolist") else [int(i) for i in nodes]
    return list(map(_new_mesh_key, zip(repeat(NODE), items, repeat(()))))


_new_mesh_key = partial(tuple.__new__, MeshKey)


class TextureKey(NamedTuple):
    """One texture patch: the window (col0, row0, width, height) texels of pyramid ``level``;
    ``source`` 0 for the base pyramid, 1 for a detail pyramid (textures/detail.py)."""

    level: int
    col0: int
    row0: int
    width: int
    height: int
    source: int = 0

    @classmethod
    def of(cls, patch: Any, source: int = 0) -> TextureKey:
        """The key of a TexturePatch (textures/patch.py) of pyramid ``source``."""
        return cls(patch.level, patch.col0, patch.row0, patch.width, patch.height, source)


class LitKey(NamedTuple):
    """The group key of a lit textured frame's meshes (render/tree_source.py): ``texture``
    (a TextureKey) colours them, ``normal`` (a render/normal_map.NormalKey) lights them in
    place of the normal map."""

    texture: Any
    normal: Any
