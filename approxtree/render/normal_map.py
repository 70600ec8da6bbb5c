"""The normal map: per-pixel normals of the terrain, computed once from the height field.

Lighting (render/style.py) needs the surface normal under every fragment, whatever patch is
drawn there: the normal map samples h_T on a lattice over the domain (a Grid's own cells,
strided to at most NORMAL_MAP_MAX texels a side; other terrains through ``height_at``), takes
central differences in display units (the exaggeration included, so the light follows it)
and stores the normals' x and y as two uint8 channels (z follows, the normal pointing up).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from approxtree.geometry.grid import OVERVIEW_SIDE, Grid

#: Largest side of the normal map (texels), further limited by GL_MAX_TEXTURE_SIZE.
NORMAL_MAP_MAX = OVERVIEW_SIDE  # the overview a tree store keeps is this map's samples
#: Lattice side for terrains without a grid (sampled through height_at).
SCATTERED_SIDE = 1024
#: Rows of the normal map computed at once: its float64 temporaries stay a few tens of MB
#: (the whole 4096² map at once took 1.4 GB).
_NORMAL_STRIP_ROWS = 256


def normal_map(
    terrain: Any, origin: np.ndarray, scale: np.ndarray, max_side: int
) -> tuple[np.ndarray, np.ndarray]:
    """Normal x, y (display units) over the terrain's domain as (ny, nx, 2) uint8, and the uv
    transform (4,) float: uv = local_xy * t[:2] + t[2:].

    origin: (3,) local origin of the GPU buffers; scale: (3,) display scale (exaggeration
    included); max_side: the context's largest texture side.
    """
    limit = min(NORMAL_MAP_MAX, max_side)
    if isinstance(terrain, Grid):
        # Ascending x and y so that texture rows run south to north; one strided read
        # (a windowed grid reads only the sampled cells, block by block).
        xs, ys = terrain.x_coords, terrain.y_coords
        rs, cs = terrain.overview_steps(limit)
        z = np.asarray(terrain.strided_heights(rs, cs), dtype=np.float64)
        xs, ys = xs[::cs], ys[::rs]
    else:
        d = terrain.domain
        n = min(limit, SCATTERED_SIDE)
        xs = np.linspace(d.xmin, d.xmax, n)
        ys = np.linspace(d.ymin, d.ymax, n)
        z = terrain.height_at(xs[None, :], ys[:, None])
    ox, oy, _ = origin
    sx, sy, sz = scale
    data = normal_texels(z * sz, (xs - ox) * sx, (ys - oy) * sy)
    ny, nx = data.shape[:2]
    # Texel centre k sits at xs[k]: u = (x − xs[0]) / (dx · nx) + 0.5 / nx.
    dx = (xs[-1] - xs[0]) / max(nx - 1, 1) if nx > 1 else 1.0
    dy = (ys[-1] - ys[0]) / max(ny - 1, 1) if ny > 1 else 1.0
    uv = np.array(
        [
            1.0 / (dx * nx),
            1.0 / (dy * ny),
            0.5 / nx - (xs[0] - ox) / (dx * nx),
            0.5 / ny - (ys[0] - oy) / (dy * ny),
        ]
    )
    return data, uv


def normals(z: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """(ny, nx, 3) unit normals of heights z (ny, nx) on ascending axes xs (nx,), ys (ny,).

    Central differences (one-sided at the border); NaN (holes) gives the up vector.
    """
    if z.shape[0] < 2 or z.shape[1] < 2:
        out = np.zeros((*z.shape, 3))
        out[..., 2] = 1.0
        return out
    dzdy, dzdx = np.gradient(z, ys, xs)
    n = np.stack([-dzdx, -dzdy, np.ones_like(z)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    bad = ~np.isfinite(n).all(axis=-1)
    n[bad] = (0.0, 0.0, 1.0)
    return n


def normal_texels(z: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """(ny, nx, 2) uint8 normal x, y of ``normals(z, xs, ys)``, computed strip by strip.

    Each strip takes one row of halo on either side, so central differences see the same
    neighbours as over the whole map and every texel is the same as computed at once.
    """
    ny, nx = z.shape
    out = np.empty((ny, nx, 2), dtype=np.uint8)
    for a in range(0, ny, _NORMAL_STRIP_ROWS):
        b = min(ny, a + _NORMAL_STRIP_ROWS)
        lo, hi = max(0, a - 1), min(ny, b + 1)
        nrm = normals(z[lo:hi], xs, ys[lo:hi])[a - lo : a - lo + (b - a)]
        out[a:b] = np.rint((nrm[..., :2] * 0.5 + 0.5) * 255.0).astype(np.uint8)
    return out
