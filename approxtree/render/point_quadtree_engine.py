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
3. Nodes whose box lies outside the frustum are never refined and not drawn (the cut stays
   a restricted partition, so their visible neighbours keep matching edges).
4. Each drawn node's mesh is one GPU cache entry keyed by (node, midpoints, kept midpoints,
   points replayed), so a mesh is uploaded again only when its own refinement changes.

The cut's mesh is continuous (shared lattice vertices, midpoints on straight edges covered by
zero-area triangles), so no skirts are hung; ``skirts`` is accepted and changes nothing.
γ and texture pyramids do not apply (max_gamma is 0); a triangle budget is not offered.
``full_resolution`` draws the cut at α = 0: every data point of every visible leaf.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.camera import Camera
from approxtree.render.engine import DEFAULT_CACHE_BYTES, Engine, Frame, create_context
from approxtree.render.frame_state import FrameState, display_scale
from approxtree.render.frustum import boxes_in_frustum
from approxtree.render.gpu_cache import GpuCache
from approxtree.render.selector import Selection, check_thresholds, eye_below_ground
from approxtree.render.shaders import create_program


def pixels_per_radian(fs: FrameState) -> float:
    """λ: the largest screen pixels per radian of view angle over the image (at its corner)."""
    w, h = fs.viewport
    t2 = ((0.5 * w) ** 2 + (0.5 * h) ** 2) / fs.focal_px**2
    return float(fs.focal_px * (1.0 + t2))


class PointQuadtreeEngine(Engine):
    """Renderer of one PointQuadtree (see the module docstring); made by ``Engine(tree)``."""

    def __init__(
        self,
        tree,
        textures: Any = None,
        context: Any = None,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
        offscreen: bool | None = None,
        skirts: bool = True,
    ) -> None:
        # Bad arguments fail before any GPU object exists.
        _no_textures(textures)
        if not (isinstance(cache_bytes, int) and cache_bytes > 0):
            raise InvalidParameterError(f"cache_bytes must be an int > 0, got {cache_bytes!r}.")
        self.tree = tree
        self.owns_context = context is None
        self.offscreen = self.owns_context if offscreen is None else bool(offscreen)
        self.skirts = bool(skirts)
        self.ctx = create_context() if context is None else context
        self.scale = display_scale(tree.terrain)
        self._data_texels = self.texels = np.zeros((len(tree), 2))
        self._full_chunks = None
        self._targets: dict[tuple[str, int, int], Any] = {}
        self._released = False
        self.programs = {
            "terrain": create_program(self.ctx, "terrain"),
            "position": create_program(self.ctx, "position"),
            "textured": create_program(self.ctx, "textured"),
        }
        self.cache = GpuCache(self.ctx, cache_bytes)
        self.normal_map, self._normal_uv = self._make_normal_map()
        self.pyramid = None
        self._texture_patches: dict[tuple[str, int], Any] = {}
        #: The LODCut of the last frame (None before the first).
        self.last_cut = None

    def set_textures(self, textures: Any) -> None:
        """Only None: a point quadtree is drawn with the hypsometric colour ramp."""
        self._check_alive()
        _no_textures(textures)

    def render(
        self,
        camera: Camera,
        size: tuple[int, int] = (1280, 720),
        alpha: float = 1.0,
        gamma: float = 2.0,
        wireframe: bool = False,
        full_resolution: bool = False,
        target: Any = None,
        read_image: bool | None = None,
        world_positions: bool = False,
        lighting: bool = True,
        share_textures: bool = True,
        max_triangles: int | None = None,
    ) -> Frame:
        """Draw the LOD mesh of ``camera`` with C = alpha (see Engine.render for the arguments;
        gamma and share_textures do not apply, max_triangles is refused)."""
        self._check_alive()
        alpha, gamma = check_thresholds(alpha, gamma)
        if max_triangles is not None:
            raise InvalidParameterError(
                "A triangle budget (max_triangles) is not available for a point quadtree; "
                "choose its detail with alpha."
            )
        fs = self.frame_state(camera, size)
        w, h = fs.viewport
        # 1-3. The cut: α as C, λ from the view, frustum-culled nodes kept coarse.
        t0 = time.perf_counter()
        tree = self.tree
        lam = pixels_per_radian(fs)
        below = eye_below_ground(tree, fs)
        visible = boxes_in_frustum(tree.bboxes, fs.planes)
        cut = tree.lod_cut(fs.eye, lam, 0.0 if full_resolution else alpha, fs.scale, visible)
        self.last_cut = cut
        drawn = np.flatnonzero(cut.visible) if not below else np.empty(0, dtype=np.int64)
        rho = cut.screen_errors(lam)[drawn]
        keys = [
            (
                "pq",
                int(cut.rows[k]),
                tuple(cut.midpoints[k].tolist()),
                tuple(cut.keep[k].tolist()),
                int(cut.inserted[k]),
            )
            for k in drawn.tolist()
        ]
        results = np.where(visible, 1, 0).astype(np.uint8)
        results[cut.rows[cut.visible]] = 2
        selection = Selection(
            cut.rows[drawn],
            rho,
            np.zeros(len(drawn)),
            np.arange(len(tree), dtype=np.int64),
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
        select_ms = (time.perf_counter() - t0) * 1e3
        groups = [(None, keys)]
        # 4. Upload what the cache lacks.
        t0 = time.perf_counter()
        resident = self._upload(groups)
        upload_ms = (time.perf_counter() - t0) * 1e3
        # 5. Draw.
        own = target is None and self.offscreen
        if target is None:
            target = self._target("color", w, h) if self.offscreen else self.ctx.fbo
        if read_image is None:
            read_image = own
        draw_ms, triangles, _ = self._draw(
            target, fs, groups, resident, wireframe, "terrain", lighting
        )
        image = None
        if read_image:
            raw = target.read(viewport=(0, 0, w, h), components=4, alignment=1)
            image = np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 4)[::-1].copy()
        positions = self._positions(fs, groups) if world_positions else None
        stats = {
            "nodes_visited": selection.stats["nodes_visited"],
            "culled": selection.stats["culled"],
            "patches": len(keys),
            "triangles": int(triangles),
            "max_alpha": selection.stats["max_alpha"],
            "max_gamma": 0.0,
            "select_ms": round(select_ms, 3),
            "upload_ms": round(upload_ms, 3),
            "draw_ms": round(draw_ms, 3),
            "gpu_bytes": int(self.cache.nbytes),
            "texture_patches": 0,
            "texture_switches": 0,
        }
        return Frame(image, stats, selection, fs, positions)

    def _mesh_data(self, key: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(vertex data (n, 4) float32: local x, y, z and flag 0; triangles (m, 3) uint32)."""
        _, row, midpoints, keep, inserted = key
        verts, tris = self.tree.node_mesh(self.tree.node_keys[row], midpoints, keep, inserted)
        data = np.zeros((len(verts), 4), dtype=np.float32)
        data[:, :3] = verts - self.tree.origin
        return data, np.asarray(tris, dtype=np.uint32)

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
