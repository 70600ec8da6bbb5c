"""Engine: draws a tree with moderngl, offscreen (EGL) or into a host's context.

The Engine is the small facade a host program uses (DESIGN.md, "Renderer roles"):
``Engine(tree, context=...).render(camera, size, cut)``. What differs between the kinds of
tree lives in the tree's tile source (source.py: select, plan, load); the Renderer
(renderer.py) owns every GL object — programs, the normal map (normal_map.py), the palette,
the GPU cache, offscreen framebuffers — and the context when the Engine created it
(context.py). ``release()`` frees them all and stops the source's background loads. The
Engine never touches a global context: it creates a standalone EGL one or draws into the
``context`` it was given (embedding: into the framebuffer bound there).

A frame (``render``):

1. FrameState from the camera and viewport (display scale of the terrain, near/far fitted).
2. Selection (pure, no GL): the source's cut for the frame's ``Cut`` (α, γ, a triangle
   budget, or the full resolution).
3. Plan: what is drawn — the cut itself (``Paging(wait=True)``, a single image), or what is
   resident while it loads (an interactive frame); meshes grouped by texture patch.
4. Upload: missing meshes (patch + skirt, float32 relative to ``tree.origin``) and texture
   patches (RGBA8 with hardware mipmaps) into the LRU GpuCache.
5. Draw in the frame's ``Style``: clear to transparent black, per texture group one bind, one
   draw call per mesh, ``ctx.finish()`` (draw_ms).
6. Read back the RGBA image (from the engine's own framebuffer); ``world_positions(frame)``
   draws the frame again into a float buffer of world positions.

Lighting (render/style.py): per-pixel normals from the normal map, lit by the Style's sun. The
base colour is the texture patch's texel (trilinear); without a pyramid, the hypsometric
palette (textures/palettes.py) at the fragment's elevation; a pyramid of grey shading (a baked
hillshade) shades that palette. Walls along the domain's outer border are drawn in a neutral
wall colour, lit from their outward normal; the background is transparent, a sky or a colour.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.cache_keys import NODE, MeshKey, TextureKey
from approxtree.render.camera import Camera
from approxtree.render.context import check_size, create_context, max_texture_size
from approxtree.render.cut import Cut
from approxtree.render.frame import Frame, FramePlan, Groups, finish_frame
from approxtree.render.frame_state import FrameState, display_scale, overview_camera
from approxtree.render.gpu_cache import GpuCache
from approxtree.render.normal_map import normal_map
from approxtree.render.provider import DEFAULT_CPU_CACHE_BYTES, PayloadProvider
from approxtree.render.renderer import Renderer, front_to_back
from approxtree.render.source import TileSource, source_for
from approxtree.render.style import Style
from approxtree.render.traversal import Paging
from approxtree.textures.palettes import get_palette

#: Default GPU cache budget (bytes).
DEFAULT_CACHE_BYTES = 1 << 30


class Engine:
    """Renderer of one tree: an ApproximationTree or a PointQuadtree (its tile source).

    textures: a TexturePyramid (or its folder), or None to draw with the hypsometric palette
    (``set_textures``). context: a moderngl Context to draw into (embedding); None creates a
    standalone EGL one. cache_bytes: GPU cache budget. offscreen: draw into the engine's own
    framebuffer and read the image back; None means "when the engine created the context".
    skirts: hang skirts below patch borders (``set_skirts``). cpu_cache_bytes, loader_threads:
    the source's CPU cache of payloads and its background threads. exaggeration: displayed
    z = z × this (``set_vertical_exaggeration``); palette: a palette name or Palette
    (``set_palette``).
    """

    def __init__(
        self,
        tree: Any,
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
        # Bad arguments and a tree with nothing to draw fail before any GPU object exists.
        self.tree = tree
        self.source: TileSource = source_for(tree, skirts, cpu_cache_bytes, loader_threads)
        self.source.set_textures(textures)
        _check_exaggeration(exaggeration)
        get_palette(palette)
        if not (isinstance(cache_bytes, int) and cache_bytes > 0):
            raise InvalidParameterError(f"cache_bytes must be an int > 0, got {cache_bytes!r}.")
        self.owns_context = context is None
        self.offscreen = self.owns_context if offscreen is None else bool(offscreen)
        self.ctx = create_context() if context is None else context
        #: The Renderer (render/renderer.py): every GL object of the engine.
        self.renderer = Renderer(self.ctx, cache_bytes, self.owns_context)
        self.cache: GpuCache = self.renderer.cache
        self._released = False
        self.renderer.set_walls(tree.terrain.domain, tree.origin)
        self.set_vertical_exaggeration(exaggeration)
        self.set_palette(palette)
        #: The tree's version the caches hold (``follow_tree``); figures of the last tree
        #: change (gpu_dropped, gpu_kept) and of the last texture change (texture_gpu_...).
        self._tree_version = getattr(tree, "version", 0)
        self.update_figures: dict[str, int] = {}
        # Load the compiled selection kernels now, so select_ms of the first frame is honest.
        warm = self.frame_state(overview_camera(tree.bboxes[0], self.scale), (2, 2))
        self.source.select(warm, Cut())

    # -- a tree that changes (tree.update) -----------------------------------------------------

    def follow_tree(self) -> bool:
        """Take the tree's updates since the last frame (every frame calls this): meshes of
        changed nodes leave the GPU and CPU caches, the others are re-keyed to their new ids;
        the normal map and palette range follow the edited terrain. True when it changed."""
        if not self.tree_changed:
            return False
        follow = getattr(self.source, "follow", None)
        old_to_new = self.tree.changes_since(self._tree_version)
        self._tree_version = self.tree.version
        if follow is None:  # pragma: no cover - only approximation trees change
            self._rekey(lambda key: None if isinstance(key, MeshKey) else key)
        else:
            self._rekey(follow(old_to_new))
        return True

    @property
    def tree_changed(self) -> bool:
        """The tree was updated since the last frame (the next one follows it)."""
        return getattr(self.tree, "version", 0) != self._tree_version

    def replace_tree(self, tree: Any, old_to_new: np.ndarray | None) -> None:
        """Draw ``tree``, a fresh load of this engine's store after another process updated
        it (``approxtree update``), keeping the payloads of the nodes ``old_to_new`` maps:
        (n_old,) the new id of each old node whose payload is unchanged, −1 elsewhere; None:
        every node changed. render/live.py makes the map; ``follow_tree`` keeps the
        in-memory case."""
        self._check_alive()
        replace = getattr(self.source, "replace_tree", None)
        if replace is None:
            raise InvalidParameterError("Only an approximation tree's Engine takes a new tree.")
        mapping = replace(tree, old_to_new)
        self.tree = tree
        self._tree_version = getattr(tree, "version", 0)
        self._rekey(mapping)

    def _rekey(self, mapping: Any) -> None:
        """Re-key the GPU cache after a tree change; the normal map and palette follow."""
        before = len(self.cache)
        self.renderer.forget_textures(lambda key: True)
        dropped = self.cache.rekey(mapping)
        self.update_figures |= {"gpu_dropped": dropped, "gpu_kept": before - dropped}
        self.set_vertical_exaggeration(self.exaggeration)
        self.set_palette(self.palette)

    # -- settings ---------------------------------------------------------------------------

    def set_textures(self, textures: Any) -> None:
        """Texture the terrain with a TexturePyramid (or the folder holding one), or None.

        γ_N then follows each node's texture patch; the texture patches of a previous pyramid
        leave the GPU and CPU caches. The same pyramid re-baked (``textures.rebake``: a new
        build, or another process's ``approxtree update --textures``) drops only the patches
        meeting a re-baked tile of their level (render/texture_follow.py); update_figures
        counts them (``texture_gpu_dropped``, ``texture_gpu_kept``).
        """
        self._check_alive()
        stale = self.source.set_textures(textures)
        before = sum(isinstance(key, TextureKey) for key in self.cache.keys())
        self.renderer.forget_textures(stale)
        dropped = self.cache.drop(stale)
        self.update_figures |= {
            "texture_gpu_dropped": dropped,
            "texture_gpu_kept": before - dropped,
        }

    def set_palette(self, palette: Any) -> None:
        """Colour untextured terrain (and tint baked shading) with a hypsometric palette: a
        name of ``approxtree.textures.palettes.PALETTES``, a Palette, or None (the default)."""
        self._check_alive()
        palette = get_palette(palette)
        oz, (z0, z1) = self.tree.origin[2], self.tree.terrain.z_range
        lut, (p0, p1) = palette.lookup_table((z0, z1))
        self.renderer.set_palette(lut, (p0 - oz, p1 - oz))
        self.palette = palette

    def set_vertical_exaggeration(self, factor: float) -> None:
        """Draw z times ``factor`` (> 0): α, the normals and near/far follow the new scale.

        The factor is part of the display scale (FrameState.scale, lens): the α bound measures
        error segments ε_T(N) · factor long on screen, so a cut for α stays within α pixels of
        the exaggerated terrain (tests/test_cartography.py renders and measures it)."""
        _check_exaggeration(factor)
        self._check_alive()
        self.scale = display_scale(self.tree.terrain) * np.array([1.0, 1.0, float(factor)])
        side = max_texture_size(self.ctx, default=4096)
        data, uv = normal_map(self.tree.terrain, self.tree.origin, self.scale, side)
        self.renderer.set_normal_map(data, uv)
        # Untextured γ measures the normal map's (or patch's) texel, which the texture limit
        # may coarsen; normal patches are computed for the new scale.
        self.source.set_shading_side(side, self.scale)

    def set_skirts(self, skirts: bool) -> None:
        """Turn skirts on or off; cached meshes are dropped when this changes them."""
        if self.source.set_skirts(skirts):
            self.cache.release()

    @property
    def shade_texture(self) -> bool:
        """The textures are grey shading (a baked hillshade) that shades the palette."""
        binding = self.source.binding
        return binding is not None and binding.shading

    @property
    def exaggeration(self) -> float:
        """The vertical exaggeration: displayed z = z × this factor (see ``display_scale``)."""
        return float(self.scale[2] / display_scale(self.tree.terrain)[2])

    @property
    def texels(self) -> np.ndarray:
        """(n, 2) texel sizes of the nodes (γ): their texture patches', else the normal map's."""
        return self.source.texels

    @property
    def provider(self) -> PayloadProvider | None:
        """The source's PayloadProvider (CPU cache, background loads), or None."""
        return self.source.provider

    @property
    def normal_map(self) -> Any:
        """The normal map texture (owned by the renderer)."""
        return self.renderer.normal_map

    def texture_patch(self, node: int) -> Any:
        """The TexturePatch ``node`` is drawn with when it textures itself (with a pyramid)."""
        binding = self.source.binding
        if binding is None:
            raise InvalidParameterError("This Engine draws no texture pyramid (set_textures).")
        return binding.patch(MeshKey(NODE, int(node)))

    # -- frames -----------------------------------------------------------------------------

    def frame_state(self, camera: Camera, size: tuple[int, int]) -> FrameState:
        """The FrameState of ``camera`` over ``size`` for this tree (validated)."""
        size = check_size(self.ctx, size)
        return FrameState.from_camera(
            camera, size, self.tree.bboxes[0], self.tree.origin, self.scale
        )

    def render(
        self,
        camera: Camera,
        size: tuple[int, int] = (1280, 720),
        cut: Cut = Cut(),
        *,
        style: Style = Style(),
        paging: Paging = Paging(),
        target: Any = None,
    ) -> Frame:
        """Draw one frame (module docstring, steps 1-6) of ``camera`` over ``size`` (w, h) px.

        cut: how the cut is chosen; style: what it looks like; paging: whether the frame
        waits for the store. target: the framebuffer to draw into; None: the engine's own
        one, read back into Frame.image, or, embedded (context=), the one bound there.
        """
        self._check_alive()
        _check_kinds(cut=(cut, Cut), style=(style, Style), paging=(paging, Paging))
        self.follow_tree()
        fs = self.frame_state(camera, size)
        uploads = self.cache.uploads
        # Lit textured frames may light with normal patches (their γ and groups follow).
        self.source.set_lighting(style.lit(self.source.binding is not None))
        t0 = time.perf_counter()
        wanted = self.source.select(fs, cut)
        t1 = time.perf_counter()
        plan = self.source.plan(wanted, fs, cut, paging, self.renderer)
        plan.groups = self._front_to_back(plan.groups, fs)
        resident = self._upload(plan.groups)
        t2 = time.perf_counter()
        own = target is None and self.offscreen
        if target is None:
            target = self.renderer.target("color", *fs.viewport) if own else self.ctx.fbo
        draw_ms, triangles, switches = self._draw(target, fs, plan.groups, resident, style)
        image = self.renderer.read_image(target, fs.viewport) if own else None
        figures = {
            "triangles": triangles,
            "select_ms": (t1 - t0) * 1e3,
            "upload_ms": (t2 - t1) * 1e3,
            # Meshes and texture patches put on the GPU this frame, whichever path did it.
            "gpu_uploads": self.cache.uploads - uploads,
            "draw_ms": draw_ms,
            "gpu_bytes": self.cache.nbytes,
            "texture_switches": switches,
            "cpu_bytes": self.provider.nbytes if self.provider is not None else 0,
        }
        return finish_frame(plan, fs, image, figures, style.background.opaque)

    def world_positions(self, frame: Frame) -> np.ndarray:
        """(h, w, 4) float64 world x, y, z and a flag (1 surface, 0 skirt, −1 nothing: x, y, z
        NaN) of the surface ``frame`` drew, row 0 at the top; also kept as frame.positions.
        An extra pass of the frame's meshes into a float buffer."""
        self._check_alive()
        fs = frame.frame_state
        groups: Groups = [(None, list(frame.meshes))]
        fbo = self.renderer.target("position", *fs.viewport)
        resident = self._upload(groups)
        self.renderer.draw(fbo, fs, groups, resident, "position", Style(), False, self.source.load)
        frame.positions = self.renderer.read_positions(fbo, fs.viewport, self.tree.origin)
        return frame.positions

    # -- host hooks: what is on the GPU, and uploads ahead of a frame -----------------------

    def resident(self, nodes: np.ndarray) -> np.ndarray:
        """(k,) bool: whether a mesh of each node id of ``nodes`` (k,) is in the GPU cache."""
        self.follow_tree()
        on_gpu = {key.node for key in self.cache.keys() if isinstance(key, MeshKey)}
        return np.array([int(i) in on_gpu for i in np.asarray(nodes)], dtype=bool)

    def upload(self, node: int) -> bool:
        """Upload the mesh of ``node`` now unless resident; True when it was uploaded (never
        for a tree whose meshes depend on the view: a frame uploads its own)."""
        self._check_alive()
        self.follow_tree()
        key = MeshKey(NODE, int(node))
        if self.source.view_dependent or key in self.cache:
            return False
        self.renderer.mesh(key, self.source.load)
        return True

    # -- housekeeping -----------------------------------------------------------------------

    def release(self) -> None:
        """Free every GPU object of the engine (and its context, if it created it), stop the
        source's background loads and empty its CPU cache."""
        if self._released:
            return
        self._released = True
        self.source.release()
        self.renderer.release()

    @property
    def released(self) -> bool:
        return self._released

    def __enter__(self) -> Engine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def _check_alive(self) -> None:
        if self._released:
            raise InvalidParameterError("This Engine was released; create a new one.")

    def _front_to_back(self, groups: Groups, fs: FrameState) -> Groups:
        """``groups`` nearest first (renderer.front_to_back) by their nodes' box centres, when
        every key draws a tree node (else as planned); the same order whatever is cached."""
        keys = [key for _, ks in groups for key in ks]
        if not keys or any(k.kind != NODE or k.shape for k in keys):
            return groups
        boxes = np.asarray(self.tree.bboxes, dtype=np.float64)[[k.item for k in keys]]
        centres = 0.5 * (boxes[:, :3] + boxes[:, 3:]) * fs.scale
        return front_to_back(groups, centres, np.asarray(fs.eye, dtype=np.float64) * fs.scale)

    def _upload(self, groups: Groups) -> Any:
        return self.renderer.upload(groups, self.source.load)

    def _draw(
        self, target: Any, fs: FrameState, groups: Groups, resident: Any, style: Style
    ) -> tuple[float, int, int]:
        """Clear ``target`` and draw the groups in ``style`` (Renderer.draw); returns (ms incl.
        ctx.finish(), triangles, texture binds)."""
        binding = self.source.binding
        program = "terrain" if binding is None else "textured"
        # Untextured: per-group normal patches where the source has them; textured: the
        # texture patches', and the normal patches' of lit groups (LitKey).
        shading_uv = self.source.shading_uv
        uv = shading_uv if binding is None else binding.uv
        if binding is not None and shading_uv is not None:
            uv = _either_uv(binding.uv, shading_uv)
        lit, shade = style.lit(binding is not None), binding is not None and binding.shading
        args = (program, style, lit, self.source.load, uv, shade)
        return self.renderer.draw(target, fs, groups, resident, *args)


def _either_uv(texture_uv: Callable, normal_uv: Callable) -> Callable:
    """The uv of a texture patch (TextureKey) or of a normal patch (any other key)."""
    return lambda key: texture_uv(key) if isinstance(key, TextureKey) else normal_uv(key)


def _check_exaggeration(factor: Any) -> None:
    if not (isinstance(factor, int | float) and math.isfinite(factor) and factor > 0):
        raise InvalidParameterError(
            f"vertical exaggeration must be a finite number > 0, got {factor!r}."
        )


def _check_kinds(**given: tuple[Any, type]) -> None:
    """InvalidParameterError naming the first argument that is not of its type."""
    for name, (value, kind) in given.items():
        if not isinstance(value, kind):
            raise InvalidParameterError(
                f"{name} must be a {kind.__name__} ({kind.__module__}), got {value!r}."
            )


#: Also importable from here (their home is render/frame.py).
__all__ = ["DEFAULT_CACHE_BYTES", "Engine", "Frame", "FramePlan"]
