"""Drawing a PointQuadtree (seed 003) with the Engine: its per-view restricted LOD mesh.

``Engine(quadtree)`` returns a PointQuadtreeEngine: the same frames, stats keys, offscreen and
embedded drawing, GPU cache, normal map and programs as for an ApproximationTree; only the
selection differs. Each frame:

1. λ, the pixels per radian of the view, is taken where the perspective magnifies most: an
   angle δθ at angle θ off the view axis spans up to f·δθ/cos²θ pixels (f the focal length
   in pixels), largest at the image corner, so λ = f·(1 + t²) with t the tangent of the
   corner's angle. With d the distance from the eye to a node's 3-D box, a vertical error
   segment of length δ inside the box subtends at most δ/d radians, so ρ = λ·δ/d bounds
   its length on screen in pixels anywhere in the image.
2. The user's α is the seed's tolerance C: a node is refined while ρ > α, and a drawn leaf
   replays its insertion order until its measured error is within α·d/λ. Every drawn mesh
   thus shows its data points within α pixels of where the mesh draws them, the promise α
   makes for approximation trees. ``stats["max_alpha"]`` is the largest ρ of the drawn
   meshes, from their measured errors.
3. Nodes whose box lies outside the frustum, or whose square lies outside the terrain's
   domain (the root square reaches past the data on its shorter side, where heights would
   only be extrapolated), are never refined and not drawn (the cut stays a restricted
   partition, so their visible neighbours keep matching edges).
4. Each drawn node's mesh is one GPU cache entry keyed by (node, midpoints, kept midpoints,
   points replayed), so a mesh is uploaded again only when its own refinement changes. The
   meshes a frame lacks are built together, in one kernel call over arrays
   (``node_meshes``, render/lod_cut.py), and handed to the cache node by node.

The cut's mesh is continuous (shared lattice vertices, midpoints on straight edges covered by
zero-area triangles), so no skirts are hung; ``skirts`` is accepted and changes nothing.
γ and texture pyramids do not apply (max_gamma is 0); a triangle budget is not offered.
``full_resolution`` draws the cut at α = 0: every data point of every visible leaf.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.engine import DEFAULT_CACHE_BYTES, Engine
from approxtree.render.frame_state import FrameState
from approxtree.render.frustum import boxes_in_frustum
from approxtree.render.lod_cut import LodSelector, node_meshes, pixels_per_radian
from approxtree.render.selector import Selection, eye_below_ground


class PointQuadtreeEngine(Engine):
    """Renderer of one PointQuadtree (see the module docstring); made by ``Engine(tree)``.

    ``render`` is the Engine's: alpha is the tolerance C, gamma and share_textures do not
    apply, max_triangles is refused, full_resolution draws the cut at C = 0.
    """

    def __init__(
        self,
        tree,
        textures: Any = None,
        context: Any = None,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
        offscreen: bool | None = None,
        skirts: bool = True,
        cpu_cache_bytes: int | None = None,
        loader_threads: int | None = None,
        exaggeration: float = 1.0,
        palette: Any = None,
    ) -> None:
        # A point quadtree's cut is a per-view mesh built in one kernel call per frame: no
        # payloads to page (cpu_cache_bytes and loader_threads accepted for the same call).
        # Bad arguments fail before any GPU object exists.
        _no_textures(textures)
        self._open_gpu(tree, context, cache_bytes, offscreen, skirts)
        # The Engine's picture settings (render/style.py, textures/palettes.py).
        self.set_palette(palette)
        if exaggeration != 1.0:
            self.set_vertical_exaggeration(exaggeration)
        self._data_texels = self.texels = np.zeros((len(tree), 2))
        #: The cuts of the tree (render/lod_cut.py), with their measured errors.
        self._selector = LodSelector(tree)
        #: The LODCut of the last frame (None before the first).
        self.last_cut = None
        self._frame_keys: list[tuple] = []
        # The meshes built for the upload in progress (``_upload``), by GPU cache key.
        self._batch: dict[tuple, tuple[np.ndarray, np.ndarray]] | None = None

    def set_textures(self, textures: Any) -> None:
        """Only None: a point quadtree is drawn with the hypsometric colour ramp."""
        self._check_alive()
        _no_textures(textures)

    # -- the cut (the Engine's selection step) ------------------------------------------------

    def _select(self, fs: FrameState, alpha: float, gamma: float) -> Selection:
        """The LOD cut of the view with C = alpha (module docstring, steps 1-3)."""
        tree = self.tree
        lam = pixels_per_radian(fs)
        below = eye_below_ground(tree, fs)
        visible = boxes_in_frustum(tree.bboxes, fs.planes) & tree.in_domain
        cut = self._selector.cut(fs.eye, lam, alpha, fs.scale, visible)
        self.last_cut = cut
        drawn = np.flatnonzero(cut.visible) if not below else np.empty(0, dtype=np.int64)
        rho = cut.screen_errors(lam)[drawn]
        self._frame_keys = [
            (
                "pq",
                int(cut.rows[k]),
                tuple(cut.midpoints[k].tolist()),
                tuple(cut.keep[k].tolist()),
                int(cut.inserted[k]),
            )
            for k in drawn.tolist()
        ]
        # Visited: the refined ancestors (REFINED), then the cut (SELECTED, or CULLED).
        visited = np.concatenate([cut.refined, cut.rows])
        results = np.concatenate(
            [np.full(len(cut.refined), 1), np.where(cut.visible, 2, 0)]
        ).astype(np.uint8)
        return Selection(
            cut.rows[drawn],
            rho,
            np.zeros(len(drawn)),
            visited,
            results,
            below,
            {
                "nodes_visited": cut.nodes_visited,
                "culled": int(np.count_nonzero(~cut.visible)),
                "selected": len(drawn),
                "max_alpha": float(rho.max()) if len(rho) else 0.0,
                "max_gamma": 0.0,
            },
        )

    def _full_resolution_selection(self, fs: FrameState) -> Selection:
        """The cut at C = 0: every data point of every visible leaf."""
        return self._select(fs, 0.0, 0.0)

    def _budget_selection(self, fs: FrameState, max_triangles: int) -> Selection:
        raise InvalidParameterError(
            "A triangle budget (max_triangles) is not available for a point quadtree; "
            "choose its detail with alpha."
        )

    def _mesh_keys(self, selection: Selection, full_resolution: bool) -> list[tuple]:
        """One GPU cache key per drawn node: (node, midpoints, kept midpoints, replayed)."""
        return self._frame_keys

    def _upload(self, groups) -> list[tuple[Any, list[Any]]] | None:
        """The Engine's upload, after building every mesh the cache lacks in one kernel call
        (``node_meshes``); the cache then takes them node by node."""
        missing = [key for _, keys in groups for key in keys if key not in self.cache]
        self._batch = self._build_meshes(missing)
        try:
            return super()._upload(groups)
        finally:
            self._batch = None

    def _build_meshes(self, keys: list[tuple]) -> dict[tuple, tuple[np.ndarray, np.ndarray]]:
        """The GPU data of the meshes of ``keys`` (``_mesh_data``), built in one kernel call:
        views into one vertex array (V, 4) float32 and one triangle array (T, 3) uint32."""
        if not keys:
            return {}
        _, rows, midpoints, keep, inserted = zip(*keys, strict=True)
        verts, vstart, tris, tstart = node_meshes(self.tree, rows, midpoints, keep, inserted)
        data = np.zeros((len(verts), 4), dtype=np.float32)
        data[:, :3] = verts - self.tree.origin
        tris = tris.astype(np.uint32)
        v, t = vstart.tolist(), tstart.tolist()
        return {key: (data[v[m] : v[m + 1]], tris[t[m] : t[m + 1]]) for m, key in enumerate(keys)}

    def _mesh_data(self, key: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(vertex data (n, 4) float32: local x, y, z and flag 0; triangles (m, 3) uint32)."""
        batch = getattr(self, "_batch", None)
        if batch and key in batch:
            return batch[key]
        # Outside a frame's upload (or a mesh evicted since): a batch of one.
        return self._build_meshes([key])[key]

    def resident(self, nodes: np.ndarray) -> np.ndarray:
        """(k,) bool: whether a mesh of each node row of ``nodes`` is in the GPU cache."""
        rows = {k[1] for k in self.cache.keys() if k[0] == "pq"}
        return np.array([int(i) in rows for i in np.asarray(nodes)], dtype=bool)

    def upload(self, node: int) -> bool:
        """Nothing to do ahead of a frame: the frame uploads the meshes of its cut."""
        self._check_alive()
        return False

    def set_skirts(self, skirts: bool) -> None:
        """Kept for the viewer's toggle; the LOD mesh needs no skirts."""
        self.skirts = bool(skirts)


def _no_textures(textures: Any) -> None:
    if textures is not None:
        raise InvalidParameterError(
            "A point quadtree is drawn with the hypsometric colour ramp; texture pyramids "
            "apply to approximation trees (build one without --kind point-quadtree)."
        )


__all__ = ["PointQuadtreeEngine", "pixels_per_radian"]
