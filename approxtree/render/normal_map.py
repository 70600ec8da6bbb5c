"""The normal map: per-pixel normals of the terrain, computed once from the height field.

Lighting (render/style.py) needs the surface normal under every fragment, whatever patch is
drawn there: the normal map samples h_T on a lattice over the domain (a Grid's own cells,
strided to at most NORMAL_MAP_MAX texels a side; other terrains through ``height_at``), takes
central differences in display units (the exaggeration included, so the light follows it)
and stores the normals' x and y as two uint8 channels (z follows, the normal pointing up).

The normal map is the untextured shading's texture patch in the core paper's sense (3.3): the
shading pyramid's levels are the data's normals and their 2×, 4×, ... coarser strides, and the
root's patch, the finest level whose subtexture covering the domain fits the largest texture
side, covers every node; descendants share it. A grid smaller than that side is sampled up to
UPSAMPLE_MAX times finer than its cells (``ShadingLattice.upsample``), bilinearly between the
data's normals, as the GPU's filter would between texels: its texels then stay under a pixel
where the data's cells grow to a few. γ_N of an untextured frame is measured on this texel
(``shading_texels``): it is what every node is drawn with, so refining the geometry never
makes it finer, and γ refines nothing (selector.py: γ refines a node only where a descendant's
texel is finer).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from approxtree.geometry.grid import OVERVIEW_SIDE, Grid

#: Largest side of the normal map (texels), further limited by GL_MAX_TEXTURE_SIZE.
NORMAL_MAP_MAX = OVERVIEW_SIDE  # the overview a tree store keeps is this map's samples
#: Lattice side for terrains without a grid (sampled through height_at).
SCATTERED_SIDE = 1024
#: Most texels of the shading lattice per data cell edge (a power of two).
UPSAMPLE_MAX = 4
#: Rows of the normal map computed at once: its float64 temporaries stay a few tens of MB
#: (the whole 4096² map at once took 1.4 GB).
_NORMAL_STRIP_ROWS = 256


@dataclass(frozen=True)
class ShadingLattice:
    """Where the normal map's texels lie: data lattice xs (nx,), ys (ny,) ascending (a Grid's
    strided lines, or a regular lattice through ``height_at``), each cell of it cut into
    ``upsample`` × ``upsample`` texels; rs, cs: the Grid's row and column steps (0: not a
    Grid)."""

    xs: np.ndarray
    ys: np.ndarray
    rs: int
    cs: int
    upsample: int

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx) texels of the normal map."""
        u = self.upsample
        return (len(self.ys) - 1) * u + 1, (len(self.xs) - 1) * u + 1

    @property
    def texel(self) -> tuple[float, float]:
        """(w, h) of one texel in world x, y units: the texel of γ (the lattice spacing)."""
        ny, nx = self.shape
        w = (self.xs[-1] - self.xs[0]) / (nx - 1) if nx > 1 else 0.0
        h = (self.ys[-1] - self.ys[0]) / (ny - 1) if ny > 1 else 0.0
        # A single line (a one-cell-wide terrain): the other direction's spacing, else 1.
        w = w or h or 1.0
        return float(w), float(h or w)


def shading_lattice(terrain: Any, max_side: int = NORMAL_MAP_MAX) -> ShadingLattice:
    """The lattice of the normal map of ``terrain`` within ``max_side`` texels a side (further
    limited to NORMAL_MAP_MAX): reads no heights."""
    limit = min(NORMAL_MAP_MAX, max_side)
    if isinstance(terrain, Grid):
        # Ascending x and y so that texture rows run south to north.
        rs, cs = terrain.overview_steps(limit)
        xs, ys = terrain.x_coords[::cs], terrain.y_coords[::rs]
    else:
        d = terrain.domain
        n = min(limit, SCATTERED_SIDE)
        xs, ys = np.linspace(d.xmin, d.xmax, n), np.linspace(d.ymin, d.ymax, n)
        # Its lattice is sampled through height_at at any spacing: no upsampling.
        return ShadingLattice(xs, ys, 0, 0, 1)
    # The finest power of two up to UPSAMPLE_MAX keeping the lattice within the limit.
    cells = max(len(xs), len(ys)) - 1
    u = 1
    while 2 * u <= UPSAMPLE_MAX and cells * 2 * u + 1 <= limit:
        u *= 2
    return ShadingLattice(np.asarray(xs), np.asarray(ys), int(rs), int(cs), u if cells else 1)


