"""Overlay: lines of text drawn over the terrain in the viewer's window.

The text is rendered with Pillow's built-in bitmap font into an RGBA image (light text on a
translucent dark box), uploaded as a texture when it changes, and drawn as one alpha-blended
quad at the top-left corner (``shaders/overlay.glsl``). The overlay owns its program, texture
and vertex array and frees them in ``release()``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from approxtree.render.shaders import create_program

#: Pixels between the text box and the window corner, and around the text.
MARGIN, PADDING = 8, 6
#: Line height of the bitmap font (pixels).
LINE_HEIGHT = 12


def text_image(lines: list[str]) -> np.ndarray:
    """(h, w, 4) uint8 RGBA image of ``lines``, row 0 at the top."""
    font = ImageFont.load_default()
    width = max((int(font.getlength(s)) for s in lines), default=0) + 2 * PADDING
    height = LINE_HEIGHT * len(lines) + 2 * PADDING
    img = Image.new("RGBA", (max(width, 1), max(height, 1)), (0, 0, 0, 150))
    draw = ImageDraw.Draw(img)
    for i, s in enumerate(lines):
        draw.text((PADDING, PADDING + i * LINE_HEIGHT), s, font=font, fill=(255, 255, 230, 255))
    return np.asarray(img)


class Overlay:
    """Text overlay on a moderngl context ``ctx`` (the window's)."""

    def __init__(self, ctx: Any) -> None:
        self.ctx = ctx
        self.program = create_program(ctx, "overlay")
        # The unit square as a triangle strip, in the registry's position attribute.
        corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype="f4")
        self.vbo = ctx.buffer(corners.tobytes())
        self.vao = ctx.vertex_array(self.program, [(self.vbo, "3f", "in_position")])
        self.texture: Any = None
        self._lines: list[str] = []

    def set_lines(self, lines: list[str]) -> None:
        """Replace the text (uploaded only when it changed)."""
        if lines == self._lines:
            return
        self._lines = list(lines)
        if self.texture is not None:
            self.texture.release()
            self.texture = None
        if not lines:
            return
        rgba = np.ascontiguousarray(text_image(lines))
        h, w = rgba.shape[:2]
        self.texture = self.ctx.texture((w, h), 4, rgba.tobytes())
        self.texture.filter = (self.ctx.NEAREST, self.ctx.NEAREST)

    def draw(self, viewport: tuple[int, int]) -> None:
        """Draw the text at the top-left corner of the bound framebuffer of size ``viewport``."""
        if self.texture is None:
            return
        vw, vh = viewport
        w, h = self.texture.size
        x0 = -1.0 + 2.0 * MARGIN / vw
        y1 = 1.0 - 2.0 * MARGIN / vh
        self.program["u_rect"].value = (x0, y1 - 2.0 * h / vh, x0 + 2.0 * w / vw, y1)
        self.program["u_text"].value = 0
        self.texture.use(location=0)
        ctx = self.ctx
        with ctx.scope(enable_only=ctx.BLEND):
            ctx.blend_func = ctx.SRC_ALPHA, ctx.ONE_MINUS_SRC_ALPHA
            ctx.viewport = (0, 0, vw, vh)
            self.vao.render(ctx.TRIANGLE_STRIP, vertices=4)

    def release(self) -> None:
        if self.texture is not None:
            self.texture.release()
            self.texture = None
        self.vao.release()
        self.vbo.release()
        self.program.release()
