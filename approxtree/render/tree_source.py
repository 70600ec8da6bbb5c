"""ApproximationTreeSource: the tile source of an approximation tree (render/source.py).

What the Engine draws of an ApproximationTree, and from where:

1. Select (``select``, no GL): the cut by α and γ (selector.py), by a triangle budget
   (budget.py, per-node triangle counts with skirts made on first use), or the full-resolution
   chunks (full_resolution.py) — for the camera's FrameState or a frozen one (``Cut.frozen``).
2. Plan (``plan``): a single image draws the cut itself; an interactive frame
   (``Paging(wait=False)``) plans with the traversal (traversal.py): payloads in the CPU cache
   are uploaded within the frame's budget, the others requested from the provider coarsest
   first, and the nearest resident ancestors drawn meanwhile. With a texture pyramid each
   drawn node is textured by the patch of itself or of the ancestor closest to the root whose
   γ is within the threshold (core paper, 4.2; texture_sharing.py), meshes grouped by texture
   patch (texture_binding.py); a patch not loaded yet is stood in for by the root's.
3. Load (``load``): a node's payload — its patch T_N read from the store without being kept
   by the tree, with skirts hung below its border (their depth from the node's error or z
   extent; walls on node borders only when patches reach their rectangle), float32 relative
   to the tree's origin — or a texture patch's texels, through the provider's CPU cache.

Texel sizes (γ): the texture patch's with a pyramid (``set_textures``), else the normal
patch's (render/normal_map.py: the normal map every node shares, or, on a grid over
NORMAL_MAP_MAX a side, each node's normal patch, shared with ancestors as texture patches
are), and per node whether a descendant's texel is finer (``selector.finer_below``): γ
refines only there (render/node_shading.py holds the shading's figures and groups). A
textured frame lit at runtime (``set_lighting``) over normal patches lights each texture
group by its nodes' normal patches (groups keyed by LitKey), and γ refines where either kind
of patch is over γ with a finer one below. Full-resolution chunks are shaded by their own
normal patches (full_resolution.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from approxtree.errors import EmptyTerrainError, InvalidParameterError
from approxtree.geometry.rect import Rect
from approxtree.render.budget import node_triangles, select_budget
from approxtree.render.cache_keys import CHUNK, NODE, MeshKey, TextureKey, node_keys
from approxtree.render.cut import Cut
from approxtree.render.frame import PAGING_KEYS, FramePlan
from approxtree.render.frame_state import FrameState
from approxtree.render.full_resolution import FullResolutionSource
from approxtree.render.node_shading import NodeShading
from approxtree.render.normal_map import NormalKey
from approxtree.render.prefetch import Prefetcher
from approxtree.render.provider import DEFAULT_CPU_CACHE_BYTES, Payload, PayloadProvider
from approxtree.render.renderer import Renderer
from approxtree.render.selector import Selection, finer_below, select
from approxtree.render.skirts import add_skirts, patches_reach_rect, skirt_base, skirt_depths
from approxtree.render.texture_binding import (
    TextureBinding,
    as_pyramid,
    group_meshes,
)
from approxtree.render.texture_follow import pyramids_of, stale_textures
from approxtree.render.texture_sharing import texture_nodes
from approxtree.render.traversal import Paging, plan_frame
from approxtree.textures.detail import DetailTextures
from approxtree.textures.patch import patch_texel_sizes

#: Milliseconds a frame spends writing texture patches when the paging sets no upload budget.
TEXTURE_STEP_MS = 4.0


class ApproximationTreeSource:
    """The tile source of an ApproximationTree (see the module docstring).

    skirts: hang skirts below patch borders; cpu_cache_bytes, loader_threads: the provider's
    CPU cache budget and background threads. Raises EmptyTerrainError for a tree with
    nothing to draw, before anything is made.
    """

    #: A node's mesh is its patch (with skirts), whatever the view.
    view_dependent = False

    def __init__(
        self,
        tree: Any,
        skirts: bool = True,
        cpu_cache_bytes: int = DEFAULT_CPU_CACHE_BYTES,
        loader_threads: int = 2,
    ) -> None:
        _check_drawable(tree)
        self.tree = tree
        self.provider = PayloadProvider(self._build, cpu_cache_bytes, loader_threads)
        self.full = FullResolutionSource(tree)
        self.skirts = bool(skirts)
        self.binding: TextureBinding | None = None
        self._node_borders = patches_reach_rect(tree.terrain)
        d = tree.terrain.domain
        self._domain = (d.xmin, d.ymin, d.xmax, d.ymax)
        #: The nodes' untextured shading: normal patches, their texels (render/node_shading.py).
        self.shading = NodeShading(tree)
        #: Called after each node's patch is read from the tree; raises to refuse a payload
        #: read from a store another process swapped meanwhile (render/live.py).
        self.payload_check: Callable[[], None] | None = None
        #: Camera motion and frame times of interactive frames (render/prefetch.py).
        self.prefetch = Prefetcher()
        self._node_figures(refresh=False)

    def _node_figures(self, refresh: bool = True) -> None:
        """Per-node figures used every frame, computed once (and again after a tree update;
        ``refresh``: the shading's too)."""
        tree = self.tree
        # The untextured shading's texels (the normal map's for every node, γ refining nothing,
        # or each node's normal patch's); with a pyramid, each node's texture patch's; and
        # where a finer one lies below.
        if refresh:
            self.shading.refresh(tree)
        self.texels, self.finer = self.shading.texels, self.shading.finer
        self.sources = np.zeros(len(tree), dtype=np.int64)
        if self.binding is not None:
            pyramid = self.binding.detail or self.binding.pyramid
            self.texels, self.sources = self._texture_texels(pyramid)
            self.finer = finer_below(tree, self.texels)
        # Skirts: infinite errors stand in by the node's z extent; walls on node borders only.
        extents = tree.bboxes[:, 5] - tree.bboxes[:, 2]
        rects = np.asarray(tree.rects, dtype=np.float64) if self._node_borders else None
        self.skirt_depths = skirt_depths(tree.errors, tree.terrain.z_range, extents, rects)
        self.skirt_base = skirt_base(tree.errors, tree.terrain.z_range, extents)
        #: Triangles drawn per node (the budget's counts), made on first use.
        self._node_triangles: np.ndarray | None = None

    # -- the protocol ---------------------------------------------------------------------------

    def select(self, fs: FrameState, cut: Cut) -> Selection:
        """The wanted cut of the frame (step 1)."""
        view = cut.frozen or fs
        if cut.full_resolution:
            return self.full.select(view)
        texels, finer = (
            self.shading.lit_figures(self.texels, self.finer)
            if self._lit_patches
            else (self.texels, self.finer)
        )
        if cut.max_triangles is not None:
            if self._node_triangles is None:
                self._node_triangles = node_triangles(self.tree, self.skirts)
            return select_budget(self.tree, view, cut.max_triangles, self._node_triangles, texels)
        return select(self.tree, view, cut.alpha, cut.gamma, texels, finer)

    def plan(
        self, wanted: Selection, fs: FrameState, cut: Cut, paging: Paging, renderer: Renderer
    ) -> FramePlan:
        """What the frame draws (step 2); an interactive frame uploads and requests here."""
        if cut.full_resolution:
            plan = self.full.plan(wanted)
            self._texture(plan, plan.meshes, wanted.nodes.copy(), np.zeros(len(wanted.nodes)))
            if self.binding is None and self.shading.active:
                # Each chunk shaded by its own normal patch, as finely as the cut's nodes.
                chunks = self.full.normal_patches(self.shading.side)
                zscale = self.shading.zscale
                keys: list[Hashable | None] = [chunks.key(int(i), zscale) for i in wanted.nodes]
                plan.groups = group_meshes(plan.meshes, keys)
            return plan
        interactive = not paging.wait
        figures, requests, ahead = dict.fromkeys(PAGING_KEYS, 0), list[Any](), list[Any]()
        drawn, views = wanted, list[Selection]()
        if interactive:
            drawn, figures, requests, ahead, views = self._page(wanted, fs, cut, paging, renderer)
        meshes = node_keys(drawn.nodes)
        plan = FramePlan(drawn, meshes, [(None, meshes)], figures)
        if self.binding is not None:
            tex_nodes, tex_gammas = texture_nodes(
                self.tree.parents, drawn, cut.gamma, cut.share_textures, self.sources
            )
            self._texture(plan, node_keys(tex_nodes), tex_nodes, tex_gammas)
            loaded = loaded_by(renderer, self.provider)
            tex_requests: list = []
            if interactive:
                # Texture patches not drawable yet: the root's stands in, the rest is
                # requested. A patch is drawable once complete on the GPU: its mip chain is
                # made on a worker thread and written over frames within the upload budget.
                provider = self.provider

                def texels(key: Any) -> Any:
                    payload = provider.get(key) if key in provider else None
                    return None if payload is None else payload.texels

                plan.groups, tex_requests = self.binding.page(
                    plan.groups, lambda key: renderer.texture_drawable(key, lambda: texels(key))
                )
                renderer.step_textures(
                    TEXTURE_STEP_MS if paging.upload_ms is None else paging.upload_ms
                )
            if self._lit_patches:
                # Lit: each texture group split by its meshes' normal patches (LitKey); in an
                # interactive frame one not loaded yet is lit by the map, and requested.
                plan.groups, normal_requests = self.shading.lit_groups(
                    plan, cut, loaded if interactive else None
                )
                tex_requests += normal_requests
            if interactive:
                figures["texture_stand_ins"] = len(tex_requests)
                # Meshes first: a few kB each against MBs of texels, and a missing mesh
                # coarsens the geometry (α), a missing texture only the colour.
                requests = requests + tex_requests
                ahead = ahead + [key for view in views for key in self._texture_keys(view, cut)]
        elif self.shading.active:
            # Normal patches after the meshes too, for the same reason; in an interactive
            # frame one not loaded yet is drawn with the normal map and requested.
            normal_requests = self.shading.normal_groups(
                plan, cut, loaded_by(renderer, self.provider) if interactive else None
            )
            if interactive:
                figures["texture_stand_ins"] = len(normal_requests)
            requests = requests + normal_requests
        if interactive:
            # One request per frame (it replaces the previous frame's): meshes, then textures,
            # then what the next frames will want (loaded only where it evicts none of those).
            self.provider.request(requests, ahead)
        return plan

    def set_lighting(self, lit: bool) -> None:
        """Whether the next frames are lit: a lit textured frame of a grid with normal patches
        lights each group with its normal patch (an interactive frame the map where one is not
        loaded yet; full-resolution chunks keep the map), and γ refines where the texture or
        the normal patch is over γ with a finer one of its kind below
        (``NodeShading.lit_figures``)."""
        self.shading.lit = bool(lit)

    @property
    def _lit_patches(self) -> bool:
        """Textured frames lit with normal patches."""
        return self.shading.lit and self.binding is not None and self.shading.active

    def _texture_keys(self, selection: Selection, cut: Cut) -> list[TextureKey]:
        """The texture patches the nodes of ``selection`` are drawn with (with a pyramid)."""
        if self.binding is None:
            return []
        tex_nodes, _ = texture_nodes(
            self.tree.parents, selection, cut.gamma, cut.share_textures, self.sources
        )
        groups = self.binding.groups(node_keys(selection.nodes), node_keys(tex_nodes))
        return [key for key, _ in groups if key is not None]

    def load(self, key: MeshKey | TextureKey) -> Payload:
        """The payload of ``key`` (step 3): nodes and texture patches through the CPU cache
        (loaded now when missing), a full-resolution chunk built (never kept on the CPU)."""
        if isinstance(key, MeshKey) and key.kind == CHUNK:
            return self.full.load(key)
        return self.provider.load(key)

    def set_textures(self, textures: Any) -> Callable[[Hashable], bool]:
        """Texture with a TexturePyramid (or its folder), or None; texel sizes follow.

        Returns the predicate of the cache keys this makes stale (render/texture_follow.py):
        after a re-bake of the same pyramid, only the texture patches meeting a re-baked
        tile; else every texture patch. The CPU cache drops them here, the caller the GPU's.
        """
        pyramid = as_pyramid(textures, self.tree.terrain)
        before = pyramids_of(self.binding)
        if pyramid is None:
            self.binding, self.texels, self.finer = None, self.shading.texels, self.shading.finer
            self.sources = np.zeros(len(self.tree), dtype=np.int64)
        else:
            self.binding = TextureBinding(pyramid, self.tree.origin, self._rect_of, self._level_of)
            self.texels, self.sources = self._texture_texels(pyramid)
            self.finer = finer_below(self.tree, self.texels)
        self.shading.forget_lit()
        stale = stale_textures(before, pyramids_of(self.binding))
        self.provider.drop(stale)
        return stale

    def _texture_texels(self, pyramid: Any) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) texel of each node's texture patch, in the pyramid the node uses (``pyramid``:
        a TexturePyramid or DetailTextures), and (n,) int64 that pyramid (TextureKey.source:
        0 base, 1 detail)."""
        rects = np.asarray(self.tree.rects, dtype=np.float64)
        if not isinstance(pyramid, DetailTextures):
            return patch_texel_sizes(pyramid, rects), np.zeros(len(rects), dtype=np.int64)
        # γ_N from the patch of the pyramid each node uses.
        texels = patch_texel_sizes(pyramid.base, rects)
        detail = pyramid.uses_detail(self.tree.levels, rects)
        texels[detail] = patch_texel_sizes(pyramid.detail, rects[detail])
        return texels, detail.astype(np.int64)

    def set_shading_side(self, side: int, scale: np.ndarray | None = None) -> None:
        """The normal map's largest side (the context's texture limit) and the display scale
        (3,) of the normals (None: as before): untextured texels and normal patches follow."""
        self.shading.set_side(side, scale)
        if self.binding is None:
            self.texels, self.finer = self.shading.texels, self.shading.finer

    @property
    def shading_uv(self) -> Callable[[Any], tuple[float, float, float, float]] | None:
        """The uv transform of a normal patch key, None when frames draw only the normal map
        (no normal patches)."""
        return self.shading.uv

    def set_skirts(self, skirts: bool) -> bool:
        """Hang skirts or not; True when that changes the meshes (the cached ones dropped)."""
        skirts = bool(skirts)
        if skirts == self.skirts:
            return False
        self.skirts = skirts
        self._node_triangles = None
        self.provider.drop(lambda key: isinstance(key, MeshKey))
        return True

    def replace_tree(
        self, tree: Any, old_to_new: np.ndarray | None
    ) -> Callable[[Hashable], Hashable | None]:
        """Draw ``tree`` instead, a fresh load of the same terrain after another process
        updated its store; ``old_to_new`` as for ``follow`` (render/live.py makes
        it). Returns ``follow``'s key map."""
        _check_drawable(tree)
        self.tree = tree
        return self.follow(old_to_new)

    def follow(self, old_to_new: np.ndarray | None) -> Callable[[Hashable], Hashable | None]:
        """Take a tree update (``ApproximationTree.changes_since``: (n_old,) new id of every
        unchanged old node, −1 elsewhere; None: unknown, everything changed) and return the
        key map of the caches: an unchanged node's mesh gets its new id; a mesh whose payload
        changed (node rebuilt, skirt depth or base moved) maps to None, as does every
        full-resolution chunk. Texture patches keep their keys (the pyramid is not re-baked
        here). The provider's CPU cache is re-keyed here; the caller re-keys the GPU cache."""
        depths, base = self.skirt_depths, self.skirt_base
        self._node_figures()
        self.full = FullResolutionSource(self.tree)
        if self.binding is not None:
            self.binding.forget()
        # Skirted meshes all change when their common base moves.
        everything = old_to_new is None or (self.skirts and self.skirt_base != base)
        new_ids = np.full(0, -1, dtype=np.int64) if old_to_new is None or everything else old_to_new
        same = np.zeros(len(self.tree), dtype=bool)
        if not everything:
            kept = np.flatnonzero(new_ids >= 0)
            same[new_ids[kept]] = (
                True if not self.skirts else depths[kept] == self.skirt_depths[new_ids[kept]]
            )

        def mapping(key: Hashable) -> Hashable | None:
            if isinstance(key, TextureKey):
                return key
            if not isinstance(key, MeshKey) or key.kind != NODE or everything:
                return None
            new = int(new_ids[key.item]) if key.item < len(new_ids) else -1
            return MeshKey(NODE, new) if new >= 0 and same[new] else None

        self.provider.rekey(mapping)
        return mapping

    def release(self) -> None:
        """Stop the provider's threads and empty its CPU cache."""
        self.provider.close()

    # -- paging ---------------------------------------------------------------------------------

    def _page(
        self, wanted: Selection, fs: FrameState, cut: Cut, paging: Paging, renderer: Renderer
    ) -> tuple[Selection, dict[str, int], list, list, list[Selection]]:
        """The drawn cut of an interactive frame, its paging figures, the mesh keys to
        request (coarsest, most visible first), those to prefetch (traversal.py) and the
        cuts of the predicted views.

        Uploads the wanted nodes whose payload is in the CPU cache (coarsest first, within
        the budget), and returns the nearest resident ancestors of what is still missing. The
        root counts as resident: the draw loads it when it is not (the one blocking read).
        """
        self.provider.raise_error()
        cache = renderer.cache

        def on_gpu(nodes: np.ndarray) -> np.ndarray:
            nodes = np.asarray(nodes)
            return cache.is_resident(node_keys(nodes)) | (nodes == 0)

        t0 = time.perf_counter()
        allowance = self.prefetch.start(t0, fs, paging, cut.frozen is not None)
        # The cuts of the views the camera is about to reach (none for a frozen cut).
        views = [] if cut.frozen else self.prefetch.views(fs, paging, self.tree.bboxes[0])
        selections = [self.select(view, cut) for view in views]
        ahead = [sel.nodes for sel in selections]
        plan = plan_frame(
            wanted,
            fs,
            self.tree,
            self.texels,
            on_gpu,
            self._on_cpu,
            paging.max_uploads,
            ahead,
            paging.siblings,
        )
        budget_ms = (
            None
            if paging.upload_ms is None
            else paging.upload_ms - (time.perf_counter() - t0) * 1e3
        )
        if allowance is not None:
            budget_ms = allowance if budget_ms is None else min(budget_ms, allowance)
        t1 = time.perf_counter()
        uploads = renderer.upload_within(node_keys(plan.upload), self.load, None, budget_ms)
        self.prefetch.uploaded((time.perf_counter() - t1) * 1e3)
        # What is drawable now (uploads may have evicted older meshes from a small cache).
        drawn = plan_frame(wanted, fs, self.tree, self.texels, on_gpu, self._on_cpu, 0)
        figures = {
            "stand_ins": drawn.stand_ins,
            "pending": drawn.pending,
            "paged_uploads": uploads,
            "texture_stand_ins": 0,
        }
        requests, prefetch = node_keys(plan.request), node_keys(plan.prefetch)
        return drawn.drawn, figures, requests, prefetch, selections

    def _on_cpu(self, nodes: np.ndarray) -> np.ndarray:
        """(k,) bool: node payloads in the provider's CPU cache."""
        return self.provider.is_resident(node_keys(np.asarray(nodes)))

    # -- payloads -------------------------------------------------------------------------------

    def _build(self, key: MeshKey | TextureKey) -> Payload:
        """The payload of ``key``, built now: the provider's loader (it runs on the provider's
        threads and reads the tree's store without keeping the patch, ``read_patch``)."""
        if isinstance(key, NormalKey):
            texels = self.shading.normals.upload_texels(key, self.tree.origin, self.shading.scale)
            return Payload(texels=texels)
        if isinstance(key, TextureKey):
            if self.binding is None:  # the pyramid was dropped while this load waited
                raise InvalidParameterError("No texture pyramid: set_textures(None) was called.")
            return Payload(texels=self.binding.texels(key))
        i = key.item
        patch = _read_patch(self.tree, i)
        if self.payload_check is not None:
            self.payload_check()
        if not self.skirts:
            verts, tris = patch.vertices, patch.triangles
            flags = np.zeros(len(verts), dtype=np.float32)
        else:
            verts, tris, flags = add_skirts(
                patch.vertices,
                patch.triangles,
                float(self.skirt_depths[i]),
                self._domain,
                self.skirt_base,
                patch.rect.as_tuple() if self._node_borders else None,
            )
        return Payload.mesh(verts, tris, flags, self.tree.origin)

    def _texture(
        self, plan: FramePlan, owners: list[MeshKey], nodes: np.ndarray, gammas: np.ndarray
    ) -> None:
        """Group ``plan``'s meshes by the texture patch of their ``owners`` (with a pyramid)."""
        if self.binding is not None:
            plan.groups = self.binding.groups(plan.meshes, owners)
            plan.texture_nodes, plan.texture_gammas = nodes, gammas

    def _level_of(self, owner: MeshKey) -> int:
        """The tree level of ``owner``: a node's; a full-resolution chunk is below every leaf."""
        if owner.kind == CHUNK:
            return int(self.tree.levels.max()) + 1
        return int(self.tree.levels[owner.item])

    def _rect_of(self, owner: MeshKey) -> Rect:
        """The rectangle the texture patch of ``owner`` covers: a node's domain, a chunk's."""
        if owner.kind == CHUNK:
            return self.full.rect(owner.item)
        return self.tree.node(owner.item).rect


def loaded_by(renderer: Renderer, provider: PayloadProvider) -> Callable[[Hashable], bool]:
    """Whether a key's payload is at hand: on the GPU or in the CPU cache."""
    cache = renderer.cache
    return lambda key: key in cache or key in provider


def _check_drawable(tree: Any) -> None:
    """EmptyTerrainError for a tree whose only node has no triangle (too few valid points)."""
    if tree.child_count[0] == 0 and len(tree.patch(0).triangles) == 0:
        raise EmptyTerrainError(
            f"This tree has nothing to draw: its terrain's {tree.terrain.point_count} valid "
            "data point(s) form no triangle (a surface needs at least three points not on one "
            "line, e.g. one grid cell of valid corners). Check the file's nodata value or use "
            "a larger area."
        )


def _read_patch(tree: Any, i: int) -> Any:
    """T_N of node i, read without being kept by the tree when it can be (bounded memory)."""
    reader = getattr(tree, "read_patch", None)
    return reader(i) if reader is not None else tree.patch(i)
