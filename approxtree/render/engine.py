"""Engine: draws an approximation tree with moderngl, offscreen (EGL) or into a host's context.

The Engine is the facade over the renderer's three roles (DESIGN.md, "Renderer roles"): the
PayloadProvider (provider.py) loads node payloads on background threads into a CPU cache
bounded in bytes, the traversal (selector.py, traversal.py) chooses the cut and what is drawn
while it loads, and the Renderer (renderer.py) owns the GL objects. It owns every GPU object it
makes — programs, the normal map, the patch cache, its offscreen framebuffers and, when it
created it, the context — and frees them (and stops the provider) in ``release()``. It never
touches a global context: either it creates a standalone EGL context or it draws into the
``context`` it was given (embedding: into the framebuffer bound there).

A frame:

1. FrameState from the camera and viewport (display scale of the terrain, near/far fitted).
2. Selection (pure, no GL): the cut of the tree for alpha and gamma; ``full_resolution`` draws
   the unsimplified terrain instead (the grid in chunks of CHUNK lines, frustum-culled). An
   interactive frame (``wait=False``) then plans with the traversal: payloads in the CPU cache
   are uploaded within the frame's budget, the others requested from the provider, and the
   nearest resident ancestors drawn meanwhile; a single image (``wait=True``) draws the cut
   itself, loading what it lacks.
3. Textures (with a texture pyramid): each selected node is textured by the texture patch of
   itself or of the ancestor closest to the root whose γ is within the threshold (core paper,
   4.2); meshes are grouped by texture patch so each patch is bound once.
4. Upload: missing meshes (patch + skirt, float32 relative to ``tree.origin``) and texture
   patches (RGBA8 with hardware mipmaps) into the LRU GpuCache.
5. Draw: clear to transparent black, per texture group one bind, one draw call per mesh,
   ``ctx.finish()`` (draw_ms).
6. Read back the RGBA image (offscreen) and, on request, a world-position buffer.

Lighting and style (render/style.py): per-pixel normals from a normal map computed once from
the height field (central differences in display units, exaggeration included, at most
NORMAL_MAP_MAX texels per side), lit by a Sun (azimuth, altitude) given per frame. The base
colour is the texture patch's texel (trilinear); without a pyramid, the hypsometric palette
(textures/palettes.py) at the fragment's elevation; a pyramid of grey shading (a baked
hillshade) shades that palette. ``lighting`` "auto" (the default) lights untextured terrain
only: baked shading is drawn once (decal); True / "on" modulates the colour by the light.
Walls along the domain's outer border are drawn in a neutral wall colour, lit from their
outward normal; the background is transparent, a sky gradient or one colour.
With a pyramid the node's texel size is its texture patch's (γ_N); without one, its data
spacing.
"""

from __future__ import annotations

import itertools
import math
import os
import time
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from approxtree.errors import ApproxTreeWarning, EmptyTerrainError, InvalidParameterError
from approxtree.geometry.grid import OVERVIEW_SIDE, Grid
from approxtree.render.camera import Camera
from approxtree.render.context import create_context
from approxtree.render.frame_state import (
    FrameState,
    check_viewport,
    display_scale,
    overview_camera,
)
from approxtree.render.frustum import boxes_in_frustum
from approxtree.render.gpu_cache import GpuCache
from approxtree.render.provider import DEFAULT_CPU_CACHE_BYTES, Payload, PayloadProvider
from approxtree.render.renderer import Renderer
from approxtree.render.selector import Selection, check_thresholds, eye_below_ground, select
from approxtree.render.skirts import add_skirts, patches_reach_rect, skirt_base, skirt_depths
from approxtree.render.style import Background, Sun, as_sun, resolve_lighting
from approxtree.render.texture_sharing import texture_nodes
from approxtree.render.traversal import Cut, plan_frame
from approxtree.render.visual_error import texel_sizes
from approxtree.textures.palettes import get_palette

#: Default GPU cache budget (bytes).
DEFAULT_CACHE_BYTES = 1 << 30
#: Texture windows of nodes remembered at most (each a few hundred bytes).
TEXTURE_PATCH_MEMO = 1 << 16
#: Largest side of the normal map (texels), further limited by GL_MAX_TEXTURE_SIZE.
NORMAL_MAP_MAX = OVERVIEW_SIDE  # the overview a tree store keeps is this map's samples
#: Data lines per side of a full-resolution chunk (256 intervals).
CHUNK = 257
#: Keys of Frame.stats and of ``approxtree render --json``.
STAT_KEYS = (
    "nodes_visited",
    "culled",
    "patches",
    "triangles",
    "max_alpha",
    "max_gamma",
    "select_ms",
    "upload_ms",
    "draw_ms",
    "gpu_bytes",
    "texture_patches",
    "texture_switches",
    "stand_ins",
    "texture_stand_ins",
    "pending",
    "uploads",
    "cpu_bytes",
    "empty",
    "warning",
)


def _check_drawable(tree) -> None:
    """EmptyTerrainError for a tree whose only node has no triangle (too few valid points)."""
    if tree.child_count[0] == 0 and len(tree.patch(0).triangles) == 0:
        raise EmptyTerrainError(
            f"This tree has nothing to draw: its terrain's {tree.terrain.point_count} valid "
            "data point(s) form no triangle (a surface needs at least three points not on one "
            "line, e.g. one grid cell of valid corners). Check the file's nodata value or use "
            "a larger area."
        )


