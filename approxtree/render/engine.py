"""Engine: draws an approximation tree with moderngl, offscreen (EGL) or into a host's context.

The Engine owns every GPU object it makes — programs, the normal map, the patch cache, its
offscreen framebuffers and, when it created it, the context — and frees them in
``release()``. It never touches a global context: either it creates a standalone EGL context
or it draws into the ``context`` it was given (embedding: into the framebuffer bound there).

A frame:

1. FrameState from the camera and viewport (display scale of the terrain, near/far fitted).
2. Selection (pure, no GL): the cut of the tree for alpha and gamma; ``full_resolution`` draws
   the unsimplified terrain instead (the grid in chunks of CHUNK lines, frustum-culled).
3. Upload: missing meshes (patch + skirt, float32 relative to ``tree.origin``) into the LRU
   GpuCache.
4. Draw: clear to transparent black, one draw call per mesh, ``ctx.finish()`` (draw_ms).
5. Read back the RGBA image (offscreen) and, on request, a world-position buffer.

Shading until texture pyramids land: per-pixel normals from a normal map computed once from
the height field (central differences in display units, at most NORMAL_MAP_MAX texels per
side) and a hypsometric colour ramp by height.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from approxtree.errors import ContextUnavailableError, InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.render.camera import Camera
from approxtree.render.frame_state import (
    FrameState,
    check_viewport,
    display_scale,
    overview_camera,
)
from approxtree.render.frustum import boxes_in_frustum
from approxtree.render.gpu_cache import GpuCache
from approxtree.render.selector import Selection, check_thresholds, eye_below_ground, select
from approxtree.render.shaders import create_program
from approxtree.render.skirts import add_skirts, skirt_base, skirt_depths
from approxtree.render.visual_error import texel_sizes

#: Default GPU cache budget (bytes).
DEFAULT_CACHE_BYTES = 1 << 30
#: Largest side of the normal map (texels), further limited by GL_MAX_TEXTURE_SIZE.
NORMAL_MAP_MAX = 4096
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
)

_INSTALL_HINT = (
    "Install the EGL and Mesa OpenGL drivers (Debian/Ubuntu: apt-get install -y libegl1 "
    "libgl1-mesa-dri; Fedora: dnf install mesa-libEGL mesa-dri-drivers), or pass a context "
    "of your own with Engine(tree, context=ctx)."
)


def create_context() -> Any:
    """A standalone headless OpenGL 3.3+ context through EGL, or ContextUnavailableError."""
    try:
        import moderngl

        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as exc:
        raise ContextUnavailableError(
            f"No OpenGL context could be created through EGL ({exc}). {_INSTALL_HINT}"
        ) from exc
    if ctx.version_code < 330:
        version = ctx.version_code
        ctx.release()
        raise ContextUnavailableError(
            f"OpenGL 3.3 or newer is needed, the EGL context offers {version}. {_INSTALL_HINT}"
        )
    return ctx


@dataclass
class Frame:
    """One rendered frame.

    image: (h, w, 4) uint8 RGBA, row 0 at the top, alpha 0 where no terrain is drawn (None
    when drawn into a host's framebuffer without read-back). stats: dict of STAT_KEYS.
    positions: (h, w, 4) float64 world x, y, z and a flag (1 surface, 0 skirt, −1 nothing,
    x, y, z NaN there), row 0 at the top, when asked for.
    """

    image: np.ndarray | None
    stats: dict[str, Any]
    selection: Selection
    frame_state: FrameState
    positions: np.ndarray | None = None


class Engine:
    """Renderer of one ApproximationTree.

    tree: the ApproximationTree. textures: texture pyramid (not supported yet: None).
    context: a moderngl Context to draw into (embedding); None creates a standalone EGL one.
    cache_bytes: GPU cache budget.
    offscreen: draw into the engine's own framebuffer and read the image back; None means
    "when the engine created the context" (an embedded engine draws into the host's
    framebuffer bound in ``context``).
    skirts: hang skirts below patch borders (off only to show what they close).
    """

    def __init__(
        self,
        tree,
        textures: Any = None,
        context: Any = None,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
        offscreen: bool | None = None,
        skirts: bool = True,
    ) -> None:
        if textures is not None:
            raise InvalidParameterError(
                "Texture pyramids are not supported by this version yet; pass textures=None."
            )
        if not (isinstance(cache_bytes, int) and cache_bytes > 0):
            raise InvalidParameterError(f"cache_bytes must be an int > 0, got {cache_bytes!r}.")
        self.tree = tree
        self.owns_context = context is None
        self.offscreen = self.owns_context if offscreen is None else bool(offscreen)
        self.skirts = bool(skirts)
        self.ctx = create_context() if context is None else context
        self.scale = display_scale(tree.terrain)
        # Per-node figures used every frame, computed once.
        self.texels = texel_sizes(tree)
        self.skirt_depths = skirt_depths(tree.errors, tree.terrain.z_range)
        self.skirt_base = skirt_base(tree.errors, tree.terrain.z_range)
        d = tree.terrain.domain
        self._domain = (d.xmin, d.ymin, d.xmax, d.ymax)
        self._full_chunks: list[tuple[Any, np.ndarray]] | None = None
        self._targets: dict[tuple[str, int, int], Any] = {}
        self._released = False
        self.programs = {
            "terrain": create_program(self.ctx, "terrain"),
            "position": create_program(self.ctx, "position"),
        }
        self.cache = GpuCache(self.ctx, cache_bytes)
        self.normal_map, self._normal_uv = self._make_normal_map()
        # Load the compiled selection kernels now, so select_ms of the first frame is honest.
        warm = overview_camera(tree.bboxes[0], self.scale)
        select(tree, self.frame_state(warm, (2, 2)), 1.0, 2.0, self.texels)

    # -- public -----------------------------------------------------------------------------

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
        alpha: float = 1.0,
        gamma: float = 2.0,
        wireframe: bool = False,
        full_resolution: bool = False,
        target: Any = None,
        read_image: bool | None = None,
        world_positions: bool = False,
        max_triangles: int | None = None,
    ) -> Frame:
        """Draw one frame; see the module docstring for the steps.

        camera: Camera; size: (w, h) pixels; alpha: α threshold (px, > 0); gamma: γ threshold
        (px², > 0, inf ignores it); wireframe: draw triangle edges instead of filled
        triangles; full_resolution: draw the unsimplified terrain (reference).
        target: framebuffer to draw into; None draws into the engine's own offscreen
        framebuffer, or, for an engine made with context=, into the framebuffer bound there.
        read_image: read the image back (default: only from the engine's own framebuffer).
        world_positions: also fill Frame.positions (an extra pass into a float buffer).
        max_triangles: triangle budget instead of the alpha threshold: draw the cut of
        smallest largest α with at most this many triangles, skirts included (``budget``);
        stats["max_alpha"] is the α reached.
        """
        self._check_alive()
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
            selection = select(self.tree, fs, alpha, gamma, self.texels)
        select_ms = (time.perf_counter() - t0) * 1e3
        # 3. Upload what the cache lacks; a frame larger than the budget is drawn in parts.
        t0 = time.perf_counter()
        keys = [("full", int(i)) if full_resolution else ("node", int(i)) for i in selection.nodes]
        batches = self._batches(keys)
        upload_ms = (time.perf_counter() - t0) * 1e3
        # 4. Draw.
        own = target is None and self.offscreen
        if target is None:
            target = self._target("color", w, h) if self.offscreen else self.ctx.fbo
        if read_image is None:
            read_image = own
        draw_ms, triangles = self._draw(target, fs, batches, keys, wireframe, "terrain")
        image = None
        if read_image:
            raw = target.read(viewport=(0, 0, w, h), components=4, alignment=1)
            image = np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 4)[::-1].copy()
        positions = None
        if world_positions:
            positions = self._positions(fs, batches, keys)
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
        }
        return Frame(image, stats, selection, fs, positions)

    def _budget_selection(self, fs: FrameState, max_triangles: int) -> Selection:
        """Selection under a triangle budget (per-node counts computed on first use)."""
        from approxtree.render.budget import node_triangles, select_budget

        if getattr(self, "_node_triangles", None) is None:
            self._node_triangles = node_triangles(self.tree, self.skirts)
        return select_budget(self.tree, fs, max_triangles, self._node_triangles, self.texels)

    def release(self) -> None:
        """Free every GPU object of the engine (and its context, if it created it)."""
        if self._released:
            return
        self._released = True
        self.cache.release()
        for fbo in self._targets.values():
            for att in (*fbo.color_attachments, fbo.depth_attachment):
                if att is not None:
                    att.release()
            fbo.release()
        self._targets.clear()
        self.normal_map.release()
        for prog in self.programs.values():
            prog.release()
        if self.owns_context:
            self.ctx.release()

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

    def _batches(self, keys: list[tuple[str, int]]) -> list[list[Any]]:
        """Meshes of ``keys`` grouped so each group fits the cache budget (normally one)."""
        batches: list[list[Any]] = [[]]
        used = 0
        for key in keys:
            mesh = self.cache.get(key, lambda key=key: self._mesh_data(key))
            if batches[-1] and used + mesh.nbytes > self.cache.budget_bytes:
                batches.append([])
                used = 0
            batches[-1].append(mesh)
            used += mesh.nbytes
        return batches

    def _meshes(self, batches: list[list[Any]], keys: list[tuple[str, int]]):
        """Yield the meshes to draw: the first batch as uploaded, later ones re-fetched."""
        if len(batches) == 1:
            yield from batches[0]
            return
        # Over budget: entries of earlier batches may have been evicted meanwhile.
        for key in keys:
            yield self.cache.get(key, lambda key=key: self._mesh_data(key))

    def _draw(self, target, fs: FrameState, batches, keys, wireframe: bool, program: str):
        """Clear ``target`` and draw the meshes; returns (ms incl. ctx.finish(), triangles)."""
        import moderngl

        ctx = self.ctx
        prog = self.programs[program]
        w, h = fs.viewport
        prog["u_mvp"].write(fs.local_to_clip.T.astype("f4").tobytes())
        if program == "terrain":
            z0, z1 = self.tree.terrain.z_range
            oz = self.tree.origin[2]
            prog["u_z_range"].value = (z0 - oz, z1 - oz)
            prog["u_normal_uv"].value = tuple(self._normal_uv)
            prog["u_line"].value = 1.0 if wireframe else 0.0
            prog["u_normals"].value = 0
            self.normal_map.use(location=0)
        triangles = 0
        t0 = time.perf_counter()
        with ctx.scope(framebuffer=target, enable_only=moderngl.DEPTH_TEST):
            ctx.viewport = (0, 0, w, h)
            ctx.depth_func = "<"
            clear = (-1.0, -1.0, -1.0, -1.0) if program == "position" else (0.0, 0.0, 0.0, 0.0)
            target.clear(*clear, depth=1.0, viewport=(0, 0, w, h))
            ctx.wireframe = wireframe
            try:
                for mesh in self._meshes(batches, keys):
                    mesh.vao(ctx, prog).render(moderngl.TRIANGLES)
                    triangles += mesh.triangles
            finally:
                ctx.wireframe = False
            ctx.finish()
        return (time.perf_counter() - t0) * 1e3, triangles

    def _positions(self, fs: FrameState, batches, keys) -> np.ndarray:
        """(h, w, 4) world positions of the drawn surface (see Frame.positions)."""
        w, h = fs.viewport
        fbo = self._target("position", w, h)
        self._draw(fbo, fs, batches, keys, False, "position")
        raw = fbo.read(viewport=(0, 0, w, h), components=4, dtype="f4", alignment=1)
        local = np.frombuffer(raw, dtype=np.float32).reshape(h, w, 4)[::-1].astype(np.float64)
        out = local.copy()
        out[..., :3] += self.tree.origin
        out[local[..., 3] < -0.5, :3] = np.nan
        return out

    def _target(self, kind: str, w: int, h: int) -> Any:
        """The engine's offscreen framebuffer of ``kind`` ("color" RGBA8, "position" RGBA32F)."""
        key = (kind, w, h)
        fbo = self._targets.get(key)
        if fbo is None:
            # One size at a time per kind: drop buffers of a previous size.
            for old in [k for k in self._targets if k[0] == kind]:
                stale = self._targets.pop(old)
                for att in (*stale.color_attachments, stale.depth_attachment):
                    att.release()
                stale.release()
            dtype = "f4" if kind == "position" else "f1"
            color = self.ctx.renderbuffer((w, h), 4, dtype=dtype)
            depth = self.ctx.depth_renderbuffer((w, h))
            fbo = self.ctx.framebuffer(color_attachments=[color], depth_attachment=depth)
            self._targets[key] = fbo
        return fbo

    # -- geometry ---------------------------------------------------------------------------

    def _mesh_data(self, key: tuple[str, int]) -> tuple[np.ndarray, np.ndarray]:
        """(vertex data (n, 4) float32: local x, y, z and skirt flag; triangles (m, 3) uint32)."""
        kind, i = key
        if kind == "full":
            patch = self._full_resolution_chunks()[i][0]
            verts, tris = patch.vertices, patch.triangles
            flags = np.zeros(len(verts), dtype=np.float32)
        elif not self.skirts:
            patch = self.tree.patch(i)
            verts, tris = patch.vertices, patch.triangles
            flags = np.zeros(len(verts), dtype=np.float32)
        else:
            patch = self.tree.patch(i)
            verts, tris, flags = add_skirts(
                patch.vertices,
                patch.triangles,
                float(self.skirt_depths[i]),
                self._domain,
                self.skirt_base,
            )
        data = np.empty((len(verts), 4), dtype=np.float32)
        data[:, :3] = verts - self.tree.origin
        data[:, 3] = flags
        return data, np.asarray(tris, dtype=np.uint32)

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

    def _make_normal_map(self) -> tuple[Any, np.ndarray]:
        """RG8 texture of normal x, y (display units) over the domain, and its uv transform.

        Returns (texture, (4,) float: uv = local_xy * t[:2] + t[2:]).
        """
        terrain = self.tree.terrain
        limit = min(NORMAL_MAP_MAX, int(self.ctx.info.get("GL_MAX_TEXTURE_SIZE", 4096)))
        if isinstance(terrain, Grid):
            # Ascending x and y so that texture rows run south to north.
            z = terrain.heights
            xs, ys = terrain.x_coords, terrain.y_coords
            if xs[0] > xs[-1]:
                z, xs = z[:, ::-1], xs[::-1]
            if ys[0] > ys[-1]:
                z, ys = z[::-1], ys[::-1]
            stride = max(1, math.ceil(max(z.shape) / limit))
            z = np.asarray(z[::stride, ::stride], dtype=np.float64)
            xs, ys = xs[::stride], ys[::stride]
        else:
            d = terrain.domain
            n = min(limit, 1024)
            xs = np.linspace(d.xmin, d.xmax, n)
            ys = np.linspace(d.ymin, d.ymax, n)
            z = terrain.height_at(xs[None, :], ys[:, None])
        ox, oy, _ = self.tree.origin
        sx, sy, sz = self.scale
        nrm = _normals(z * sz, (xs - ox) * sx, (ys - oy) * sy)
        data = np.ascontiguousarray(np.rint((nrm[..., :2] * 0.5 + 0.5) * 255.0).astype(np.uint8))
        ny, nx = data.shape[:2]
        tex = self.ctx.texture((nx, ny), 2, data.tobytes(), dtype="f1")
        tex.repeat_x = False
        tex.repeat_y = False
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
        return tex, uv


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
