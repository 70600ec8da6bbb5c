"""The normal map and normal patches: per-pixel normals of the terrain, from its heights.

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

A Grid over NORMAL_MAP_MAX cells a side gets a strided map, coarser than its data. There the
shading is a pyramid of normal patches (``NormalPatches``, ``pyramid_levels``): level 0 holds
the data's normals upsampled PATCH_UPSAMPLE_MAX times (8: a node near a low camera whose ×4
texel still projects over γ has a finer one), the next levels 4×, 2× upsampled, the data's
own normals, then every 2nd, 4th, ... line; a node's patch is the finest level's window
covering D_N within NORMAL_PATCH_MAX texels a side, and a node whose patch would be no finer than
the strided map keeps the map (``NormalKey`` None). A patch is uploaded as the normals of its
window's lattice lines (``upload_texels``, ``upload_uv``): the GPU's bilinear filter draws the
upsampled level's texels between them (``texels_of``: the same values, up to 8-bit rounding),
so a 1024-texel patch at ×4 is 256² texels on the GPU, not 1024². Patches are computed on
demand from the heights (a window with one line of halo: the same central differences as over
the whole level) and cached like texture patches (the provider's CPU cache, the GPU cache,
least recently used out); nodes share an ancestor's patch as they share texture patches
(render/texture_sharing.py), and full-resolution chunks are shaded each by its own patch
(render/full_resolution.py). γ_N is then its patch's texel, and ``finer_below`` sees the finer
patches below the large nodes. A terrain within NORMAL_MAP_MAX a side has no patches: its
frames are drawn as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from approxtree.geometry.grid import OVERVIEW_SIDE, Grid

#: Largest side of the normal map (texels), further limited by GL_MAX_TEXTURE_SIZE.
NORMAL_MAP_MAX = OVERVIEW_SIDE  # the overview a tree store keeps is this map's samples
#: Lattice side for terrains without a grid (sampled through height_at).
SCATTERED_SIDE = 1024
#: Most texels of the shading lattice per data cell edge (a power of two).
UPSAMPLE_MAX = 4
#: Largest side of a normal patch's level (texels, upsampled): smaller than the texture limit,
#: so that a frame computes patches near the size of what it draws (a 4096² patch of an
#: ancestor shared by a few near nodes cost seconds to compute).
NORMAL_PATCH_MAX = 1024
#: Most texels per data cell edge of the normal patches' finest level (a power of two): a
#: node near the camera whose ×UPSAMPLE_MAX texel still projects over γ has a finer one.
PATCH_UPSAMPLE_MAX = 8
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
    step = max(_NORMAL_STRIP_ROWS // u, 1)
    for a in range(0, ny, step):
        b = min(ny, a + step)
        # Data rows a..b (b for the bilinear weights of the strip's last fine rows), each
        # with its central-difference neighbours.
        last = min(b + 1, ny)
        lo, hi = max(0, a - 1), min(ny, last + 1)
        xy = _normal_xy(z[lo:hi], xs, ys[lo:hi])[a - lo : last - lo]
        r_end = b * u if b < ny else out.shape[0]
        if u > 1:
            _bilinear_texels(np.ascontiguousarray(xy), u, a, r_end, out)
            continue
        out[a * u : r_end] = np.rint((xy[: r_end - a * u] * 0.5 + 0.5) * 255.0).astype(np.uint8)
    return out


def _normal_xy(z: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """(ny, nx, 2) float64 x, y of ``normals(z, xs, ys)``, compiled: the same arithmetic as
    np.gradient (its uniform-spacing formula where the axis's steps are all equal) and the
    norm, so every value is the same bit for bit, 10× faster."""
    if z.shape[0] < 2 or z.shape[1] < 2:
        return np.zeros((*z.shape, 2))
    z = np.ascontiguousarray(z, dtype=np.float64)
    xs, ys = np.asarray(xs, dtype=np.float64), np.asarray(ys, dtype=np.float64)
    dx, dy = np.diff(xs), np.diff(ys)
    return _normal_xy_kernel(z, xs, ys, bool((dx == dx[0]).all()), bool((dy == dy[0]).all()))


@njit(cache=True, inline="always")
def _derivative(f0, f1, f2, c0, c1, c2, i, n, uniform):
    """np.gradient's first-order-edge derivative at index i of n from the values f0, f1, f2
    at i − 1, i, i + 1 (clamped) and their coordinates c0, c1, c2."""
    if i == 0:
        return (f2 - f1) / (c2 - c1)
    if i == n - 1:
        return (f1 - f0) / (c1 - c0)
    if uniform:
        return (f2 - f0) / (2.0 * (c1 - c0))
    dx1, dx2 = c1 - c0, c2 - c1
    a = -(dx2) / (dx1 * (dx1 + dx2))
    b = (dx2 - dx1) / (dx1 * dx2)
    c = dx1 / (dx2 * (dx1 + dx2))
    return a * f0 + b * f1 + c * f2


@njit(cache=True)
def _normal_xy_kernel(z, xs, ys, ux, uy):
    """Unit normals' x, y (ny, nx, 2) of heights z (ny, nx): see ``_normal_xy``."""
    ny, nx = z.shape
    out = np.empty((ny, nx, 2))
    _normals_into(z, xs, ys, ux, uy, 0, 0, out)
    return out


@njit(cache=True)
def _normal_rgba_kernel(z, xs, ys, ux, uy, top, left, out):
    """``out`` (h, w, 4) uint8: the normals of rows top.., columns left.. of heights z (a
    window with its halo), encoded as ``normal_texels`` does, then 0, 255."""
    _normals_into(z, xs, ys, ux, uy, top, left, out)


@njit(cache=True)
def _normals_into(z, xs, ys, ux, uy, top, left, out):
    """Unit normals' x, y of rows top.., columns left.. of heights z (ny, nx) into ``out``
    (h, w, 2) float64, or encoded (h, w, 4) uint8: rint((n · 0.5 + 0.5) · 255), 0, 255."""
    ny, nx = z.shape
    h, w = out.shape[0], out.shape[1]
    encode = out.shape[2] == 4
    # Uniform spacing: np.gradient divides by twice the first step, as here.
    sx, sy = xs[1] - xs[0], ys[1] - ys[0]
    for i in range(h):
        r = top + i
        r0, r2 = max(r - 1, 0), min(r + 1, ny - 1)
        for j in range(w):
            k = left + j
            k0, k2 = max(k - 1, 0), min(k + 1, nx - 1)
            if ux and 0 < k < nx - 1:
                gx = (z[r, k2] - z[r, k0]) / (2.0 * sx)
            else:
                gx = _derivative(z[r, k0], z[r, k], z[r, k2], xs[k0], xs[k], xs[k2], k, nx, False)
            if uy and 0 < r < ny - 1:
                gy = (z[r2, k] - z[r0, k]) / (2.0 * sy)
            else:
                gy = _derivative(z[r0, k], z[r, k], z[r2, k], ys[r0], ys[r], ys[r2], r, ny, False)
            nrm = math.sqrt(gx * gx + gy * gy + 1.0)
            vx, vy, vz = -gx / nrm, -gy / nrm, 1.0 / nrm
            if not (math.isfinite(vx) and math.isfinite(vy) and math.isfinite(vz)):
                vx, vy = 0.0, 0.0
            if encode:
                out[i, j, 0] = np.uint8(np.rint((vx * 0.5 + 0.5) * 255.0))
                out[i, j, 1] = np.uint8(np.rint((vy * 0.5 + 0.5) * 255.0))
                out[i, j, 2] = 0
                out[i, j, 3] = 255
            else:
                out[i, j, 0], out[i, j, 1] = vx, vy


@njit(cache=True)
def _bilinear_texels(xy, u, a, r_end, out):
    """Fine rows a·u .. r_end of ``out`` (ny', nx', 2) uint8 from the normals' x, y ``xy``
    (m, nx, 2) float64 of data rows a, a + 1, ...: bilinear at texel k / u, encoded as
    rint((n · 0.5 + 0.5) · 255); the arithmetic of a numpy column-then-row interpolation."""
    nx = xy.shape[1]
    for row in range(a * u, r_end):
        r0 = row // u - a
        r1 = min(r0 + 1, xy.shape[0] - 1)
        fr = (row % u) / u
        for k in range(out.shape[1]):
            c0 = k // u
            c1 = min(c0 + 1, nx - 1)
            fc = (k - c0 * u) / u
            for ch in range(2):
                v0 = xy[r0, c0, ch] * (1.0 - fc) + xy[r0, c1, ch] * fc
                v1 = xy[r1, c0, ch] * (1.0 - fc) + xy[r1, c1, ch] * fc
                v = v0 * (1.0 - fr) + v1 * fr
                out[row, k, ch] = np.uint8(np.rint((v * 0.5 + 0.5) * 255.0))


class NormalKey(NamedTuple):
    """One normal patch: ``rows`` × ``cols`` lines of the data lattice of every ``step``-th
    line, from lattice line ``row0``, ``col0`` (grid index / step, in the raster's order), each
    cell cut into ``upsample`` × ``upsample`` texels (as ``normal_texels``); ``zscale``: the
    display scale of z its normals were computed with."""

    step: int
    upsample: int
    row0: int
    col0: int
    rows: int
    cols: int
    zscale: float

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) texels of the patch."""
        u = self.upsample
        return (self.rows - 1) * u + 1, (self.cols - 1) * u + 1


def pyramid_levels(stride: int) -> list[tuple[int, int]]:
    """[(step, upsample)] of the normal pyramid's levels finer than a map strided by
    ``stride``, finest first: the data's normals upsampled PATCH_UPSAMPLE_MAX, ..., 2 times
    (as the small grid's normal map), the data's own, then every 2nd, 4th, ... line."""
    levels = []
    u = PATCH_UPSAMPLE_MAX
    while u > 1:
        levels.append((1, u))
        u //= 2
    step = 1
    while step < stride:
        levels.append((step, 1))
        step *= 2
    return levels


class NormalPatches:
    """The normal patches of a terrain's nodes (see the module docstring).

    terrain: the tree's terrain; rects: (n, 4) float64 node rectangles (xmin, ymin, xmax,
    ymax); max_side: the largest texture side. ``active`` is False (no patch, every node drawn
    with the normal map) unless the terrain is a Grid whose normal map is strided.
    """

    def __init__(self, terrain: Any, rects: np.ndarray, max_side: int = NORMAL_MAP_MAX) -> None:
        self.terrain = terrain
        self.max_side = max_side
        lattice = shading_lattice(terrain, max_side)
        n = len(rects)
        #: (n, 2) float64 texel (world x, y) of the patch each node is drawn with (γ_N).
        self.texels = np.tile(np.array(lattice.texel, dtype=np.float64), (n, 1))
        #: (n,) int64 level (pyramid_levels) of each node's patch, −1: the normal map; (n, 4)
        #: int64 its window (row0, col0, rows, cols) in lattice lines.
        self.levels = np.full(n, -1, dtype=np.int64)
        self.windows = np.zeros((n, 4), dtype=np.int64)
        stride = max(abs(lattice.rs), abs(lattice.cs))
        self.active = isinstance(terrain, Grid) and stride > 1
        self.pyramid = pyramid_levels(stride) if self.active else []
        if not self.active or n == 0:
            return
        limit = min(NORMAL_MAP_MAX, max_side, NORMAL_PATCH_MAX)
        ranges = terrain.index_ranges(np.asarray(rects, dtype=np.float64))
        rows, cols = terrain.shape
        cell = np.array(terrain.cell_size, dtype=np.float64)
        todo = (ranges[:, 1] >= ranges[:, 0]) & (ranges[:, 3] >= ranges[:, 2])
        # Finest level first: a node takes the first whose window fits the texture side (the
        # levels are all finer than the strided map, which patches no finer keep).
        for level, (step, u) in enumerate(self.pyramid):
            if not todo.any():
                break
            r0, c0 = ranges[:, 0] // step, ranges[:, 2] // step
            r1 = np.minimum(-(-ranges[:, 1] // step), (rows - 1) // step)
            c1 = np.minimum(-(-ranges[:, 3] // step), (cols - 1) // step)
            fits = todo & ((r1 - r0) * u + 1 <= limit) & ((c1 - c0) * u + 1 <= limit)
            self.levels[fits] = level
            self.windows[fits] = np.column_stack([r0, c0, r1 - r0 + 1, c1 - c0 + 1])[fits]
            self.texels[fits] = cell * step / u
            todo &= ~fits

    def key(self, node: int, zscale: float) -> NormalKey | None:
        """The NormalKey of ``node``'s patch for z drawn ``zscale`` times, None: the map."""
        level = int(self.levels[node])
        if level < 0:
            return None
        step, u = self.pyramid[level]
        r0, c0, nr, nc = (int(v) for v in self.windows[node])
        return NormalKey(step, u, r0, c0, nr, nc, float(zscale))

    def texels_of(self, key: NormalKey, origin: np.ndarray, scale: np.ndarray) -> np.ndarray:
        """(h, w, 4) uint8 texels of a patch's level (``key.shape``): normal x, y (display
        units: x, y × ``scale`` (3,), z × key.zscale), 0, 255; row 0 the southernmost line,
        column 0 the westernmost (the normal map's order). What the GPU draws from
        ``upload_texels``: every ``key.upsample``-th texel is one of those, the others the
        bilinear filter's values between them."""
        z, xs, ys, top, left = self._window(key, origin, scale)
        u = key.upsample
        xy = normal_texels(z, xs, ys, u)
        h, w = key.shape
        out = np.zeros((h, w, 4), dtype=np.uint8)
        out[..., :2] = xy[top * u : top * u + h, left * u : left * u + w]
        out[..., 3] = 255
        return out

    def upload_texels(self, key: NormalKey, origin: np.ndarray, scale: np.ndarray) -> np.ndarray:
        """(rows, cols, 4) uint8: the texture of a patch, its lattice lines' normals (as
        ``texels_of``, which holds them at every ``key.upsample``-th texel); the GPU's
        bilinear filter upsamples them as ``normal_texels`` does, so an upsampled level costs
        no more texels than the data's (a 4096-texel patch at ×4 is 1024² texels, not 4096²)."""
        z, xs, ys, top, left = self._window(key, origin, scale)
        out = np.zeros((key.rows, key.cols, 4), dtype=np.uint8)
        if z.shape[0] < 2 or z.shape[1] < 2:
            out[..., :2], out[..., 3] = 128, 255  # a single line: the up vector
            return out
        dx, dy = np.diff(xs), np.diff(ys)
        ux, uy = bool((dx == dx[0]).all()), bool((dy == dy[0]).all())
        _normal_rgba_kernel(np.ascontiguousarray(z), xs, ys, ux, uy, top, left, out)
        return out

    def _window(
        self, key: NormalKey, origin: np.ndarray, scale: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
        """Heights (display z) of a patch's window with one line of halo each side (within
        the grid), rows south to north, its display axes xs, ys, and the window's first row
        and column in them."""
        grid, s = self.terrain, key.step
        rows, cols = grid.shape
        a, b = key.row0, key.row0 + key.rows - 1
        c, d = key.col0, key.col0 + key.cols - 1
        # One halo line each side, so central differences match the whole level's.
        ha, hb = max(a - 1, 0), min(b + 1, (rows - 1) // s)
        hc, hd = max(c - 1, 0), min(d + 1, (cols - 1) // s)
        z = np.asarray(grid.heights[ha * s : hb * s + 1 : s, hc * s : hd * s + 1 : s], float)
        xs = grid.x_coords[hc * s : hd * s + 1 : s]
        ys = grid.y_coords[ha * s : hb * s + 1 : s]
        top, left = a - ha, c - hc
        # Ascending x and y: texture rows run south to north, columns west to east.
        if len(ys) > 1 and ys[1] < ys[0]:
            z, ys, top = z[::-1], ys[::-1], hb - b
        if len(xs) > 1 and xs[1] < xs[0]:
            z, xs, left = z[:, ::-1], xs[::-1], hd - d
        ox, oy, _ = origin
        sx, sy, _ = scale
        return z * key.zscale, (xs - ox) * sx, (ys - oy) * sy, top, left

    def uv(self, key: NormalKey, origin: np.ndarray) -> tuple[float, float, float, float]:
        """uv = local.xy * t[:2] + t[2:] of a patch's level (``texels_of``: texel centres on
        its lattice lines and every 1/upsample between)."""
        return self._uv(key, origin, key.upsample)

    def upload_uv(self, key: NormalKey, origin: np.ndarray) -> tuple[float, float, float, float]:
        """uv of a patch's texture (``upload_texels``: texel centres on its lattice lines)."""
        return self._uv(key, origin, 1)

    def _uv(self, key: NormalKey, origin: np.ndarray, u: int) -> tuple[float, float, float, float]:
        """uv of a patch's lattice lines cut into ``u`` texels per cell."""
        grid, s = self.terrain, key.step
        xs = grid.x_coords[[key.col0 * s, (key.col0 + key.cols - 1) * s]]
        ys = grid.y_coords[[key.row0 * s, (key.row0 + key.rows - 1) * s]]
        dx = grid.cell_size[0] * s / u
        dy = grid.cell_size[1] * s / u
        ny, nx = (key.rows - 1) * u + 1, (key.cols - 1) * u + 1
        ox, oy, _ = origin
        return (
            1.0 / (dx * nx),
            1.0 / (dy * ny),
            0.5 / nx - (float(xs.min()) - ox) / (dx * nx),
            0.5 / ny - (float(ys.min()) - oy) / (dy * ny),
        )
