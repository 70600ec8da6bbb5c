"""Helpers of the tests that read written imagery tiles back: the pixel at a point."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from approxtree.tiles.schemes import scheme_named


def pixel_at(folder: Path, lon: float, lat: float, z: int) -> np.ndarray | None:
    """(4,) uint8 RGBA pixel at (lon, lat) of the geographic imagery tile of zoom z holding it,
    in the written folder (None when no tile holds it)."""
    scheme = scheme_named("geographic")
    for path in (Path(folder) / str(z)).glob("*/*.png"):
        x, y = int(path.parent.name), int(path.stem)
        west, south, east, north = scheme.bounds(z, x, y)
        if west <= lon < east and south <= lat < north:
            image = np.asarray(Image.open(path).convert("RGBA"))
            size = image.shape[0]
            col = int((lon - west) / (east - west) * size)
            row = int((north - lat) / (north - south) * size)
            return image[row, col]
    return None