class EmptyFrameWarning(ApproxTreeWarning):
    """A frame shows no terrain (camera under the ground, frustum that misses the terrain)."""


def empty_frame_reason(
    selection: Selection, triangles: int, image: np.ndarray | None
) -> str | None:
    """Why a frame shows no terrain, or None when it shows some.

    image: (h, w, 4) uint8 read back (alpha 0 where nothing is drawn), or None when not read.
    """
    if selection.below_ground:
        return (
            "The camera is below the terrain surface: the frame shows no terrain. Move the "
            "eye above the ground."
        )
    if len(selection.nodes) == 0:
        return (
            "No part of the terrain lies in the view frustum: the frame shows no terrain. "
            "Aim the camera at the terrain."
        )
    if triangles == 0:
        return (
            "The patches in view hold no triangle (isolated valid data points): the frame "
            "shows no terrain."
        )
    if image is not None and not image[..., 3].any():
        return (
            "No terrain pixel was drawn: the terrain's bounding boxes touch the view frustum "
            "but its surface stays outside the image. Aim the camera at the terrain."
        )
    return None


@dataclass
class Frame:
    """One rendered frame.

    image: (h, w, 4) uint8 RGBA, row 0 at the top, alpha 0 where no terrain is drawn (None
    when drawn into a host's framebuffer without read-back). stats: dict of STAT_KEYS.
    positions: (h, w, 4) float64 world x, y, z and a flag (1 surface, 0 skirt, −1 nothing,
    x, y, z NaN there), row 0 at the top, when asked for.
    texture_nodes: (k,) int64, per selected node the node whose texture patch textured it
    (itself or a shared ancestor), and texture_gammas: (k,) that node's γ; None without a
    texture pyramid.
    """

    image: np.ndarray | None
    stats: dict[str, Any]
    selection: Selection
    frame_state: FrameState
    positions: np.ndarray | None = None
    texture_nodes: np.ndarray | None = None
    texture_gammas: np.ndarray | None = None

    def _repr_png_(self) -> bytes | None:
        """The image as a PNG, for Jupyter (None when it was not read back)."""
        if self.image is None:
            return None
        import io

        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(self.image), "RGBA").save(buf, format="PNG")
        return buf.getvalue()


