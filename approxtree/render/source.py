"""Tile sources: what differs between the kinds of tree the Engine draws.

The Engine (engine.py) is the same facade for every tree; what a frame selects, loads and
textures comes from the tree's *tile source* (DESIGN.md, "Tile sources"), found in one table,
``SOURCES``: tree kind (``tree.tree_kind``) → source class, as patches/table.py maps terrain
types and strategies to patch classes. A source implements ``TileSource``:

- ``select(fs, cut)``: the wanted cut of a frame (pure, no GL) for a FrameState and a Cut;
- ``plan(wanted, fs, cut, paging, renderer)``: what the frame draws — the meshes, grouped by
  texture patch, and, for an interactive frame, what is drawn while the cut loads;
- ``load(key)``: a node's payload (mesh with skirts, or texture patch) for the GPU cache;
- ``set_textures(textures)``: the texture pyramid (or None), which the texel sizes ``texels``
  of γ follow;
- ``set_shading_side(side, scale)``: the largest side of the normal map (the context's texture
  limit) and the display scale of its normals, which the untextured texels follow;
- ``shading_uv``: the uv transform of a group's normal patch key, or None when untextured
  groups are all drawn with the one normal map;
- ``set_skirts(skirts)``: hang skirts or not (True when that changes the meshes);
- ``release()``: stop background work and free what the source holds.

Sources: ``ApproximationTreeSource`` (tree_source.py: the selector, triangle budgets, the
provider's background loads, skirts, texture patches; full resolution is a source of its own,
full_resolution.py) and ``PointQuadtreeSource`` (point_quadtree_source.py: the per-view LOD
mesh of seed 003, built per frame).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any, Protocol

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.cache_keys import MeshKey, TextureKey
from approxtree.render.cut import Cut
from approxtree.render.frame import FramePlan
from approxtree.render.frame_state import FrameState
from approxtree.render.point_quadtree_source import PointQuadtreeSource
from approxtree.render.provider import Payload, PayloadProvider
from approxtree.render.renderer import Renderer
from approxtree.render.selector import Selection
from approxtree.render.texture_binding import TextureBinding
from approxtree.render.traversal import Paging
from approxtree.render.tree_source import ApproximationTreeSource


class TileSource(Protocol):
    """What the Engine asks of the tree it draws (see the module docstring).

    texels: (n, 2) texel sizes of the nodes (γ). binding: the TextureBinding of the texture
    pyramid, or None. provider: the PayloadProvider of background loads (CPU cache), or None
    when meshes are built per frame. view_dependent: a node's mesh depends on the view
    (nothing of it can be uploaded ahead of a frame).
    """

    texels: np.ndarray
    view_dependent: bool

    @property
    def binding(self) -> TextureBinding | None: ...

    @property
    def provider(self) -> PayloadProvider | None: ...

    def select(self, fs: FrameState, cut: Cut) -> Selection: ...

    def plan(
        self, wanted: Selection, fs: FrameState, cut: Cut, paging: Paging, renderer: Renderer
    ) -> FramePlan: ...

    def load(self, key: MeshKey | TextureKey) -> Payload: ...

    def set_textures(self, textures: Any) -> Callable[[Hashable], bool]: ...

    def set_shading_side(self, side: int, scale: np.ndarray | None = None) -> None: ...

    def set_lighting(self, lit: bool) -> None: ...

    @property
    def shading_uv(self) -> Callable[[Any], tuple[float, float, float, float]] | None: ...

    def set_skirts(self, skirts: bool) -> bool: ...

    def release(self) -> None: ...


#: tree kind (``tree.tree_kind``; an ApproximationTree has none) → its tile source.
SOURCES: dict[str, type] = {
    "approximation_tree": ApproximationTreeSource,
    "point_quadtree": PointQuadtreeSource,
}


def source_for(
    tree: Any, skirts: bool = True, cpu_cache_bytes: int | None = None, loader_threads: int = 2
) -> TileSource:
    """The tile source of ``tree``'s kind (``SOURCES``); skirts, cpu_cache_bytes and
    loader_threads go to it (None: its default CPU cache)."""
    kind = getattr(tree, "tree_kind", "approximation_tree")
    if kind not in SOURCES:
        raise InvalidParameterError(
            f"No renderer for a tree of kind {kind!r}; the Engine draws {', '.join(SOURCES)}."
        )
    options: dict[str, Any] = {"skirts": skirts, "loader_threads": loader_threads}
    if cpu_cache_bytes is not None:
        options["cpu_cache_bytes"] = cpu_cache_bytes
    return SOURCES[kind](tree, **options)
