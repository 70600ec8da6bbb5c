"""DetailTextures: a base pyramid refined by a detail pyramid below a tree level (seed §3.3).

A satellite image textures the whole terrain; a detailed texture (a city map) takes over for
the nodes at or below a tree level whose domain lies inside the detail pyramid's footprint:
where its coarsest level is opaque (alpha 255 on every texel the domain touches, so the finer
texels under the domain are opaque, or within a rounding of it: a detail image baked over the
whole terrain is transparent outside the image). A node's texture patch, and so its visual
texture error γ_N, comes from the pyramid it uses. On the command line a detail pyramid is
spelt ``FOLDER@LEVEL`` (``--textures base --textures city@6``; ``parse_textures``).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.rect import Rect
from approxtree.textures.pyramid import TexturePyramid

#: ``FOLDER@LEVEL``: a detail pyramid and the tree level from which it is used.
_DETAIL = re.compile(r"^(?P<folder>.+)@(?P<level>-?\d+)$")


def _pyramid(textures: Any) -> TexturePyramid:
    """A TexturePyramid as it is, or opened from its folder."""
    if isinstance(textures, TexturePyramid):
        return textures
    if isinstance(textures, str | os.PathLike):
        return TexturePyramid(textures)
    raise InvalidParameterError(
        f"A texture pyramid or its folder is needed, got a {type(textures).__name__}."
    )


class DetailTextures:
    """``base`` everywhere, ``detail`` for nodes at tree level >= ``level`` inside its footprint.

    base, detail: TexturePyramids or their folders, in one CRS; level: a tree level >= 0.
    """

    def __init__(self, base: Any, detail: Any, level: int) -> None:
        self.base = _pyramid(base)
        self.detail = _pyramid(detail)
        if isinstance(level, bool) or not isinstance(level, int | np.integer) or level < 0:
            raise InvalidParameterError(f"A detail level is a tree level >= 0, got {level!r}.")
        self.level = int(level)
        if self.base.crs and self.detail.crs:
            from rasterio.crs import CRS

            if CRS.from_user_input(self.base.crs) != CRS.from_user_input(self.detail.crs):
                raise InvalidParameterError(
                    f"The detail pyramid in {self.detail.folder} is in {self.detail.crs}, the "
                    f"base in {self.base.crs}; bake both from the same terrain."
                )
        last = len(self.detail) - 1
        self._coarse = self.detail.levels[last]
        # Summed-area table of the coarsest level's texels that are not opaque: a domain is
        # inside the footprint when the texels it touches hold none.
        holes = (self.detail.level(last)[..., 3] < 255).astype(np.int64)
        self._holes = np.zeros((holes.shape[0] + 1, holes.shape[1] + 1), dtype=np.int64)
        self._holes[1:, 1:] = holes.cumsum(axis=0).cumsum(axis=1)
        lv = self.detail.levels[0]
        x0, y0 = lv.transform @ (0, 0)
        x1, y1 = lv.transform @ (lv.width, lv.height)
        #: The world rectangle of the detail pyramid's level 0 (the footprint lies inside).
        self.extent = Rect(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))

    def inside(self, rects: np.ndarray) -> np.ndarray:
        """(n,) bool: which of n rectangles (n, 4) (xmin, ymin, xmax, ymax) lie where the
        detail pyramid is opaque (module docstring)."""
        rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
        lv = self._coarse
        inv = ~lv.transform
        ca, ra = inv.a * rects[:, 0] + inv.c, inv.e * rects[:, 3] + inv.f
        cb, rb = inv.a * rects[:, 2] + inv.c, inv.e * rects[:, 1] + inv.f
        eps = 1e-9
        c0 = np.floor(np.minimum(ca, cb) + eps).astype(np.int64)
        r0 = np.floor(np.minimum(ra, rb) + eps).astype(np.int64)
        c1 = np.maximum(c0 + 1, np.ceil(np.maximum(ca, cb) - eps).astype(np.int64))
        r1 = np.maximum(r0 + 1, np.ceil(np.maximum(ra, rb) - eps).astype(np.int64))
        within = (c0 >= 0) & (r0 >= 0) & (c1 <= lv.width) & (r1 <= lv.height)
        c0, c1 = np.clip(c0, 0, lv.width), np.clip(c1, 0, lv.width)
        r0, r1 = np.clip(r0, 0, lv.height), np.clip(r1, 0, lv.height)
        s = self._holes
        holes = s[r1, c1] - s[r0, c1] - s[r1, c0] + s[r0, c0]
        return within & (holes == 0)

    def uses_detail(self, levels: np.ndarray, rects: np.ndarray) -> np.ndarray:
        """(n,) bool: which of n nodes use the detail pyramid. levels: (n,) tree levels;
        rects: (n, 4) float64 domains (xmin, ymin, xmax, ymax)."""
        return (np.asarray(levels) >= self.level) & self.inside(rects)

    def pyramid_for(self, level: int, rect: Rect) -> TexturePyramid:
        """The pyramid a node at tree ``level`` over the domain ``rect`` is textured with."""
        box = np.array([[rect.xmin, rect.ymin, rect.xmax, rect.ymax]], dtype=np.float64)
        return self.detail if self.uses_detail(np.array([level]), box)[0] else self.base

    def __repr__(self) -> str:
        return f"DetailTextures({self.base.folder}, {self.detail.folder}@{self.level})"


def open_drape(textures: Any, terrain: Any = None) -> TexturePyramid | DetailTextures:
    """``textures`` (a TexturePyramid, its folder, or a DetailTextures) ready to drape: a folder
    is opened, and each pyramid's CRS must be the terrain's when both have one."""
    drape = textures if isinstance(textures, DetailTextures) else _pyramid(textures)
    pyramids = (drape.base, drape.detail) if isinstance(drape, DetailTextures) else (drape,)
    crs = getattr(terrain, "crs", None)
    for pyramid in pyramids:
        if pyramid.crs and crs:
            from pyproj import CRS

            if not CRS.from_user_input(pyramid.crs).equals(CRS.from_user_input(crs)):
                raise InvalidParameterError(
                    f"The texture pyramid's CRS ({pyramid.crs}) differs from the terrain's "
                    f"({crs}); bake the texture in the terrain's CRS."
                )
    return drape


def parse_textures(specs: Sequence[str]) -> list[Any]:
    """Command-line ``--textures`` values → pyramids to drape: a folder is a pyramid (by its
    folder), ``FOLDER@LEVEL`` refines the pyramid before it (a ``DetailTextures``)."""
    out: list[Any] = []
    for spec in specs:
        match = _DETAIL.match(spec)
        if match is None or Path(spec).is_dir():
            out.append(spec)
            continue
        if not out:
            raise InvalidParameterError(
                f"--textures {spec}: a detail pyramid (FOLDER@LEVEL) refines the pyramid "
                "given before it; give the base pyramid first."
            )
        level = int(match["level"])
        if isinstance(out[-1], DetailTextures):
            raise InvalidParameterError(f"--textures {spec}: one detail pyramid per base pyramid.")
        if level < 0:
            raise InvalidParameterError(f"--textures {spec}: the level must be >= 0.")
        out[-1] = DetailTextures(out[-1], match["folder"], level)
    return out