class Engine:
    """Renderer of one ApproximationTree.

    tree: the ApproximationTree. textures: a TexturePyramid (or its folder), or None to draw
    with the hypsometric colour ramp; ``set_textures`` changes it later.
    context: a moderngl Context to draw into (embedding); None creates a standalone EGL one.
    cache_bytes: GPU cache budget.
    offscreen: draw into the engine's own framebuffer and read the image back; None means
    "when the engine created the context" (an embedded engine draws into the host's
    framebuffer bound in ``context``).
    skirts: hang skirts below patch borders (off only to show what they close).
    cpu_cache_bytes: budget of the provider's CPU cache of node payloads (meshes with skirts,
    texture patches); loader_threads: its background threads.

    Paging (DESIGN.md, "Renderer roles"): the provider (render/provider.py) loads payloads on
    background threads into its CPU cache, the traversal (render/traversal.py) plans each
    frame, the GpuCache holds what was uploaded. ``render(..., wait=True)`` (a single image)
    blocks until every payload of the cut is drawn; ``wait=False`` (interactive frames) never
    blocks on the store except for the root: missing nodes are requested coarsest first and
    their nearest resident ancestors are drawn meanwhile.
    """

    def __new__(cls, tree: Any, *args: Any, **kwargs: Any) -> Engine:
        # A PointQuadtree (seed 003) is drawn by its own engine: its cut is a per-view mesh.
        if cls is Engine and getattr(tree, "tree_kind", None) == "point_quadtree":
            from approxtree.render.point_quadtree_engine import PointQuadtreeEngine

            return super().__new__(PointQuadtreeEngine)
        return super().__new__(cls)

    def __init__(
        self,
        tree,
        textures: Any = None,
        context: Any = None,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
        offscreen: bool | None = None,
        skirts: bool = True,
        cpu_cache_bytes: int = DEFAULT_CPU_CACHE_BYTES,
        loader_threads: int = 2,
        exaggeration: float = 1.0,
        palette: Any = None,
    ) -> None:
        # Bad textures and a tree with nothing to draw fail before any GPU object exists.
        _check_drawable(tree)
        textures = _as_pyramid(textures, tree.terrain)
        _check_exaggeration(exaggeration)
        palette = get_palette(palette)
        provider = PayloadProvider(self._load_payload, cpu_cache_bytes, loader_threads)
        self._open_gpu(tree, context, cache_bytes, offscreen, skirts)
        self.provider = provider
        # Per-node figures used every frame, computed once.
        self._data_texels = texel_sizes(tree)
        self.texels = self._data_texels
        # Skirts: infinite errors stand in by the node's z extent; walls on node borders only.
        extents = tree.bboxes[:, 5] - tree.bboxes[:, 2]
        self._node_borders = patches_reach_rect(tree.terrain)
        rects = np.asarray(tree.rects, dtype=np.float64) if self._node_borders else None
        self.skirt_depths = skirt_depths(tree.errors, tree.terrain.z_range, extents, rects)
        self.skirt_base = skirt_base(tree.errors, tree.terrain.z_range, extents)
        d = tree.terrain.domain
        self._domain = (d.xmin, d.ymin, d.xmax, d.ymax)
        self.set_palette(palette)
        if exaggeration != 1.0:
            self.set_vertical_exaggeration(exaggeration)
        self.set_textures(textures)
        # Load the compiled selection kernels now, so select_ms of the first frame is honest.
        warm = overview_camera(tree.bboxes[0], self.scale)
        warm_selection = select(tree, self.frame_state(warm, (2, 2)), 1.0, 2.0, self.texels)
        texture_nodes(tree.parents, warm_selection, 2.0)

    def _open_gpu(
        self, tree: Any, context: Any, cache_bytes: int, offscreen: bool | None, skirts: bool
    ) -> None:
        """The GL state every engine owns: context, programs, GPU cache, normal map.

        Shared by the engines of every tree kind; a bad cache size fails before any GL object.
        """
        if not (isinstance(cache_bytes, int) and cache_bytes > 0):
            raise InvalidParameterError(f"cache_bytes must be an int > 0, got {cache_bytes!r}.")
        self.tree = tree
        self.owns_context = context is None
        self.offscreen = self.owns_context if offscreen is None else bool(offscreen)
        self.skirts = bool(skirts)
        self.ctx = create_context() if context is None else context
        self.scale = display_scale(tree.terrain)
        self._full_chunks: list[tuple[Any, np.ndarray]] | None = None
        self._released = False
        #: The Renderer (render/renderer.py): every GL object of the engine.
        self.renderer = Renderer(self.ctx, cache_bytes, self.owns_context)
        self.programs = self.renderer.programs
        self.cache: GpuCache = self.renderer.cache
        self.renderer.set_normal_map(*self._normal_map_data())
        # Side walls are the skirts on the domain's border (local coordinates).
        d = tree.terrain.domain
        ox, oy, _ = tree.origin
        self.renderer.domain = (d.xmin - ox, d.ymin - oy, d.xmax - ox, d.ymax - oy)
        self.renderer.domain_tol = 1e-5 * max(d.xmax - d.xmin, d.ymax - d.ymin, 1e-9)
        self.set_palette(None)
        self.shade_texture = False
        self.pyramid = None
        self._texture_patches: dict[tuple[str, int], Any] = {}
        #: The PayloadProvider (None for engines that build their meshes per frame).
        self.provider: PayloadProvider | None = None

    # -- public -----------------------------------------------------------------------------

    def set_textures(self, textures: Any) -> None:
        """Texture the terrain with a TexturePyramid (or the folder holding one), or None.

        γ_N then follows each node's texture patch; the texture patches of a previous pyramid
        leave the GPU cache.
        """
        self._check_alive()
        from approxtree.textures.patch import patch_texel_sizes

        textures = _as_pyramid(textures, self.tree.terrain)
        self.cache.drop(lambda key: key[0] == "tex")
        if self.provider is not None:
            self.provider.drop(lambda key: key[0] == "tex")
        self._texture_patches.clear()
        self.pyramid = textures
        self.shade_texture = textures is not None and _is_shading(textures)
        self.texels = (
            self._data_texels
            if textures is None
            else patch_texel_sizes(textures, np.asarray(self.tree.rects, dtype=np.float64))
        )

    def set_palette(self, palette: Any) -> None:
        """Colour untextured terrain (and tint baked shading) with a hypsometric palette: a
        name of ``approxtree.textures.palettes.PALETTES``, a Palette, or None (the default)."""
        self._check_alive()
        palette = get_palette(palette)
        oz = self.tree.origin[2]
        z0, z1 = self.tree.terrain.z_range
        lut, (p0, p1) = palette.lookup_table((z0, z1))
        self.renderer.set_palette(lut, (p0 - oz, p1 - oz))
        self.palette = palette

    @property
    def exaggeration(self) -> float:
        """The vertical exaggeration: displayed z = z × this factor (see ``display_scale``)."""
        return float(self.scale[2] / display_scale(self.tree.terrain)[2])

    def texture_patch(self, node: int) -> Any:
        """The TexturePatch of ``node`` (made on first use; references the pyramid's data)."""
        from approxtree.textures.patch import TexturePatch

        key = ("node", int(node))
        patch = self._texture_patches.get(key)
        if patch is None:
            # Bounded like the caches, however many nodes a fly-over visits.
            if len(self._texture_patches) >= TEXTURE_PATCH_MEMO:
                self._texture_patches.clear()
            patch = TexturePatch.for_rect(self.pyramid, self.tree.node(int(node)).rect)
            self._texture_patches[key] = patch
        return patch

    def frame_state(self, camera: Camera, size: tuple[int, int]) -> FrameState:
        """The FrameState of ``camera`` over ``size`` for this tree (validated)."""
        w, h = check_viewport(size)
        limit = self._max_viewport()
        if w > limit[0] or h > limit[1]:
            raise InvalidParameterError(
                f"size {w} × {h} exceeds this OpenGL's limit of {limit[0]} × {limit[1]} pixels."
            )
        return FrameState.from_camera(
            camera, (w, h), self.tree.bboxes[0], self.tree.origin, self.scale
        )

    def render(
        self,
        camera: Camera,
        size: tuple[int, int] = (1280, 720),
        alpha: float | Cut = 1.0,
        gamma: float = 2.0,
        wireframe: bool = False,
        full_resolution: bool = False,
        target: Any = None,
        read_image: bool | None = None,
        world_positions: bool = False,
        lighting: bool | str | None = "auto",
        share_textures: bool = True,
        max_triangles: int | None = None,
        wait: bool = True,
        max_uploads: int | None = None,
        upload_ms: float | None = None,
        sun: Sun | tuple[float, float] | None = None,
        background: Background | str | tuple | None = None,
    ) -> Frame:
        """Draw one frame; see the module docstring for the steps.

        camera: Camera; size: (w, h) pixels; alpha: α threshold (px, > 0), or a Cut
        (traversal.py) that gives alpha, gamma, max_triangles and full_resolution; gamma: γ
        threshold (px², > 0, inf ignores it); wireframe: draw triangle edges instead of filled
        triangles; full_resolution: draw the unsimplified terrain (reference).
        target: framebuffer to draw into; None draws into the engine's own offscreen
        framebuffer, or, for an engine made with context=, into the framebuffer bound there.
        read_image: read the image back (default: only from the engine's own framebuffer).
        world_positions: also fill Frame.positions (an extra pass into a float buffer).
        lighting: modulate the colour by the light (True or "on") or draw it unlit (False or
        "off", decal mode); "auto" lights untextured terrain only (a baked shading texture is
        drawn once, as it is).
        share_textures: let nodes use an ancestor's texture patch (section 4.2); off only to
        measure what sharing saves.
        max_triangles: triangle budget instead of the alpha threshold: draw the cut of
        smallest largest α with at most this many triangles, skirts included (``budget``);
        stats["max_alpha"] is the α reached.
        wait: draw the settled cut, loading every payload it needs (a single image); False
        draws an interactive frame that never waits for the store except for the root: the
        nodes not yet loaded are requested in the background and their nearest resident
        ancestors drawn meanwhile (stats "stand_ins", "pending"). max_uploads, upload_ms:
        such a frame's upload budget (meshes, milliseconds after the first; None: no limit).
        sun: a Sun or (azimuth, altitude) in degrees (default 315°, 45°): the light of
        ``lighting`` and of the side walls. background: "transparent" (default: alpha 0 where
        no terrain is drawn), "sky", a colour name, "#rrggbb" or (r, g, b); an opaque
        background makes the read-back image opaque.
        """
        self._check_alive()
        sun = as_sun(sun)
        background = Background.parse(background)
        lighting = resolve_lighting(lighting, self.pyramid is not None)
        # A Cut object (DESIGN.md) in place of alpha sets every cut option at once.
        if isinstance(alpha, Cut):
            cut = alpha
            alpha, gamma = cut.alpha, cut.gamma
            max_triangles, full_resolution = cut.max_triangles, cut.full_resolution
        alpha, gamma = check_thresholds(alpha, gamma)
        fs = self.frame_state(camera, size)
        w, h = fs.viewport
        # 2. Selection (or the full-resolution chunks).
        t0 = time.perf_counter()
        if full_resolution:
            selection = self._full_resolution_selection(fs)
        elif max_triangles is not None:
            selection = self._budget_selection(fs, max_triangles)
        else:
            selection = self._select(fs, alpha, gamma)
        select_ms = (time.perf_counter() - t0) * 1e3
        # 2b. Paging: what is drawn while the cut loads (the traversal's plan).
        t0 = time.perf_counter()
        paging = {"stand_ins": 0, "pending": 0, "uploads": 0, "texture_stand_ins": 0}
        requests: list[tuple] = []
        interactive = not wait and not full_resolution and self.provider is not None
        if interactive:
            selection, paging, requests = self._page(selection, fs, max_uploads, upload_ms)
        page_ms = (time.perf_counter() - t0) * 1e3
        keys = self._mesh_keys(selection, full_resolution)
        # 3. Texture patch of each mesh, and the meshes grouped by texture patch.
        tex_nodes = tex_gammas = None
        if self.pyramid is not None:
            if full_resolution:
                tex_nodes = selection.nodes.copy()
                tex_gammas = np.zeros(len(tex_nodes))
                owners = [("full", int(i)) for i in tex_nodes]
            else:
                tex_nodes, tex_gammas = texture_nodes(
                    self.tree.parents, selection, gamma, share_textures
                )
                owners = [("node", int(i)) for i in tex_nodes]
            groups = self._group_by_texture(keys, owners)
            if interactive:
                # Texture patches not loaded yet: the root's stands in, the rest is requested.
                groups, tex_requests = self._page_textures(groups)
                paging["texture_stand_ins"] = len(tex_requests)
                requests = tex_requests + requests
        else:
            groups = [(None, keys)]
        if interactive:
            # One request per frame (it replaces the previous frame's): textures, then meshes.
            self.provider.request(requests)
        # 4. Upload what the cache lacks; a frame larger than the budget is drawn in parts.
        t0 = time.perf_counter()
        resident = self._upload(groups)
        upload_ms = (time.perf_counter() - t0) * 1e3 + page_ms
        # 4. Draw.
        own = target is None and self.offscreen
        if target is None:
            target = self._target("color", w, h) if self.offscreen else self.ctx.fbo
        if read_image is None:
            read_image = own
        program = "terrain" if self.pyramid is None else "textured"
        draw_ms, triangles, switches = self._draw(
            target, fs, groups, resident, wireframe, program, lighting, sun, background
        )
        image = None
        if read_image:
            raw = target.read(viewport=(0, 0, w, h), components=4, alignment=1)
            image = np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 4)[::-1].copy()
        positions = None
        if world_positions:
            positions = self._positions(fs, [(None, keys)])
        stats = {
            "nodes_visited": selection.stats["nodes_visited"],
            "culled": selection.stats["culled"],
            "patches": len(keys),
            "triangles": int(triangles),
            "max_alpha": selection.stats["max_alpha"],
            "max_gamma": selection.stats["max_gamma"],
            "select_ms": round(select_ms, 3),
            "upload_ms": round(upload_ms, 3),
            "draw_ms": round(draw_ms, 3),
            "gpu_bytes": int(self.cache.nbytes),
            "texture_patches": sum(1 for tex, _ in groups if tex is not None),
            "texture_switches": int(switches),
            **paging,
            "cpu_bytes": int(self.provider.nbytes) if self.provider is not None else 0,
        }
        # 7. A frame without terrain says so (stats and a warning) instead of a silent blank.
        reason = empty_frame_reason(selection, triangles, image)
        if image is not None and background.opaque:
            # The background pass left alpha 0 off the terrain (for the check above).
            image[..., 3] = 255
        stats["empty"] = reason is not None
        stats["warning"] = reason
        if reason is not None:
            warnings.warn(reason, EmptyFrameWarning, stacklevel=2)
        return Frame(image, stats, selection, fs, positions, tex_nodes, tex_gammas)

    def _select(self, fs: FrameState, alpha: float, gamma: float) -> Selection:
        """The cut of the frame by alpha and gamma (after the host's selection filter)."""
        selection = select(self.tree, fs, alpha, gamma, self.texels)
        if self.selection_filter is not None:
            selection = self.selection_filter(selection, fs)
        return selection

    def _page(
        self,
        wanted: Selection,
        fs: FrameState,
        max_uploads: int | None,
        upload_ms: float | None,
    ) -> tuple[Selection, dict[str, int], list[tuple]]:
        """The drawn cut of an interactive frame, its paging figures and the mesh keys to
        request, coarsest first (traversal.py).

        Uploads the wanted nodes whose payload is in the CPU cache (coarsest first, within
        the budget), and returns the nearest resident ancestors of what is still missing. The
        root counts as resident: the draw loads it when it is not (the one blocking read).
        """
        provider = self.provider
        provider.raise_error()
        t0 = time.perf_counter()
        plan = plan_frame(
            wanted, fs, self.tree, self.texels, self._on_gpu, self._on_cpu, max_uploads
        )
        budget_ms = None if upload_ms is None else upload_ms - (time.perf_counter() - t0) * 1e3
        uploads = self.renderer.upload_within(
            [("node", int(i)) for i in plan.upload], self._mesh_data, None, budget_ms
        )
        # What is drawable now (uploads may have evicted older meshes from a small cache).
        drawn = plan_frame(wanted, fs, self.tree, self.texels, self._on_gpu, self._on_cpu, 0)
        paging = {
            "stand_ins": drawn.stand_ins,
            "pending": drawn.pending,
            "uploads": uploads,
            "texture_stand_ins": 0,
        }
        return drawn.drawn, paging, [("node", int(i)) for i in plan.request]

    def _page_textures(self, groups):
        """Groups of an interactive frame whose texture patches are all loaded or loadable
        without the store: a texture patch neither on the GPU nor in the CPU cache is replaced
        by the root's (coarser, always drawable: its one blocking read) and requested.

        Returns (groups, texture keys to request).
        """
        root_key = self._group_by_texture([("node", 0)], [("node", 0)])[0][0]
        merged: dict[tuple, list] = {}
        requests = []
        for tex_key, keys in groups:
            if tex_key not in self.cache and tex_key not in self.provider:
                requests.append(tex_key)
                tex_key = root_key
            merged.setdefault(tex_key, []).extend(keys)
        return list(merged.items()), requests

    def _on_gpu(self, nodes: np.ndarray) -> np.ndarray:
        """(k,) bool: node meshes in the GPU cache; the root always counts (see ``_page``)."""
        nodes = np.asarray(nodes)
        return self.resident(nodes) | (nodes == 0)

    def _on_cpu(self, nodes: np.ndarray) -> np.ndarray:
        """(k,) bool: node payloads in the provider's CPU cache."""
        return self.provider.is_resident([("node", int(i)) for i in np.asarray(nodes)])

    def _mesh_keys(self, selection: Selection, full_resolution: bool) -> list[tuple]:
        """GPU cache keys of the meshes to draw for ``selection`` (``_mesh_data`` builds them)."""
        kind = "full" if full_resolution else "node"
        return [(kind, int(i)) for i in selection.nodes]

    def _budget_selection(self, fs: FrameState, max_triangles: int) -> Selection:
        """Selection under a triangle budget (per-node counts computed on first use)."""
        from approxtree.render.budget import node_triangles, select_budget

        if getattr(self, "_node_triangles", None) is None:
            self._node_triangles = node_triangles(self.tree, self.skirts)
        return select_budget(self.tree, fs, max_triangles, self._node_triangles, self.texels)

    def release(self) -> None:
        """Free every GPU object of the engine (and its context, if it created it), stop the
        provider's threads and empty its CPU cache."""
        if self._released:
            return
        self._released = True
        if self.provider is not None:
            self.provider.close()
        self.renderer.release()

    @property
    def normal_map(self) -> Any:
        """The normal map texture (owned by the renderer)."""
        return self.renderer.normal_map

    @property
    def _targets(self) -> dict[tuple[str, int, int], Any]:
        return self.renderer.targets

    @property
    def released(self) -> bool:
        return self._released

    def __enter__(self) -> Engine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    # -- frame steps ------------------------------------------------------------------------

    def _check_alive(self) -> None:
        if self._released:
            raise InvalidParameterError("This Engine was released; create a new one.")

    def _max_viewport(self) -> tuple[int, int]:
        dims = self.ctx.info.get("GL_MAX_VIEWPORT_DIMS", (16384, 16384))
        rb = int(self.ctx.info.get("GL_MAX_RENDERBUFFER_SIZE", 16384))
        return min(int(dims[0]), rb), min(int(dims[1]), rb)

    def _group_by_texture(self, keys: list[tuple[str, int]], owners: list[tuple[str, int]]):
        """[(texture key, mesh keys)] with meshes grouped by their texture patch.

        owners: per mesh key, the ("node", id) or ("full", chunk) whose texture patch it uses.
        Two owners with the same window of the same level share one texture.
        """
        groups: dict[tuple, list[tuple[str, int]]] = {}
        for key, owner in zip(keys, owners, strict=True):
            p = self._owner_patch(owner)
            groups.setdefault(("tex", p.level, p.col0, p.row0, p.width, p.height), []).append(key)
        return list(groups.items())

    def _owner_patch(self, owner: tuple[str, int]) -> Any:
        if owner[0] == "node":
            return self.texture_patch(owner[1])
        from approxtree.geometry.rect import Rect
        from approxtree.textures.patch import TexturePatch

        patch = self._texture_patches.get(owner)
        if patch is None:
            b = self._full_resolution_chunks()[owner[1]][1]
            patch = TexturePatch.for_rect(self.pyramid, Rect(b[0], b[1], b[3], b[4]))
            self._texture_patches[owner] = patch
        return patch

    def _texture_data(self, tex_key: tuple) -> np.ndarray:
        """(h, w, 4) uint8 texels of a texture window (through the provider's CPU cache)."""
        if self.provider is not None:
            return self.provider.load(tex_key).texels
        return self._load_payload(tex_key).texels

    def _texture_uv(self, tex_key: tuple) -> tuple[float, float, float, float]:
        """uv = local.xy * t[:2] + t[2:] of a texture window (u along columns, v along rows,
        texel row 0 at v = 0)."""
        _, level, c0, r0, w, h = tex_key
        t = self.pyramid.levels[level].transform
        ox, oy, _ = self.tree.origin
        # col = (x − c) / a and row = (y − f) / e for a north-up level, x = local x + ox.
        return (
            1.0 / (t.a * w),
            1.0 / (t.e * h),
            (ox - t.c) / (t.a * w) - c0 / w,
            (oy - t.f) / (t.e * h) - r0 / h,
        )

    def _get_mesh(self, key: tuple[str, int]) -> Any:
        return self.cache.get(key, lambda: self._mesh_data(key))

    def _get_texture(self, tex_key: tuple) -> Any:
        return self.cache.get_texture(tex_key, lambda: self._texture_data(tex_key))

    def _upload(self, groups) -> list[tuple[Any, list[Any]]] | None:
        """Upload what the frame needs; returns the resident entries per group, or None when
        the frame exceeded the cache budget (entries were evicted: the draw fetches again)."""
        evictions = self.cache.evictions
        resident = []
        for tex_key, keys in groups:
            tex = self._get_texture(tex_key) if tex_key is not None else None
            resident.append((tex, [self._get_mesh(k) for k in keys]))
        return resident if self.cache.evictions == evictions else None

    def _draw(
        self,
        target,
        fs: FrameState,
        groups,
        resident,
        wireframe: bool,
        program: str,
        lighting: bool = True,
        sun: Sun | None = None,
        background: Background | None = None,
    ):
        """Clear ``target`` and draw the groups (Renderer.draw); returns (ms incl.
        ctx.finish(), triangles, texture binds)."""
        z0, z1 = self.tree.terrain.z_range
        oz = self.tree.origin[2]
        return self.renderer.draw(
            target,
            fs,
            groups,
            resident,
            wireframe,
            program,
            lighting,
            (z0 - oz, z1 - oz),
            self._get_mesh,
            self._get_texture,
            self._texture_uv,
            light=(sun or Sun()).direction,
            background=background,
            shade_texture=program == "textured" and self.shade_texture,
        )

    def _positions(self, fs: FrameState, groups) -> np.ndarray:
        """(h, w, 4) world positions of the drawn surface (see Frame.positions)."""
        w, h = fs.viewport
        fbo = self._target("position", w, h)
        self._draw(fbo, fs, groups, self._upload(groups), False, "position")
        raw = fbo.read(viewport=(0, 0, w, h), components=4, dtype="f4", alignment=1)
        local = np.frombuffer(raw, dtype=np.float32).reshape(h, w, 4)[::-1].astype(np.float64)
        out = local.copy()
        out[..., :3] += self.tree.origin
        out[local[..., 3] < -0.5, :3] = np.nan
        return out

    def _target(self, kind: str, w: int, h: int) -> Any:
        """The engine's offscreen framebuffer of ``kind`` ("color" RGBA8, "position" RGBA32F)."""
        return self.renderer.target(kind, w, h)

    # -- geometry ---------------------------------------------------------------------------

    def _mesh_data(self, key: tuple[str, int]) -> tuple[np.ndarray, np.ndarray]:
        """(vertex data (n, 4) float32: local x, y, z and skirt flag; triangles (m, 3) uint32).

        Node meshes come through the provider's CPU cache (loaded now when missing).
        """
        if key[0] == "node" and self.provider is not None:
            payload = self.provider.load(key)
            return payload.vertices, payload.triangles
        payload = self._load_payload(key)
        return payload.vertices, payload.triangles

    def _load_payload(self, key: tuple) -> Payload:
        """The payload of ``key``: ("node", i) or ("full", chunk) mesh arrays, or a texture
        window's texels (("tex", level, col0, row0, w, h)). Runs on the provider's threads:
        it reads the tree's store without keeping the patch (``read_patch``)."""
        if key[0] == "tex":
            from approxtree.textures.patch import TexturePatch

            _, level, c0, r0, w, h = key
            texels = TexturePatch(self.pyramid, level, c0, r0, w, h).texels()
            return Payload(texels=np.ascontiguousarray(texels, dtype=np.uint8))
        kind, i = key
        skirts = self.skirts
        if kind == "full":
            patch = self._full_resolution_chunks()[i][0]
            verts, tris = patch.vertices, patch.triangles
            flags = np.zeros(len(verts), dtype=np.float32)
        elif not skirts:
            patch = _read_patch(self.tree, i)
            verts, tris = patch.vertices, patch.triangles
            flags = np.zeros(len(verts), dtype=np.float32)
        else:
            patch = _read_patch(self.tree, i)
            verts, tris, flags = add_skirts(
                patch.vertices,
                patch.triangles,
                float(self.skirt_depths[i]),
                self._domain,
                self.skirt_base,
                patch.rect.as_tuple() if self._node_borders else None,
            )
        data = np.empty((len(verts), 4), dtype=np.float32)
        data[:, :3] = verts - self.tree.origin
        data[:, 3] = flags
        return Payload(data, np.ascontiguousarray(tris, dtype=np.uint32).reshape(-1, 3))

    def _full_resolution_chunks(self) -> list[tuple[Any, np.ndarray]]:
        """(patch, bbox (6,)) of the unsimplified terrain.

        Grid: full-resolution GridPatches over blocks of CHUNK × CHUNK data lines sharing
        their border lines (so no cracks and no skirts). Other terrains: the tree's leaves.
        """
        if self._full_chunks is not None:
            return self._full_chunks
        from approxtree.patches.grid import GridPatch

        terrain = self.tree.terrain
        chunks: list[tuple[Any, np.ndarray]] = []
        if isinstance(terrain, Grid):
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
        else:
            for i in self.tree.leaves:
                chunks.append((self.tree.patch(int(i)), self.tree.bboxes[i]))
        self._full_chunks = chunks
        return chunks

    def _full_resolution_selection(self, fs: FrameState) -> Selection:
        """A Selection over the full-resolution chunks (ids index the chunk list)."""
        chunks = self._full_resolution_chunks()
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

    def _normal_map_data(self) -> tuple[np.ndarray, np.ndarray]:
        """Normal x, y (display units) over the domain as (ny, nx, 2) uint8, and the uv
        transform (4,) float: uv = local_xy * t[:2] + t[2:]."""
        terrain = self.tree.terrain
        limit = min(NORMAL_MAP_MAX, int(self.ctx.info.get("GL_MAX_TEXTURE_SIZE", 4096)))
        if isinstance(terrain, Grid):
            # Ascending x and y so that texture rows run south to north; one strided read
            # (a windowed grid reads only the sampled cells, block by block).
            xs, ys = terrain.x_coords, terrain.y_coords
            rs, cs = terrain.overview_steps(limit)
            z = np.asarray(terrain.strided_heights(rs, cs), dtype=np.float64)
            xs, ys = xs[::cs], ys[::rs]
        else:
            d = terrain.domain
            n = min(limit, 1024)
            xs = np.linspace(d.xmin, d.xmax, n)
            ys = np.linspace(d.ymin, d.ymax, n)
            z = terrain.height_at(xs[None, :], ys[:, None])
        ox, oy, _ = self.tree.origin
        sx, sy, sz = self.scale
        data = _normal_texels(z * sz, (xs - ox) * sx, (ys - oy) * sy)
        ny, nx = data.shape[:2]
        # Texel centre k sits at xs[k]: u = (x − xs[0]) / (dx · nx) + 0.5 / nx.
        dx = (xs[-1] - xs[0]) / max(nx - 1, 1) if nx > 1 else 1.0
        dy = (ys[-1] - ys[0]) / max(ny - 1, 1) if ny > 1 else 1.0
        uv = np.array(
            [
                1.0 / (dx * nx),
                1.0 / (dy * ny),
                0.5 / nx - (xs[0] - ox) / (dx * nx),
                0.5 / ny - (ys[0] - oy) / (dy * ny),
            ]
        )
        return data, uv

    # -- host hooks (interactive viewers) ---------------------------------------------------
    # A host that draws many frames per second bounds the work of each frame: it filters the
    # selection (draw resident ancestors while children upload, or freeze the cut), uploads
    # a few meshes per frame itself, and changes display settings without a new Engine.

    #: fn(selection, frame_state) -> Selection applied to every frame's selection, or None.
    selection_filter: Any = None

    def set_selection_filter(self, fn: Any) -> None:
        """Replace each frame's selection by ``fn(selection, frame_state)`` (None: as selected)."""
        self.selection_filter = fn

    def resident(self, nodes: np.ndarray) -> np.ndarray:
        """(k,) bool: whether the mesh of each node id of ``nodes`` (k,) is in the GPU cache."""
        return np.array([("node", int(i)) in self.cache for i in np.asarray(nodes)], dtype=bool)

    def upload(self, node: int) -> bool:
        """Upload the mesh of ``node`` now unless resident; True when it was uploaded."""
        self._check_alive()
        key = ("node", int(node))
        if key in self.cache:
            return False
        self.cache.get(key, lambda: self._mesh_data(key))
        return True

    def set_skirts(self, skirts: bool) -> None:
        """Turn skirts on or off; cached meshes are dropped when this changes them."""
        skirts = bool(skirts)
        if skirts != self.skirts:
            self.skirts = skirts
            self.cache.release()
            if self.provider is not None:
                self.provider.drop(lambda key: key[0] == "node")

    def set_vertical_exaggeration(self, factor: float) -> None:
        """Draw z times ``factor`` (> 0): α, the normals and near/far follow the new scale.

        The factor is part of the display scale (FrameState.scale, lens): the α bound measures
        error segments ε_T(N) · factor long on screen, so a cut for α stays within α pixels of
        the exaggerated terrain (tests/test_cartography.py renders and measures it)."""
        _check_exaggeration(factor)
        self._check_alive()
        self.scale = display_scale(self.tree.terrain) * np.array([1.0, 1.0, float(factor)])
        self.renderer.set_normal_map(*self._normal_map_data())


