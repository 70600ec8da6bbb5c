"""TextureData: RGBA images over a georeferenced extent (core paper, section 5).

Subclassing contract: a texture sets ``transform`` (affine, pixel corner → world), ``shape``
(rows, cols) and ``crs``, and implements ``rgba()``. Textures of a Grid use the grid's own
lattice: one texel per data point, so a texel's centre is a data point.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from functools import cached_property

import numpy as np
from affine import Affine

from approxtree.geometry.rect import Rect
from approxtree.kernels.rgba import grey_into_bands, grey_into_rgba


class TextureData(ABC):
    """A georeferenced RGBA texture: (rows, cols, 4) uint8, alpha 0 where there is no data."""

    transform: Affine
    shape: tuple[int, int]
    crs: str | None = None
    #: Bands of the texture's pyramid levels (``level_strips``): 4 (R, G, B, A), or 2 (grey,
    #: A) for a texture with R = G = B everywhere (shadings), stored in half the bytes.
    bands: int = 4

    @abstractmethod
    def rgba(self) -> np.ndarray:
        """The texture: (rows, cols, 4) uint8."""

    def band_strips(self, rows: int) -> Iterator[np.ndarray]:
        """The texture as successive strips of at most ``rows`` rows from the top, each
        (4, ≤ rows, cols) uint8 in band order (R, G, B, A planes) and valid until the next is
        asked for; writers that stream (the texture pyramid) read these. By default, slices
        of ``rgba()``."""
        rgba = self.rgba()
        for r0 in range(0, rgba.shape[0], rows):
            yield np.ascontiguousarray(np.moveaxis(rgba[r0 : r0 + rows], -1, 0))

    def level_strips(self, rows: int) -> Iterator[np.ndarray]:
        """The texture as the pyramid stores it: strips of at most ``rows`` rows from the top,
        each (``bands``, ≤ rows, cols) uint8, alpha last, valid until the next is asked for.
        By default ``band_strips`` (RGBA)."""
        return self.band_strips(rows)

    @cached_property
    def extent(self) -> Rect:
        """D(Q): the world rectangle covered by the texels (pixel edges, not centres)."""
        rows, cols = self.shape
        x0, y0 = self.transform @ (0, 0)
        x1, y1 = self.transform @ (cols, rows)
        return Rect(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))

    @property
    def texel_size(self) -> tuple[float, float]:
        """(w, h) of one texel in world units."""
        return (abs(self.transform.a), abs(self.transform.e))


def grey_to_rgba(shade: np.ndarray) -> np.ndarray:
    """(rows, cols) uint8 grey levels, 0 = nodata → (rows, cols, 4) RGBA with R = G = B."""
    out = np.empty((*shade.shape, 4), dtype=np.uint8)
    grey_into_rgba(np.ascontiguousarray(shade, dtype=np.uint8), out)
    return out


def grey_strips(shade: np.ndarray, rows: int) -> Iterator[np.ndarray]:
    """``grey_to_rgba(shade)`` as band-order strips of at most ``rows`` rows (``band_strips``),
    assembled in one reused (4, rows, cols) buffer instead of a full-size RGBA array."""
    shade = np.ascontiguousarray(shade, dtype=np.uint8)
    buffer = np.empty((4, min(rows, shade.shape[0]), shade.shape[1]), dtype=np.uint8)
    for r0 in range(0, shade.shape[0], rows):
        n = min(rows, shade.shape[0] - r0)
        strip = buffer if n == buffer.shape[1] else np.empty((4, n, shade.shape[1]), np.uint8)
        grey_into_bands(shade[r0 : r0 + n], strip)
        yield strip


def grey_alpha_strips(shade: np.ndarray, rows: int) -> Iterator[np.ndarray]:
    """(rows, cols) uint8 grey levels (0 = nodata) as (2, ≤ rows, cols) uint8 strips of grey
    and alpha (255 where grey > 0, else 0), assembled in one reused buffer: the 2-band form of
    ``grey_strips`` (R = G = B = grey there)."""
    shade = np.ascontiguousarray(shade, dtype=np.uint8)
    buffer = np.empty((2, min(rows, shade.shape[0]), shade.shape[1]), dtype=np.uint8)
    for r0 in range(0, shade.shape[0], rows):
        n = min(rows, shade.shape[0] - r0)
        strip = buffer if n == buffer.shape[1] else np.empty((2, n, shade.shape[1]), np.uint8)
        grey = shade[r0 : r0 + n]
        strip[0] = grey
        # Alpha 0/1 written as bools into the uint8 plane, then scaled to 0/255 in place.
        np.not_equal(grey, 0, out=strip[1].view(np.bool_))
        strip[1] *= 255
        yield strip
