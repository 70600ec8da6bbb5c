"""Renderer: the GL objects of an engine — programs, GPU cache, normal map, framebuffers.

The renderer is the third of the renderer's three roles (DESIGN.md, "Renderer roles"). It owns
every GL object the Engine draws with, uploads payloads into the GpuCache (bounded in bytes,
least recently used out) within a per-frame budget, draws a frame's groups of meshes, reads
images back, and frees everything in ``release()`` — nothing relies on the garbage collector.
It neither selects nor loads: the traversal decides what to draw, the tile source supplies the
payloads (``load`` callbacks, through the provider's CPU cache).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from approxtree.glsl import create_program
from approxtree.render.cache_keys import LitKey
from approxtree.render.frame import Groups
from approxtree.render.frame_state import FrameState
from approxtree.render.gpu_cache import (
    GpuCache,
    GpuMesh,
    GpuTexture,
    mip_chain,
    staged_uploads_available,
)
from approxtree.render.provider import Payload
from approxtree.render.style import WALL_COLOUR, Background, Style

#: moderngl.TRIANGLES (moderngl is imported where GL is used).
_TRIANGLES = 0x0004

#: load(key) -> the Payload of a mesh or texture key (a tile source's ``load``).
Load = Callable[[Any], Payload]


#: Frames a texture patch being prepared or written is kept without being wanted.
STAGED_KEEP_STEPS = 30

#: Frames a wanted texture patch may stand in, once its texels are loaded, before a frame
#: finishes it whatever the cost (waits for its mip chain, writes it whole): the bound on how
#: long a frame takes to settle after a camera cut.
TEXTURE_LATE_STEPS = 2

#: Texels (bytes) of a texture patch uploaded whole in the frame its texels arrive (1024²
#: RGBA: its mip chain and upload take a few ms); larger ones are written over frames.
TEXTURE_AT_ONCE_BYTES = 4 << 20


class Renderer:
    """GL state on ``ctx``: programs, a GpuCache of ``cache_bytes``, the normal map, targets.

    owns_context: release ``ctx`` too in ``release()``.
    """

    def __init__(self, ctx: Any, cache_bytes: int, owns_context: bool) -> None:
        self.ctx = ctx
        self.owns_context = owns_context
        self.programs = {
            "terrain": create_program(ctx, "terrain"),
            "position": create_program(ctx, "position"),
            "textured": create_program(ctx, "textured"),
            # Colours as they are (no light, no shading texture): no normal map fetched.
            "textured_decal": create_program(ctx, "textured", defines=("DECAL",)),
            "sky": create_program(ctx, "sky"),
        }
        # The background pass: one triangle covering the viewport (NDC).
        corners = np.array([-1, -1, 0, 3, -1, 0, -1, 3, 0], dtype="f4")
        self._sky_vbo = ctx.buffer(corners.tobytes())
        self._sky_vao = ctx.vertex_array(
            self.programs["sky"], [(self._sky_vbo, "3f", "in_position")]
        )
        self.palette: Any = None
        self.palette_z = (0.0, 1.0)
        #: The terrain's domain in local coordinates (xmin, ymin, xmax, ymax) and the distance
        #: within which a skirt fragment counts as a side wall on its border.
        self.domain = (0.0, 0.0, 0.0, 0.0)
        self.domain_tol = 0.0
        self.cache = GpuCache(ctx, cache_bytes)
        # Texture patches of interactive frames: mip chains made on a worker thread, then
        # written over frames (GpuCache.stage_texture); the step each key was last wanted in.
        self._mips: ThreadPoolExecutor | None = None
        self._preparing: dict[Hashable, Future] = {}
        self._wanted_at: dict[Hashable, int] = {}
        # The step since which each key is wanted in every step (with its texels loaded).
        self._wanted_since: dict[Hashable, int] = {}
        #: Texture patches of at most these bytes are uploaded whole when their texels arrive.
        self.at_once_bytes = TEXTURE_AT_ONCE_BYTES
        self._step = 0
        self.targets: dict[tuple[str, int, int], Any] = {}
        self.normal_map: Any = None
        self.normal_uv = np.zeros(4)
        self.released = False

    # -- uploads ------------------------------------------------------------------------------

    def set_normal_map(self, data: np.ndarray, uv: np.ndarray) -> None:
        """Replace the normal map by ``data`` (ny, nx, 2) uint8; uv (4,): local xy → uv."""
        if self.normal_map is not None:
            self.normal_map.release()
        ny, nx = data.shape[:2]
        tex = self.ctx.texture((nx, ny), 2, np.ascontiguousarray(data).tobytes(), dtype="f1")
        tex.repeat_x = False
        tex.repeat_y = False
        self.normal_map, self.normal_uv = tex, np.asarray(uv, dtype=np.float64)

    def set_walls(self, domain: Any, origin: np.ndarray) -> None:
        """Draw the skirts on the border of ``domain`` (a Rect, world units) as side walls
        (``domain`` in local coordinates, relative to ``origin`` (3,))."""
        d, (ox, oy, _) = domain, origin
        self.domain = (d.xmin - ox, d.ymin - oy, d.xmax - ox, d.ymax - oy)
        self.domain_tol = 1e-5 * max(d.xmax - d.xmin, d.ymax - d.ymin, 1e-9)

    def set_palette(self, lut: np.ndarray, z_local: tuple[float, float]) -> None:
        """Replace the hypsometric palette by ``lut`` (n, 3) uint8, whose first and last
        texel centres sit at local heights ``z_local``."""
        if self.palette is not None:
            self.palette.release()
        lut = np.ascontiguousarray(lut, dtype=np.uint8)
        tex = self.ctx.texture((len(lut), 1), 3, lut.tobytes(), dtype="f1")
        tex.repeat_x = False
        tex.repeat_y = False
        self.palette, self.palette_z = tex, (float(z_local[0]), float(z_local[1]))

    def mesh(self, key: Hashable, load: Load) -> GpuMesh:
        """The GPU mesh of ``key``, uploaded from ``load(key)`` (a mesh Payload) on a miss."""
        return self.cache.get(key, lambda: _mesh_arrays(load(key)))

    def texture(self, key: Hashable, load: Load) -> GpuTexture:
        """The GPU texture of ``key``, uploaded from ``load(key)`` (a texture Payload: (h, w,
        4) uint8 texels) on a miss."""
        return self.cache.get_texture(key, lambda: load(key).texels)  # type: ignore[arg-type,return-value]

    def _group_texture(self, key: Hashable, load: Load) -> Any:
        """A group's texture, or (texture, normal patch) of a LitKey."""
        if isinstance(key, LitKey):
            return self.texture(key.texture, load), self.texture(key.normal, load)
        return self.texture(key, load)

    def texture_drawable(self, key: Hashable, texels: Callable[[], np.ndarray | None]) -> bool:
        """Whether the texture of ``key`` can be drawn now without a hitch: complete on the
        GPU. Otherwise, once ``texels()`` gives its (h, w, 4) uint8 texels (None: not loaded
        yet), its mip chain is made on a worker thread and ``step_textures`` writes it over
        the next frames; it becomes drawable when complete (a stand-in meanwhile)."""
        if key in self.cache:
            return True
        if not staged_uploads_available():
            # No GL library for the levels: the frame uploads it whole once loaded.
            return texels() is not None
        self._wanted_at[key] = self._step
        self._wanted_since.setdefault(key, self._step)
        if key in self._preparing or self.cache.is_staged(key):
            return False
        data = texels()
        if data is None:
            # Still loading: the frames it stands in for count from its texels' arrival.
            self._wanted_since[key] = self._step
        elif data.nbytes <= self.at_once_bytes:
            # Small enough to cost no hitch: drawable in this frame.
            self.cache.get_texture(key, lambda: data)
            return True
        else:
            if self._mips is None:
                self._mips = ThreadPoolExecutor(1, thread_name_prefix="approxtree-mips")
            self._preparing[key] = self._mips.submit(mip_chain, np.ascontiguousarray(data))
        return False

    def step_textures(self, budget_ms: float) -> int:
        """One frame's share of the texture work: stage the mip chains made, write staged
        textures for about ``budget_ms`` (those this frame wants first); a texture not wanted
        for STAGED_KEEP_STEPS steps is dropped (the camera left it; one wanted again sooner
        is not made twice). Returns how many became drawable."""
        now, self._step = self._step, self._step + 1
        for key in [k for k, at in self._wanted_at.items() if now - at > STAGED_KEEP_STEPS]:
            del self._wanted_at[key]
            future = self._preparing.pop(key, None)
            if future is not None:
                future.cancel()
        # A key left out of a step starts counting again when wanted again.
        for key in [k for k in self._wanted_since if self._wanted_at.get(k) != now]:
            del self._wanted_since[key]
        self.cache.unstage(lambda key: key not in self._wanted_at)
        # The latest patch (wanted for TEXTURE_LATE_STEPS steps or more with its texels
        # loaded): its mip chain waited for and staged now, written whole below. One a frame,
        # so a cut to a view of many large patches costs a frame of one patch at a time.
        overdue = sorted(
            (since, i, k)
            for i, (k, since) in enumerate(self._wanted_since.items())
            if now - since >= TEXTURE_LATE_STEPS and k not in self.cache
        )
        late = [k for _, _, k in overdue[:1]]
        for key in late:
            future = self._preparing.pop(key, None)
            if future is not None and not future.cancelled():
                self.cache.stage_texture(key, future.result())
        # GL storage (a 4096² patch: 20-45 ms on llvmpipe) for one patch a frame, one this
        # frame wants; a chain made for a view already left waits on the CPU until wanted.
        ready = [k for k, f in self._preparing.items() if f.done() and self._wanted_at[k] == now]
        for key in ready[:1]:
            levels = self._preparing.pop(key).result()
            if key not in self.cache:
                self.cache.stage_texture(key, levels)
        staged = self.cache.staged()
        if not staged:
            return 0
        late = [k for k in late if k in staged]
        completed = self.cache.upload_staged(float("inf"), order=late) if late else 0
        staged = self.cache.staged()
        first = [k for k in staged if self._wanted_at.get(k) == now]
        rest = [k for k in staged if self._wanted_at.get(k) != now]
        return completed + self.cache.upload_staged(budget_ms, order=first + rest)

    def wait_textures(self) -> None:
        """Wait until the mip chains being made are done (scripted replays: the same frames
        on any machine); ``step_textures`` stages them."""
        for future in list(self._preparing.values()):
            if not future.cancelled():
                future.exception()

    def forget_textures(self, predicate: Callable[[Hashable], bool]) -> None:
        """Abandon the texture patches being prepared or written whose key satisfies
        ``predicate`` (their texels are stale: a re-bake, a new pyramid, a tree change)."""
        for key in [k for k in self._preparing if predicate(k)]:
            self._preparing.pop(key).cancel()
        for key in [k for k in self._wanted_at if predicate(k)]:
            del self._wanted_at[key]
            self._wanted_since.pop(key, None)
        self.cache.unstage(predicate)

    def upload(self, groups: Sequence[tuple[Any, Sequence[Hashable]]], load: Load) -> Any:
        """Upload what a frame draws, the groups [(texture key or None, mesh keys)], from
        ``load``; returns the resident (texture, meshes) per group, or None when the frame
        exceeded the cache budget (entries were evicted: the draw fetches them again)."""
        evictions = self.cache.evictions
        resident = [
            (
                None if tex is None else self._group_texture(tex, load),
                [self.mesh(k, load) for k in keys],
            )
            for tex, keys in groups
        ]
        return resident if self.cache.evictions == evictions else None

    def upload_within(
        self,
        keys: Sequence[Hashable],
        load: Load,
        max_uploads: int | None = None,
        budget_ms: float | None = None,
    ) -> int:
        """Upload the meshes of ``keys`` (in order) missing from the cache, stopping after
        ``max_uploads`` uploads or ``budget_ms`` milliseconds (after the first); returns how
        many were uploaded."""
        t0 = time.perf_counter()
        uploads = 0
        for key in keys:
            if max_uploads is not None and uploads >= max_uploads:
                break
            if budget_ms is not None and uploads and (time.perf_counter() - t0) * 1e3 >= budget_ms:
                break
            if key in self.cache:
                continue
            self.mesh(key, load)
            uploads += 1
        return uploads

    # -- framebuffers -------------------------------------------------------------------------

    def target(self, kind: str, w: int, h: int) -> Any:
        """The offscreen framebuffer of ``kind`` ("color" RGBA8, "position" RGBA32F)."""
        key = (kind, w, h)
        fbo = self.targets.get(key)
        if fbo is None:
            # One size at a time per kind: drop buffers of a previous size.
            for old in [k for k in self.targets if k[0] == kind]:
                _release_fbo(self.targets.pop(old))
            dtype = "f4" if kind == "position" else "f1"
            color = self.ctx.renderbuffer((w, h), 4, dtype=dtype)
            depth = self.ctx.depth_renderbuffer((w, h))
            fbo = self.ctx.framebuffer(color_attachments=[color], depth_attachment=depth)
            self.targets[key] = fbo
        return fbo

    def read_image(self, target: Any, size: tuple[int, int]) -> np.ndarray:
        """(h, w, 4) uint8 RGBA of ``target``'s first ``size`` (w, h) pixels, row 0 at the top."""
        w, h = size
        raw = target.read(viewport=(0, 0, w, h), components=4, alignment=1)
        return np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 4)[::-1].copy()

    def read_positions(self, target: Any, size: tuple[int, int], origin: np.ndarray) -> np.ndarray:
        """(h, w, 4) float64 world x, y, z and flag drawn by the "position" program into
        ``target`` (local coordinates + ``origin``; x, y, z NaN where nothing was drawn)."""
        w, h = size
        raw = target.read(viewport=(0, 0, w, h), components=4, dtype="f4", alignment=1)
        local = np.frombuffer(raw, dtype=np.float32).reshape(h, w, 4)[::-1].astype(np.float64)
        out = local.copy()
        out[..., :3] += origin
        out[local[..., 3] < -0.5, :3] = np.nan
        return out

    # -- drawing ------------------------------------------------------------------------------

    def draw(
        self,
        target: Any,
        fs: FrameState,
        groups: Sequence[tuple[Any, Sequence[Hashable]]],
        resident: list[tuple[Any, list[Any]]] | None,
        program: str,
        style: Style,
        lit: bool,
        load: Load,
        texture_uv: Callable[[Any], tuple[float, float, float, float]] | None = None,
        shade_texture: bool = False,
    ) -> tuple[float, int, int]:
        """Clear ``target`` and draw the groups [(texture key or None, mesh keys)].

        resident: per group (texture, meshes) already uploaded, or None to fetch each entry
        from ``load`` while drawing (a frame larger than the cache budget). program:
        "terrain", "textured" or "position" (world positions into a float target). style:
        wireframe, the sun (the light, a unit vector in display coordinates) and the
        background (drawn behind the terrain, its colour channels only: alpha stays 0 there).
        lit: the light modulates the colour. texture_uv(texture key): its uv transform
        ("textured"; with "terrain", the group's normal patch, None its key for the normal
        map; a textured group keyed by a LitKey: its texture patch, and its normal patch lights
        it instead of the normal map). shade_texture: the textures are grey shading that
        shades the palette.
        Returns (ms incl. ctx.finish(), triangles, texture binds).
        """
        import moderngl

        ctx = self.ctx
        decal = program == "textured" and not lit and not shade_texture
        prog = self.programs["textured_decal" if decal else program]
        w, h = fs.viewport
        wireframe, background = style.wireframe, style.background
        prog["u_mvp"].write(fs.local_to_clip.T.astype("f4").tobytes())
        if program in ("terrain", "textured"):
            # A variant compiles out the uniforms it does not use: set those it has.
            uniforms = {
                "u_palette_z": self.palette_z,
                "u_light": tuple(float(v) for v in style.sun.direction),
                "u_wall": WALL_COLOUR,
                "u_domain": self.domain,
                "u_domain_tol": self.domain_tol,
                "u_palette": 2,
                "u_normal_uv": tuple(self.normal_uv),
                "u_line": 1.0 if wireframe else 0.0,
                "u_lighting": 1.0 if lit else 0.0,
                "u_normals": 0,
            }
            if program == "textured":
                uniforms |= {"u_texture": 1, "u_shade_texture": 1.0 if shade_texture else 0.0}
            for name, value in uniforms.items():
                if name in prog:
                    prog[name].value = value
            self.palette.use(location=2)
            self.normal_map.use(location=0)
        triangles = 0
        switches = 0
        patched = False  # a normal patch is bound in place of the normal map
        t0 = time.perf_counter()
        with ctx.scope(framebuffer=target, enable_only=moderngl.DEPTH_TEST):
            ctx.viewport = (0, 0, w, h)
            ctx.depth_func = "<"
            clear = (-1.0, -1.0, -1.0, -1.0) if program == "position" else (0.0, 0.0, 0.0, 0.0)
            target.clear(*clear, depth=1.0, viewport=(0, 0, w, h))
            ctx.wireframe = wireframe
            try:
                for g, (tex_key, keys) in enumerate(groups):
                    if tex_key is not None and program == "textured":
                        # Pinned while its meshes are fetched, so it outlives their uploads.
                        pair = tex_key if isinstance(tex_key, LitKey) else None
                        self.cache.pinned = set(pair) if pair else {tex_key}
                        tex = resident[g][0] if resident else self._group_texture(tex_key, load)
                        if pair is not None:
                            # A lit group's normal patch replaces the normal map.
                            tex, normal = tex
                            normal.texture.use(location=0)
                            prog["u_normal_uv"].value = texture_uv(pair.normal)  # type: ignore[misc]
                            tex_key, patched = pair.texture, True
                        elif patched:
                            self.normal_map.use(location=0)
                            prog["u_normal_uv"].value = tuple(self.normal_uv)
                            patched = False
                        tex.texture.use(location=1)
                        prog["u_tex_uv"].value = texture_uv(tex_key)  # type: ignore[misc]
                        switches += 1
                    elif program == "terrain" and texture_uv is not None:
                        # The group's normal patch, or the normal map (key None).
                        self.cache.pinned = {tex_key}
                        if tex_key is None:
                            self.normal_map.use(location=0)
                            prog["u_normal_uv"].value = tuple(self.normal_uv)
                        else:
                            tex = resident[g][0] if resident else self.texture(tex_key, load)
                            tex.texture.use(location=0)
                            prog["u_normal_uv"].value = texture_uv(tex_key)
                        switches += 1
                    meshes = resident[g][1] if resident else (self.mesh(k, load) for k in keys)
                    for mesh in meshes:
                        if mesh.triangles == 0:
                            continue
                        mesh.vao(ctx, prog).render(moderngl.TRIANGLES)
                        triangles += mesh.triangles
            finally:
                ctx.wireframe = False
                self.cache.pinned = set()
            if background.opaque and program != "position":
                self._draw_background(target, background)
            ctx.finish()
        return (time.perf_counter() - t0) * 1e3, triangles, switches

    def _draw_background(self, target: Any, background: Background) -> None:
        """The background where no terrain was drawn (depth still 1), its alpha left 0: the
        sky writes alpha 0 itself, so no colour mask makes llvmpipe read back every pixel."""
        sky = self.programs["sky"]
        top, bottom = background.colours
        sky["u_top"].value = top
        sky["u_bottom"].value = bottom
        self.ctx.depth_func = "<="
        try:
            self._sky_vao.render(_TRIANGLES)
        finally:
            self.ctx.depth_func = "<"

    # -- housekeeping -------------------------------------------------------------------------

    def release(self) -> None:
        """Free every GL object now (and the context, when owned); idempotent."""
        if self.released:
            return
        self.released = True
        if self._mips is not None:
            self._mips.shutdown(wait=True, cancel_futures=True)
        self._preparing.clear()
        self.cache.release()
        for fbo in self.targets.values():
            _release_fbo(fbo)
        self.targets.clear()
        if self.normal_map is not None:
            self.normal_map.release()
            self.normal_map = None
        if self.palette is not None:
            self.palette.release()
            self.palette = None
        self._sky_vao.release()
        self._sky_vbo.release()
        for prog in self.programs.values():
            prog.release()
        if self.owns_context:
            self.ctx.release()


