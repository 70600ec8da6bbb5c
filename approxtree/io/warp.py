"""The resampling scale GDAL's warper is given when a raster is reprojected by windows.

GDAL's warper derives its resampling scale (how many target texels one source pixel spans,
which sets the width of an antialiasing kernel) from each warped chunk's source window, so
a window's texels would depend on where the windows are cut. ``warp_scale`` measures it once
across the whole target grid, for the warp options XSCALE and YSCALE; the image bake
(textures/image.py) and its verifier (verify/pyramid_image.py) both pass it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from affine import Affine

#: Resampling names (gdalwarp's ``-r`` spellings) → rasterio's Resampling member names: the
#: choices of ``bake --resampling`` and ``verify --resampling`` (textures/image.py warps with
#: them, verify/pyramid_image.py re-warps with the same).
RESAMPLINGS = {
    "nearest": "nearest",
    "bilinear": "bilinear",
    "cubic": "cubic",
    "cubicspline": "cubic_spline",
    "lanczos": "lanczos",
    "average": "average",
}


def warp_scale(
    ds: Any, source_crs: Any, crs: Any, transform: Affine, shape: tuple[int, int]
) -> dict[str, str]:
    """GDAL's warp options XSCALE and YSCALE: target texels per source pixel along the target
    grid's middle row and column (both image axes counted).

    ds: the open source dataset (rasterio); source_crs, crs: the source's and the target's
    CRS (no reprojection when either is None); transform, shape (rows, cols): the target grid.
    {} when the scale cannot be measured (the grid's middle does not project into the
    source's CRS).
    """
    from rasterio.warp import transform as transform_points

    rows, cols = shape
    corners = [(0, rows / 2), (cols, rows / 2), (cols / 2, 0), (cols / 2, rows)]
    xs, ys = zip(*(transform @ c for c in corners), strict=True)
    if crs is not None and source_crs is not None:
        try:
            xs, ys = transform_points(crs, source_crs, list(xs), list(ys))
        except Exception:
            return {}
    inv = ~ds.transform
    p = [inv @ (x, y) for x, y in zip(xs, ys, strict=True)]
    # Source pixels spanned by the grid's middle row and column (both image axes).
    across = abs(p[1][0] - p[0][0]) + abs(p[1][1] - p[0][1])
    down = abs(p[3][0] - p[2][0]) + abs(p[3][1] - p[2][1])
    if not (np.isfinite(across) and np.isfinite(down) and across > 0 and down > 0):
        return {}
    return {"XSCALE": repr(cols / across), "YSCALE": repr(rows / down)}
