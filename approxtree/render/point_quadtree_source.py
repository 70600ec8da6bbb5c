"""PointQuadtreeSource: the tile source of a PointQuadtree (seed 003), its per-view LOD mesh.

``Engine(quadtree)`` draws through this source: the same frames, stats keys, offscreen and
embedded drawing, GPU cache, normal map and programs as for an ApproximationTree; only the
selection and the meshes differ. Each frame:

1. λ, the pixels per radian of the view, is taken where the perspective magnifies most
   (``pixels_per_radian``, at the image corner). With d the distance from the eye to a node's
   3-D box, a vertical error segment of length δ inside the box subtends at most δ/d radians,
   so ρ = λ·δ/d bounds its length on screen in pixels anywhere in the image.
2. The cut's α is the seed's tolerance C: a node is refined while ρ > α, and a drawn leaf
   replays its insertion order until its measured error is within α·d/λ (render/lod_cut.py).
   Every drawn mesh thus shows its data points within α pixels of where the mesh draws them,
   the promise α makes for approximation trees. ``stats["max_alpha"]`` is the largest ρ of
   the drawn meshes, from their measured errors.
3. Nodes whose box lies outside the frustum, or whose square lies outside the terrain's
   domain (the root square reaches past the data on its shorter side, where heights would
   only be extrapolated), are never refined and not drawn (the cut stays a restricted
   partition, so their visible neighbours keep matching edges).
4. Each drawn node's mesh is one cache entry keyed by (node, midpoints, kept midpoints, points
   replayed) (``MeshKey`` of kind LOD), so a mesh is uploaded again only when its own
   refinement changes. The meshes a frame lacks on the GPU are built together by ``plan``, in
   one kernel call over arrays (``node_meshes``), and handed to the cache node by node.

The cut's mesh is continuous (shared lattice vertices, midpoints on straight edges covered by
zero-area triangles), so no skirts are hung; ``skirts`` is accepted and changes nothing.
γ and texture pyramids do not apply (max_gamma is 0); a triangle budget is not offered.
``Cut(full_resolution=True)`` draws the cut at C = 0: every data point of every visible leaf.
Meshes are built per frame: there is no provider (no CPU cache, no background loads).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.cache_keys import LOD, MeshKey, TextureKey
from approxtree.render.cut import Cut
from approxtree.render.frame import FramePlan
from approxtree.render.frame_state import FrameState
from approxtree.render.frustum import boxes_in_frustum
from approxtree.render.lod_cut import LODCut, LodSelector, node_meshes, pixels_per_radian
from approxtree.render.provider import Payload, PayloadProvider
from approxtree.render.renderer import Renderer
from approxtree.render.selector import Selection, eye_below_ground
from approxtree.render.texture_binding import TextureBinding
from approxtree.render.traversal import Paging


class PointQuadtreeSource:
    """The tile source of a PointQuadtree (see the module docstring). skirts,
    cpu_cache_bytes and loader_threads are accepted for the Engine's call and not used."""

    #: A node's mesh depends on the view (its cut's neighbours and tolerance).
    view_dependent = True
    provider: PayloadProvider | None = None
    binding: TextureBinding | None = None

    def __init__(self, tree: Any, skirts: bool = True, **unused: Any) -> None:
        self.tree = tree
        self.selector = LodSelector(tree)
        self.texels = np.zeros((len(tree), 2))
        #: The LODCut of the last selection (None before the first).
        self.last_cut: LODCut | None = None
        # The mesh keys of the last selection, and the meshes ``plan`` built for its upload.
        self._keys: list[MeshKey] = []
        self._batch: dict[MeshKey, Payload] = {}

    def select(self, fs: FrameState, cut: Cut) -> Selection:
        """The LOD cut of the view with C = alpha (module docstring, steps 1-3); C = 0 for
        the full resolution."""
        if cut.max_triangles is not None and not cut.full_resolution:
            raise InvalidParameterError(
                "A triangle budget (max_triangles) is not available for a point quadtree; "
                "choose its detail with alpha."
            )
        view = cut.frozen or fs
        tree = self.tree
        lam = pixels_per_radian(view)
        below = eye_below_ground(tree, view)
        visible = boxes_in_frustum(tree.bboxes, view.planes) & tree.in_domain
        tolerance = 0.0 if cut.full_resolution else cut.alpha
        lod = self.selector.cut(view.eye, lam, tolerance, view.scale, visible)
        self.last_cut = lod
        drawn = np.flatnonzero(lod.visible) if not below else np.empty(0, dtype=np.int64)
        rho = lod.screen_errors(lam)[drawn]
        self._keys = [
            MeshKey(
                LOD,
                int(lod.rows[k]),
                (
                    tuple(lod.midpoints[k].tolist()),
                    tuple(lod.keep[k].tolist()),
                    int(lod.inserted[k]),
                ),
            )
            for k in drawn.tolist()
        ]
        # Visited: the refined ancestors (REFINED), then the cut (SELECTED, or CULLED).
        visited = np.concatenate([lod.refined, lod.rows])
        results = np.concatenate(
            [np.full(len(lod.refined), 1), np.where(lod.visible, 2, 0)]
        ).astype(np.uint8)
        return Selection(
            lod.rows[drawn],
            rho,
            np.zeros(len(drawn)),
            visited,
            results,
            below,
            {
                "nodes_visited": lod.nodes_visited,
                "culled": int(np.count_nonzero(~lod.visible)),
                "selected": len(drawn),
                "max_alpha": float(rho.max()) if len(rho) else 0.0,
                "max_gamma": 0.0,
            },
        )

    def plan(
        self, wanted: Selection, fs: FrameState, cut: Cut, paging: Paging, renderer: Renderer
    ) -> FramePlan:
        """The last selection's meshes; those the GPU cache lacks are built now, in one kernel
        call (module docstring, step 4). A frame never waits for a store: paging is moot."""
        missing = [key for key in self._keys if key not in renderer.cache]
        self._batch = self._build(missing)
        return FramePlan(wanted, self._keys, [(None, self._keys)])

    def load(self, key: MeshKey | TextureKey) -> Payload:
        """The mesh of ``key``: from the frame's batch, else (evicted since) a batch of one."""
        payload = self._batch.pop(key, None)  # type: ignore[arg-type]
        return payload if payload is not None else self._build([key])[key]  # type: ignore[list-item,index]

    def set_textures(self, textures: Any) -> Callable[[Hashable], bool]:
        """Only None: a point quadtree is drawn with the hypsometric colour ramp (nothing
        cached goes stale)."""
        if textures is not None:
            raise InvalidParameterError(
                "A point quadtree is drawn with the hypsometric colour ramp; texture pyramids "
                "apply to approximation trees (build one without --kind point-quadtree)."
            )
        return lambda key: False

    def set_shading_side(self, side: int, scale: np.ndarray | None = None) -> None:
        """Nothing changes: γ does not apply to a point quadtree."""

    def set_lighting(self, lit: bool) -> None:
        """Nothing changes: its frames are lit by the normal map."""

    @property
    def shading_uv(self) -> None:
        """No normal patches: every group is drawn with the normal map."""
        return None

    def set_skirts(self, skirts: bool) -> bool:
        """Nothing changes: the LOD mesh needs no skirts."""
        return False

    def release(self) -> None:
        self._batch = {}

    def _build(self, keys: list[MeshKey]) -> dict[MeshKey, Payload]:
        """The payloads of the meshes of ``keys``, built in one kernel call: views into one
        vertex array (V, 4) float32 (local x, y, z and flag 0) and one triangle array (T, 3)
        uint32."""
        if not keys:
            return {}
        rows = [key.item for key in keys]
        midpoints, keep, inserted = zip(*(key.shape for key in keys), strict=True)
        verts, vstart, tris, tstart = node_meshes(self.tree, rows, midpoints, keep, inserted)
        data = np.zeros((len(verts), 4), dtype=np.float32)
        data[:, :3] = verts - self.tree.origin
        tris = tris.astype(np.uint32)
        v, t = vstart.tolist(), tstart.tolist()
        return {
            key: Payload(data[v[m] : v[m + 1]], tris[t[m] : t[m + 1]]) for m, key in enumerate(keys)
        }