def front_to_back(groups: Groups, centres: np.ndarray, eye: np.ndarray) -> Groups:
    """``groups`` drawn nearest first: each group's keys by the distance of their ``centres``
    to ``eye`` (the keys in group order, (k, 3) display units), the groups by their nearest
    key. Depth is tested before shading (llvmpipe and GPUs), so what is drawn first hides
    the fragments behind it from the shader. Ties keep the planned order."""
    d = np.einsum("ij,ij->i", centres - eye, centres - eye)
    order, start = [], 0
    for g, (tex, keys) in enumerate(groups):
        mine = d[start : start + len(keys)]
        rank = np.argsort(mine, kind="stable")
        nearest = float(mine[rank[0]]) if len(keys) else np.inf
        order.append((nearest, g, (tex, [keys[i] for i in rank])))
        start += len(keys)
    order.sort(key=lambda o: (o[0], o[1]))
    return [o[2] for o in order]


def _release_fbo(fbo: Any) -> None:
    for att in (*fbo.color_attachments, fbo.depth_attachment):
        if att is not None:
            att.release()
    fbo.release()


def _mesh_arrays(payload: Payload) -> tuple[np.ndarray, np.ndarray]:
    """(vertex data (n, 4) float32, triangles (m, 3) uint32) of a mesh payload."""
    return payload.vertices, payload.triangles  # type: ignore[return-value]
