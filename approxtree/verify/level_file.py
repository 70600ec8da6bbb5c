"""A texture pyramid level as its texels read: the level file, its re-baked deltas over it.

Shared by the pyramid checks (``verify.pyramid``), the image check (``verify.pyramid_image``)
and the imagery tiles' drape check (``verify.map_tiles``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

#: Texels a side of a pyramid tile (the levels' own tiling; deltas hold whole tiles).
TILE = 512


def open_raster(path: Path):
    """The rasterio dataset of ``path`` (rasterio imported on first use)."""
    import rasterio

    return rasterio.open(path)


class LevelFile:
    """A level as its texels read: the base file, each delta (pyramid format 5: whole tiles
    re-baked into a file of their own, listed oldest first) read over it. ``read`` takes a
    rasterio window (``boundless`` and ``fill_value`` as rasterio's), the rest is the base
    file's (height, width, count, dtypes, transform)."""

    def __init__(self, output: Path, entry: dict) -> None:
        self.base = open_raster(output / str(entry["file"]))
        self.deltas: list[tuple[Any, tuple[int, int]]] = []
        try:
            for d in entry.get("deltas", ()):
                tr0, _, tc0, _ = (int(v) for v in d["tiles"])
                self.deltas.append((open_raster(output / str(d["file"])), (tr0 * TILE, tc0 * TILE)))
        except BaseException:
            self.close()
            raise
        self.height, self.width = self.base.height, self.base.width
        self.count, self.dtypes, self.transform = (
            self.base.count,
            self.base.dtypes,
            (self.base.transform),
        )

    def read(self, window, boundless: bool = False, fill_value: int = 0) -> np.ndarray:
        """(bands, h, w) texels of the window: the base file's, each delta's over them."""
        from rasterio.windows import Window

        # fill_value only with boundless: rasterio would fill the alpha-masked texels with it.
        if boundless:
            out = self.base.read(window=window, boundless=True, fill_value=fill_value)
        else:
            out = self.base.read(window=window)
        r0, c0 = int(window.row_off), int(window.col_off)
        r1, c1 = r0 + out.shape[1], c0 + out.shape[2]
        for ds, (a, c) in self.deltas:
            ra, rb = max(r0, a), min(r1, a + ds.height)
            ca, cb = max(c0, c), min(c1, c + ds.width)
            if ra < rb and ca < cb:
                texels = ds.read(window=Window(ca - c, ra - a, cb - ca, rb - ra))
                out[:, ra - r0 : rb - r0, ca - c0 : cb - c0] = texels
        return out

    def close(self) -> None:
        self.base.close()
        for ds, _ in self.deltas:
            ds.close()

    def __enter__(self) -> LevelFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