def shading_texels(terrain: Any, n: int, max_side: int = NORMAL_MAP_MAX) -> np.ndarray:
    """(n, 2) float64: the normal map's texel (world x, y units) for each of n nodes, the
    texel of γ of an untextured frame (every node is drawn with it)."""
    return np.tile(np.array(shading_lattice(terrain, max_side).texel, dtype=np.float64), (n, 1))


def normal_map(
    terrain: Any, origin: np.ndarray, scale: np.ndarray, max_side: int
) -> tuple[np.ndarray, np.ndarray]:
    """Normal x, y (display units) over the terrain's domain as (ny, nx, 2) uint8, and the uv
    transform (4,) float: uv = local_xy * t[:2] + t[2:].

    origin: (3,) local origin of the GPU buffers; scale: (3,) display scale (exaggeration
    included); max_side: the context's largest texture side.
    """
    lattice = shading_lattice(terrain, max_side)
    xs, ys = lattice.xs, lattice.ys
    if isinstance(terrain, Grid):
        # One strided read (a windowed grid reads only the sampled cells, block by block).
        z = np.asarray(terrain.strided_heights(lattice.rs, lattice.cs), dtype=np.float64)
    else:
        z = terrain.height_at(xs[None, :], ys[:, None])
    ox, oy, _ = origin
    sx, sy, sz = scale
    data = normal_texels(z * sz, (xs - ox) * sx, (ys - oy) * sy, lattice.upsample)
    ny, nx = data.shape[:2]
    # Texel centre k sits at x0 + k·dx: u = (x − x0) / (dx · nx) + 0.5 / nx.
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


def normal_texels(z: np.ndarray, xs: np.ndarray, ys: np.ndarray, upsample: int = 1) -> np.ndarray:
    """(ny', nx', 2) uint8 normal x, y of ``normals(z, xs, ys)``, computed strip by strip;
    with ``upsample`` u > 1, ny' = (ny − 1)·u + 1 (nx' alike): texel k lies at data line k / u,
    bilinear between the normals' x, y of the data lines around it.

    Each strip takes one row of halo on either side, so central differences see the same
    neighbours as over the whole map and every texel is the same as computed at once.
    """
    ny, nx = z.shape
    u = max(int(upsample), 1)
    out = np.empty(((ny - 1) * u + 1, (nx - 1) * u + 1, 2), dtype=np.uint8)
    # Fine column k: data column k // u and the weight of the next one.
    k = np.arange(out.shape[1])
    c0 = k // u
    c1 = np.minimum(c0 + 1, nx - 1)
    fc = ((k - c0 * u) / u)[None, :, None]
    step = max(_NORMAL_STRIP_ROWS // u, 1)
    for a in range(0, ny, step):
        b = min(ny, a + step)
        # Data rows a..b (b for the bilinear weights of the strip's last fine rows), each
        # with its central-difference neighbours.
        last = min(b + 1, ny)
        lo, hi = max(0, a - 1), min(ny, last + 1)
        xy = normals(z[lo:hi], xs, ys[lo:hi])[a - lo : last - lo, :, :2]
        r_end = b * u if b < ny else out.shape[0]
        if u > 1:
            rows = np.arange(a * u, r_end)
            r0 = rows // u - a
            r1 = np.minimum(r0 + 1, len(xy) - 1)
            fr = ((rows % u) / u)[:, None, None]
            cols = xy[:, c0] * (1.0 - fc) + xy[:, c1] * fc
            xy = cols[r0] * (1.0 - fr) + cols[r1] * fr
        out[a * u : r_end] = np.rint((xy[: r_end - a * u] * 0.5 + 0.5) * 255.0).astype(np.uint8)
    return out
