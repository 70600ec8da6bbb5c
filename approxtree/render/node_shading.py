"""NodeShading: the untextured shading of a tree's nodes, and how lit textured frames use it.

A tree's nodes are shaded by the normal map every node shares or, on a grid over the normal
map's side, each by its normal patch shared with its ancestors within γ
(render/normal_map.py). This module holds what the tile source (render/tree_source.py) needs
of them per frame:

- ``texels`` (n, 2) and ``finer`` (n,): each node's shading texel (γ_N of an untextured frame)
  and whether a descendant's is finer (``selector.finer_below``: γ refines only there);
- ``normal_groups``: an untextured plan's meshes grouped by normal patch;
- ``lit_figures`` and ``lit_groups``: a textured frame lit at runtime over normal patches
  lights each texture group by its nodes' normal patches (groups keyed by LitKey), and γ
  refines where either kind of patch is over γ with a finer one of its kind below;
- ``uv``: the uv transform of a normal patch key, for the renderer.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from approxtree.render.cache_keys import LitKey
from approxtree.render.cut import Cut
from approxtree.render.frame import FramePlan
from approxtree.render.normal_map import NORMAL_MAP_MAX, NormalPatches
from approxtree.render.selector import finer_below
from approxtree.render.texture_binding import group_meshes, page_groups
from approxtree.render.texture_sharing import texture_nodes


class NodeShading:
    """The normal patches of ``tree``'s nodes under a texture limit of ``side`` (see above).

    ``lit``: frames are lit (set per frame through the tile source's ``set_lighting``).
    """

    def __init__(self, tree: Any, side: int = NORMAL_MAP_MAX) -> None:
        self.side = side
        #: The display scale (3,) the normal patches are computed for (the Engine's, once set).
        self.scale = np.ones(3)
        self.lit = False
        self.refresh(tree)

    def refresh(self, tree: Any) -> None:
        """Compute the nodes' normal patches, their texels and where finer ones lie below
        (again after a tree update or a new texture limit)."""
        self.tree = tree
        self.normals = NormalPatches(
            tree.terrain, np.asarray(tree.rects, dtype=np.float64), self.side
        )
        self.texels = self.normals.texels
        self.finer = (
            finer_below(tree, self.texels) if self.normals.active else np.zeros(len(tree), bool)
        )
        self.forget_lit()

    def set_side(self, side: int, scale: np.ndarray | None = None) -> None:
        """The normal map's largest side and the display scale (3,) of the normals (None: as
        before): the patches and texels follow."""
        self.side = side
        if scale is not None:
            self.scale = np.asarray(scale, dtype=np.float64).copy()
        self.refresh(self.tree)

    @property
    def active(self) -> bool:
        """Whether nodes have normal patches (a grid over the normal map's side)."""
        return bool(self.normals.active)

    @property
    def zscale(self) -> float:
        """The display z scale the normal patches are computed for."""
        return float(self.scale[2])

    # -- lit textured frames --------------------------------------------------------------------

    def forget_lit(self) -> None:
        """Drop the lit figures (the texture texels they combine changed)."""
        self._lit_texels: tuple[np.ndarray, np.ndarray] | None = None

    def lit_figures(self, texels: np.ndarray, finer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) texel of a lit textured frame's nodes and (n,) bool where a finer one lies
        below, from the texture patches' ``texels`` (n, 2) and ``finer`` (n,): γ refines a
        node where its texture or its normal patch's texel is over γ and that kind has a
        finer patch below, so its texel is the coarser in area of the kinds with a finer one
        below (of both where neither has: the drawn γ, refining nothing)."""
        if self._lit_texels is None:
            nrm, fn = self.texels, self.finer
            coarser = nrm[:, 0] * nrm[:, 1] > texels[:, 0] * texels[:, 1]
            use_normal = (fn & ~finer) | (coarser & (fn == finer))
            self._lit_texels = np.where(use_normal[:, None], nrm, texels), finer | fn
        return self._lit_texels

    def lit_groups(
        self, plan: FramePlan, cut: Cut, loaded: Callable[[Hashable], bool] | None
    ) -> tuple[list, list]:
        """``plan``'s texture groups, each split by its meshes' normal patches (each node's
        own or its ancestor's within γ, as untextured): [(LitKey or TextureKey, meshes)], and
        the normal patches to request: those not ``loaded`` (None: all are drawn), lit by the
        normal map meanwhile."""
        nodes, _ = texture_nodes(self.tree.parents, plan.selection, cut.gamma, cut.share_textures)
        zscale = self.zscale
        normal = {
            mesh: self.normals.key(int(i), zscale)
            for mesh, i in zip(plan.meshes, nodes, strict=True)
        }
        wanted = {n for n in normal.values() if n is not None}
        missing = set() if loaded is None else {n for n in wanted if not loaded(n)}
        groups = []
        for tex_key, meshes in plan.groups:
            patches = [normal[m] for m in meshes]
            keys: list[Hashable | None] = [
                tex_key if n is None or n in missing else LitKey(tex_key, n) for n in patches
            ]
            groups += group_meshes(meshes, keys)
        return groups, sorted(missing)

    # -- untextured frames ----------------------------------------------------------------------

    def normal_groups(
        self, plan: FramePlan, cut: Cut, loaded: Callable[[Hashable], bool] | None
    ) -> list:
        """Group an untextured plan's meshes by normal patch: each node's own or the one of
        its ancestor closest to the root within γ (texture_sharing.py); in an interactive
        frame (``loaded``: whether a patch's texels are at hand) a patch not loaded yet is
        drawn with the normal map and requested (returned)."""
        drawn = plan.selection
        nodes, gammas = texture_nodes(self.tree.parents, drawn, cut.gamma, cut.share_textures)
        zscale = self.zscale
        plan.groups = group_meshes(plan.meshes, [self.normals.key(i, zscale) for i in nodes])
        plan.texture_nodes, plan.texture_gammas = nodes, gammas
        if loaded is None:
            return []
        plan.groups, requests = page_groups(plan.groups, loaded, None)
        return requests

    @property
    def uv(self) -> Callable[[Any], tuple[float, float, float, float]] | None:
        """The uv transform of a normal patch key, None when frames draw only the normal map
        (no normal patches)."""
        if not self.normals.active:
            return None
        normals, origin = self.normals, self.tree.origin
        return lambda key: normals.upload_uv(key, origin)