def _check_exaggeration(factor: Any) -> None:
    if not (isinstance(factor, int | float) and math.isfinite(factor) and factor > 0):
        raise InvalidParameterError(
            f"vertical exaggeration must be a finite number > 0, got {factor!r}."
        )


def _is_shading(pyramid: Any) -> bool:
    """True when a pyramid holds grey shading (R = G = B on every texel of its coarsest
    level, e.g. a baked hillshade): the renderer then shades the palette with it."""
    texels = np.asarray(pyramid.level(len(pyramid) - 1))
    if texels.ndim != 3 or texels.shape[-1] < 3:
        return False
    rgb = texels[..., :3]
    return bool((rgb[..., 0] == rgb[..., 1]).all() and (rgb[..., 1] == rgb[..., 2]).all())


def _read_patch(tree, i: int) -> Any:
    """T_N of node i, read without being kept by the tree when it can be (bounded memory)."""
    reader = getattr(tree, "read_patch", None)
    return reader(i) if reader is not None else tree.patch(i)


def _normals(z: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """(ny, nx, 3) unit normals of heights z (ny, nx) on ascending axes xs (nx,), ys (ny,).

    Central differences (one-sided at the border); NaN (holes) gives the up vector.
    """
    if z.shape[0] < 2 or z.shape[1] < 2:
        out = np.zeros((*z.shape, 3))
        out[..., 2] = 1.0
        return out
    dzdy, dzdx = np.gradient(z, ys, xs)
    n = np.stack([-dzdx, -dzdy, np.ones_like(z)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    bad = ~np.isfinite(n).all(axis=-1)
    n[bad] = (0.0, 0.0, 1.0)
    return n


#: Rows of the normal map computed at once: its float64 temporaries stay a few tens of MB
#: (the whole 4096² map at once took 1.4 GB).
_NORMAL_STRIP_ROWS = 256


def _normal_texels(z: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """(ny, nx, 2) uint8 normal x, y of ``_normals(z, xs, ys)``, computed strip by strip.

    Each strip takes one row of halo on either side, so central differences see the same
    neighbours as over the whole map and every texel is the same as computed at once.
    """
    ny, nx = z.shape
    out = np.empty((ny, nx, 2), dtype=np.uint8)
    for a in range(0, ny, _NORMAL_STRIP_ROWS):
        b = min(ny, a + _NORMAL_STRIP_ROWS)
        lo, hi = max(0, a - 1), min(ny, b + 1)
        nrm = _normals(z[lo:hi], xs, ys[lo:hi])[a - lo : a - lo + (b - a)]
        out[a:b] = np.rint((nrm[..., :2] * 0.5 + 0.5) * 255.0).astype(np.uint8)
    return out


def _as_pyramid(textures: Any, terrain) -> Any:
    """``textures`` as a TexturePyramid matching ``terrain`` (opened from a folder), or None."""
    from approxtree.textures.pyramid import TexturePyramid

    if textures is None or isinstance(textures, TexturePyramid):
        pyramid = textures
    elif isinstance(textures, str | os.PathLike):
        pyramid = TexturePyramid(textures)
    else:
        raise InvalidParameterError(
            "textures must be a TexturePyramid, the folder of one, or None; got a "
            f"{type(textures).__name__}."
        )
    if pyramid is not None:
        _check_pyramid_matches(pyramid, terrain)
    return pyramid


def _check_pyramid_matches(pyramid, terrain) -> None:
    """A pyramid must share the terrain's CRS and overlap its domain."""
    if pyramid.crs and terrain.crs:
        from rasterio.crs import CRS

        try:
            same = CRS.from_user_input(pyramid.crs) == CRS.from_user_input(terrain.crs)
        except Exception:
            same = True
        if not same:
            raise InvalidParameterError(
                f"The texture pyramid in {pyramid.folder} is in {pyramid.crs}, the terrain in "
                f"{terrain.crs}; bake the textures from this terrain (approxtree bake)."
            )
    lv = pyramid.levels[0]
    x0, y0 = lv.transform @ (0, 0)
    x1, y1 = lv.transform @ (lv.width, lv.height)
    d = terrain.domain
    if min(x0, x1) > d.xmax or max(x0, x1) < d.xmin or min(y0, y1) > d.ymax or max(y0, y1) < d.ymin:
        raise InvalidParameterError(
            f"The texture pyramid in {pyramid.folder} does not overlap the terrain's domain; "
            "bake the textures from this terrain (approxtree bake)."
        )
