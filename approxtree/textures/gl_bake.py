"""Offscreen texture generation with OpenGL (core paper, 5.3): the hillshade on the GPU.

An orthographic top-down pass over the texture lattice draws one fragment per texel; the
fragment shader (``shaders/hillshade.glsl``) evaluates gdaldem's hillshade from a height
texture. Targets larger than the framebuffer (or than ``tile_size``) are drawn tile by tile:
each tile's height texture carries a one-texel halo of its neighbours' heights (invalid
outside the grid, which reproduces gdaldem's nodata border), so every texel reads the same
nine heights as in one pass and tiled output equals untiled output exactly.

The context is the caller's (a moderngl Context; ``approxtree.render.context.create_context``
makes a standalone one): the textures room never creates one (DESIGN.md, "Package layout").

Heights go to the GPU as float32 relative to the grid's lowest height (one offset for all
tiles), so float32 keeps the differences the gradients need; the result equals the float64
numpy kernel within ±1 grey level after rounding.

``GLTopographicShading`` is a TopographicShading whose ``hillshade()`` runs here; the
slope, curvature and shadow refinements apply to it unchanged.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from approxtree.errors import ContextUnavailableError, InvalidParameterError
from approxtree.glsl import create_program
from approxtree.kernels import hillshade as hs
from approxtree.textures.shading import ALGORITHMS, TopographicShading

#: Largest tile side by default: a tile's heights and read-back take tens of MB, so a bake's
#: peak memory is set by the DEM, not by the tiles (4096 held ~1 GB more at 8192² on llvmpipe).
DEFAULT_TILE = 1024


def max_tile_size(ctx: Any) -> int:
    """The largest square tile this context can draw: viewport, renderbuffer and texture
    limits (the height texture needs two halo texels more)."""
    dims = ctx.info.get("GL_MAX_VIEWPORT_DIMS", (16384, 16384))
    rb = int(ctx.info.get("GL_MAX_RENDERBUFFER_SIZE", 16384))
    tex = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 16384))
    return int(min(dims[0], dims[1], rb, tex - 2))


def gl_hillshade(
    shading: TopographicShading, context: Any = None, tile_size: int | None = None
) -> np.ndarray:
    """``shading.hillshade()`` computed on the GPU: (rows, cols) float32 in [1, 255], 0 = nodata.

    context: the moderngl Context to draw on (None: ContextUnavailableError, which ``bake``
    answers with the numpy kernel). tile_size: side of the tiles drawn (default:
    DEFAULT_TILE, at most what the context allows).
    """
    return _on_context(shading, context, tile_size, np.float32)


def _on_context(
    shading: TopographicShading, context: Any, tile_size: int | None, dtype: type
) -> np.ndarray:
    """The tiles drawn on ``context`` into a (rows, cols) array of ``dtype``: float32 values,
    or uint8 grey levels rounded tile by tile."""
    if tile_size is not None and not (isinstance(tile_size, int) and tile_size >= 1):
        raise InvalidParameterError(f"tile_size must be an int >= 1, got {tile_size!r}.")
    if context is None:
        raise ContextUnavailableError(
            "Baking with OpenGL needs a context: pass one made by "
            "approxtree.render.context.create_context() (context=)."
        )
    tile = min(tile_size or DEFAULT_TILE, max_tile_size(context))
    out: np.ndarray = np.zeros(shading.terrain.shape, dtype=dtype)
    return _draw_tiles(context, create_program, shading, tile, out)


def _uniforms(shading: TopographicShading) -> dict[str, Any]:
    """The shader's uniforms: the numba kernel's constants, computed in float64."""
    dx, dy = shading._steps
    algorithm = ALGORITHMS[shading.algorithm]
    zf = shading.z_factor / (8.0 if algorithm == hs.HORN else 2.0)
    alt = math.radians(shading.altitude)
    az = math.radians(shading.azimuth)
    cos_alt_z = math.cos(alt) * zf
    mode = hs.COMBINED if shading.combined else hs.STANDARD
    if shading.multidirectional:
        mode = hs.MULTIDIRECTIONAL
    return {
        "u_algorithm": algorithm,
        "u_mode": mode,
        "u_inv_step": (1.0 / dx, 1.0 / dy),
        "u_sin_alt": math.sin(alt),
        "u_cos_az": math.cos(az) * cos_alt_z,
        "u_sin_az": math.sin(az) * cos_alt_z,
        "u_c225": math.cos(math.radians(225.0)) * cos_alt_z,
        "u_cos_alt_z": cos_alt_z,
        "u_square_z": zf * zf,
    }


def _tile_heights(z: np.ndarray, offset: float, r0: int, c0: int, h: int, w: int) -> np.ndarray:
    """(h + 2, w + 2, 2) float32: heights − offset and validity of a tile with its halo."""
    rows, cols = z.shape
    out = np.zeros((h + 2, w + 2, 2), dtype=np.float32)
    ra, rb = max(r0 - 1, 0), min(r0 + h + 1, rows)
    ca, cb = max(c0 - 1, 0), min(c0 + w + 1, cols)
    block = np.asarray(z[ra:rb, ca:cb], dtype=np.float64)
    valid = np.isfinite(block)
    dst = out[ra - (r0 - 1) : rb - (r0 - 1), ca - (c0 - 1) : cb - (c0 - 1)]
    dst[..., 0] = np.where(valid, block - offset, 0.0)
    dst[..., 1] = valid
    return out


def _draw_tiles(
    ctx: Any, create_program, shading: TopographicShading, tile: int, out: np.ndarray
) -> np.ndarray:
    """Draw the shading tile by tile into ``out`` (rows, cols): float32 values as drawn, or
    uint8 grey levels (each tile rounded half to even as it is read back)."""
    import moderngl

    z = shading.terrain.heights_array("baking the shading texture")
    rows, cols = z.shape
    finite = np.isfinite(z)
    offset = float(np.min(z, where=finite, initial=np.inf)) if finite.any() else 0.0
    grey = out.dtype == np.uint8
    prog = create_program(ctx, "hillshade")
    quad = ctx.buffer(np.array([-1, -1, 0, 1, -1, 0, -1, 1, 0, 1, 1, 0], dtype="f4").tobytes())
    vao = ctx.vertex_array(prog, [(quad, "3f", "in_position")])
    th, tw = min(tile, rows), min(tile, cols)
    colour = ctx.renderbuffer((tw, th), 1, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[colour])
    try:
        for name, value in _uniforms(shading).items():
            prog[name].value = value
        prog["u_heights"].value = 0
        with ctx.scope(framebuffer=fbo, enable_only=moderngl.NOTHING):
            for r0 in range(0, rows, th):
                for c0 in range(0, cols, tw):
                    h, w = min(th, rows - r0), min(tw, cols - c0)
                    data = _tile_heights(z, offset, r0, c0, h, w)
                    tex = ctx.texture((w + 2, h + 2), 2, data.tobytes(), dtype="f4")
                    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
                    try:
                        tex.use(location=0)
                        ctx.viewport = (0, 0, w, h)
                        vao.render(moderngl.TRIANGLE_STRIP)
                        raw = fbo.read(viewport=(0, 0, w, h), components=1, dtype="f4")
                    finally:
                        tex.release()
                    # Framebuffer row y is lattice row r0 + y: the texture rows were not flipped.
                    values = np.frombuffer(raw, np.float32).reshape(h, w)
                    out[r0 : r0 + h, c0 : c0 + w] = np.rint(values) if grey else values
    finally:
        for obj in (vao, quad, fbo, colour, prog):
            obj.release()
    return out


class GLTopographicShading(TopographicShading):
    """TopographicShading whose hillshade is baked on the GPU (same options and results ±1).

    context: the moderngl Context to draw on (the caller's; None: ``hillshade()`` raises
    ContextUnavailableError); tile_size: see ``gl_hillshade``.
    """

    def __init__(
        self, terrain, *args: Any, context: Any = None, tile_size: int | None = None, **kw: Any
    ) -> None:
        super().__init__(terrain, *args, **kw)
        self.context = context
        self.tile_size = tile_size

    def hillshade(self) -> np.ndarray:
        return gl_hillshade(self, self.context, self.tile_size)

    def _plain_grey(self) -> np.ndarray:
        # Rounded tile by tile: no float32 grid besides the uint8 one.
        return _on_context(self, self.context, self.tile_size, np.uint8)
