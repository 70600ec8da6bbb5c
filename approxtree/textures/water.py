"""WaterLevel: a flood as a thematic layer, the texels of a terrain below a water level.

A simulation's rising (or falling) water drawn over the relief: every texel whose height lies
below ``level`` takes the water colour, the others stay transparent, so the layers below it
(and the shading blended over it) show there. Per texel, so a new level changes only the
texels between the old and the new shore line (``rebake`` re-bakes the tiles they meet).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.textures.base import TextureData


def wet(heights: np.ndarray, level: float) -> np.ndarray:
    """(rows, cols) bool: the heights below the water level (no data is never wet)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(heights < level)


class WaterLevel(TextureData):
    """Water over the texels of ``terrain`` lower than ``level``.

    terrain: a Grid on the texture lattice (one texel per height); level: the water surface,
    in z units; colour: RGBA 0..255 of the water.
    """

    def __init__(self, terrain: Grid, level: float, colour: tuple[int, ...]) -> None:
        if not np.isfinite(level):
            raise InvalidParameterError(f"The water level must be a finite height, got {level}.")
        if len(colour) != 4:
            raise InvalidParameterError(f"The water colour must be RGBA, got {colour!r}.")
        self.terrain = terrain
        self.level = float(level)
        self.colour = np.array(colour, dtype=np.uint8)
        self.transform, self.shape, self.crs = terrain.transform, terrain.shape, terrain.crs

    def rgba(self) -> np.ndarray:
        z = self.terrain.heights_array("a water level layer")
        out = np.zeros((*self.shape, 4), dtype=np.uint8)
        out[wet(z, self.level)] = self.colour
        return out

    def band_strips(self, rows: int) -> Iterator[np.ndarray]:
        # Strip by strip: the heights are read whole once, RGBA never.
        z = self.terrain.heights_array("a water level layer")
        for r0 in range(0, self.shape[0], rows):
            mask = wet(z[r0 : r0 + rows], self.level)
            strip = np.zeros((4, *mask.shape), dtype=np.uint8)
            strip[:, mask] = self.colour[:, None]
            yield strip
