"""TexturePatch: the part of a texture pyramid that textures one node (core paper, 3.3).

For a node's domain D_N: take the first (finest) pyramid level whose subtexture covering D_N
exactly fits the maximum texture size; the patch is a power-of-two sized region of that level
covering at least D_N. A patch references the pyramid (level and texel window); its texels are
read from the level's tiles only when it is uploaded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from approxtree.geometry.rect import Rect
from approxtree.textures.pyramid import TexturePyramid


def _pow2(n: int) -> int:
    return 1 << max(0, math.ceil(math.log2(max(n, 1))))


@dataclass(frozen=True)
class TexturePatch:
    """A power-of-two window (col0, row0, width, height) of pyramid level ``level``."""

    pyramid: TexturePyramid
    level: int
    col0: int
    row0: int
    width: int
    height: int

    @classmethod
    def for_rect(cls, pyramid: TexturePyramid, rect: Rect) -> TexturePatch:
        """The finest-level patch covering ``rect`` within the maximum texture size."""
        limit = pyramid.max_texture_size
        for k, lv in enumerate(pyramid.levels):
            c0, r0, c1, r1 = _texel_span(lv.transform, rect, lv.width, lv.height)
            w, h = _pow2(c1 - c0), _pow2(r1 - r0)
            if w <= limit and h <= limit:
                return cls(pyramid, k, *_place(c0, r0, w, h, lv.width, lv.height), w, h)
        # The last level fits the limit as a whole, so this is unreachable for valid pyramids.
        lv = pyramid.levels[-1]
        return cls(pyramid, len(pyramid) - 1, 0, 0, _pow2(lv.width), _pow2(lv.height))

    @property
    def texel_size(self) -> tuple[float, float]:
        """(w, h) of one texel in world units: the texel rectangle of γ_N."""
        return self.pyramid.levels[self.level].texel_size

    @property
    def extent(self) -> Rect:
        """D(Q_N): the world rectangle the patch covers (may reach past the texture's domain)."""
        t = self.pyramid.levels[self.level].transform
        x0, y0 = t @ (self.col0, self.row0)
        x1, y1 = t @ (self.col0 + self.width, self.row0 + self.height)
        return Rect(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))

    def texels(self) -> np.ndarray:
        """(height, width, 4) uint8 RGBA; parts beyond the level's edge are transparent."""
        return self.pyramid.read(self.level, self.row0, self.col0, self.height, self.width)


def patch_levels(pyramid: TexturePyramid, rects: np.ndarray) -> np.ndarray:
    """(n,) int64 pyramid level of ``TexturePatch.for_rect`` for n rectangles at once.

    rects: (n, 4) float64 (xmin, ymin, xmax, ymax). Same arithmetic as ``_texel_span`` (the
    affine product in affine's order), so the level equals the one ``for_rect`` picks.
    """
    rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    n = len(rects)
    out = np.full(n, len(pyramid) - 1, dtype=np.int64)
    todo = np.ones(n, dtype=bool)
    limit = pyramid.max_texture_size
    eps = 1e-9
    for k, lv in enumerate(pyramid.levels):
        inv = ~lv.transform
        # Corners (xmin, ymax) and (xmax, ymin) into texel space, as inv @ (x, y) does.
        ca = rects[:, 0] * inv.a + rects[:, 3] * inv.b + inv.c
        ra = rects[:, 0] * inv.d + rects[:, 3] * inv.e + inv.f
        cb = rects[:, 2] * inv.a + rects[:, 1] * inv.b + inv.c
        rb = rects[:, 2] * inv.d + rects[:, 1] * inv.e + inv.f
        c0 = np.maximum(0, np.floor(np.minimum(ca, cb) + eps))
        r0 = np.maximum(0, np.floor(np.minimum(ra, rb) + eps))
        c1 = np.minimum(lv.width, np.maximum(c0 + 1, np.ceil(np.maximum(ca, cb) - eps)))
        r1 = np.minimum(lv.height, np.maximum(r0 + 1, np.ceil(np.maximum(ra, rb) - eps)))
        span = np.maximum(c1 - c0, r1 - r0)
        # The power of two above a span fits the limit exactly when the span does.
        fits = todo & (span <= limit)
        out[fits] = k
        todo &= ~fits
        if not todo.any():
            break
    return out


def patch_texel_sizes(pyramid: TexturePyramid, rects: np.ndarray) -> np.ndarray:
    """(n, 2) float64 texel width and height of the texture patch of each of n rectangles."""
    sizes = np.array([lv.texel_size for lv in pyramid.levels], dtype=np.float64)
    return sizes[patch_levels(pyramid, rects)]


def _texel_span(transform, rect: Rect, width: int, height: int) -> tuple[int, int, int, int]:
    """(c0, r0, c1, r1): texels whose union covers rect, clipped to the level."""
    inv = ~transform
    ca, ra = inv @ (rect.xmin, rect.ymax)
    cb, rb = inv @ (rect.xmax, rect.ymin)
    c0, c1 = sorted((ca, cb))
    r0, r1 = sorted((ra, rb))
    eps = 1e-9
    c0 = max(0, math.floor(c0 + eps))
    r0 = max(0, math.floor(r0 + eps))
    c1 = min(width, max(c0 + 1, math.ceil(c1 - eps)))
    r1 = min(height, max(r0 + 1, math.ceil(r1 - eps)))
    return c0, r0, c1, r1


def _place(c0: int, r0: int, w: int, h: int, width: int, height: int) -> tuple[int, int]:
    """Shift a w × h window starting at (c0, r0) back inside the level where it fits."""
    c0 = max(0, min(c0, width - w)) if w <= width else 0
    r0 = max(0, min(r0, height - h)) if h <= height else 0
    return c0, r0
