"""TextureData: RGBA images over a georeferenced extent (core paper, section 5).

Subclassing contract: a texture sets ``transform`` (affine, pixel corner → world), ``shape``
(rows, cols) and ``crs``, and implements ``rgba()``. Textures of a Grid use the grid's own
lattice: one texel per data point, so a texel's centre is a data point.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import cached_property

import numpy as np
from affine import Affine

from approxtree.geometry.rect import Rect


class TextureData(ABC):
    """A georeferenced RGBA texture: (rows, cols, 4) uint8, alpha 0 where there is no data."""

    transform: Affine
    shape: tuple[int, int]
    crs: str | None = None

    @abstractmethod
    def rgba(self) -> np.ndarray:
        """The texture: (rows, cols, 4) uint8."""

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
    out[..., :3] = shade[..., None]
    out[..., 3] = np.where(shade > 0, 255, 0)
    return out
