"""Hashed gradient noise: heights as a pure function of (row, col, seed), block by block.

Each octave is 2-D gradient (Perlin) noise on a lattice of ``wavelength`` cells: the gradient at
a lattice point comes from a 64-bit hash of (lattice x, lattice y, octave salt), so any window
of any raster is computed on its own, with no state shared between blocks, and a window of a
big raster equals the same window of a small one bit for bit. The kernels release the GIL, so
dask threads compute blocks in parallel.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_M1 = np.uint64(0x9E3779B97F4A7C15)
_M2 = np.uint64(0xC2B2AE3D27D4EB4F)
_M3 = np.uint64(0xFF51AFD7ED558CCD)
_M4 = np.uint64(0xC4CEB9FE1A85EC53)
_S33 = np.uint64(33)
_S7 = np.uint64(7)

# Eight unit gradients (the axes and diagonals), picked by three bits of the hash.
_D = 0.7071067811865476
_GX = np.array([1.0, -1.0, 0.0, 0.0, _D, -_D, _D, -_D])
_GY = np.array([0.0, 0.0, 1.0, -1.0, _D, _D, -_D, -_D])


@njit(cache=True, inline="always")
def mix64(h: np.uint64) -> np.uint64:
    """The murmur3 / splitmix finaliser: every input bit flips half the output bits."""
    h ^= h >> _S33
    h *= _M3
    h ^= h >> _S33
    h *= _M4
    h ^= h >> _S33
    return h


@njit(cache=True, inline="always")
def _corner(ix: np.int64, iy: np.int64, salt: np.uint64) -> np.int64:
    """Index (0..7) of the gradient at lattice point (ix, iy) of the octave with ``salt``."""
    h = mix64(np.uint64(ix) * _M1 ^ mix64(np.uint64(iy) * _M2 ^ salt))
    return np.int64(h & _S7)


@njit(cache=True, inline="always")
def _fade(t: float) -> float:
    """Perlin's quintic fade: C2 continuous at the lattice lines."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@njit(cache=True, nogil=True)
def gradient_noise_block(
    row0: int,
    col0: int,
    out: np.ndarray,
    wavelengths: np.ndarray,
    amplitudes: np.ndarray,
    offsets: np.ndarray,
    salts: np.ndarray,
    base: float,
) -> None:
    """Sum of octaves over the window whose top-left cell is (row0, col0), written into out.

    out: (rows, cols) float32 or float64, overwritten with base + Σ_k a_k · noise_k.
    wavelengths, amplitudes: (K,) float64, lattice spacing in cells and amplitude of octave k;
    offsets: (K, 2) float64 lattice shift (cells, rows) of octave k, so the octaves' lattice
    points (where gradient noise is 0) do not line up; salts: (K,) uint64 hash salts.
    Noise of one octave lies within about ±0.7.
    """
    rows, cols = out.shape
    gx = _GX
    gy = _GY
    acc = np.empty(cols)
    for i in range(rows):
        acc[:] = base
        for k in range(wavelengths.size):
            inv = 1.0 / wavelengths[k]
            amp = amplitudes[k]
            salt = salts[k]
            # The row's lattice line and fade are the same for every column of the octave.
            y = (row0 + i + offsets[k, 1]) * inv
            fy = np.floor(y)
            iy = np.int64(fy)
            ty = y - fy
            v = _fade(ty)
            ix_cached = np.int64(-(2**62))
            g00x = g00y = g10x = g10y = g01x = g01y = g11x = g11y = 0.0
            for j in range(cols):
                x = (col0 + j + offsets[k, 0]) * inv
                fx = np.floor(x)
                ix = np.int64(fx)
                tx = x - fx
                # Long wavelengths cross a lattice line rarely: hash only when they do.
                if ix != ix_cached:
                    ix_cached = ix
                    a = _corner(ix, iy, salt)
                    b = _corner(ix + 1, iy, salt)
                    c = _corner(ix, iy + 1, salt)
                    d = _corner(ix + 1, iy + 1, salt)
                    g00x, g00y = gx[a], gy[a]
                    g10x, g10y = gx[b], gy[b]
                    g01x, g01y = gx[c], gy[c]
                    g11x, g11y = gx[d], gy[d]
                n00 = g00x * tx + g00y * ty
                n10 = g10x * (tx - 1.0) + g10y * ty
                n01 = g01x * tx + g01y * (ty - 1.0)
                n11 = g11x * (tx - 1.0) + g11y * (ty - 1.0)
                u = _fade(tx)
                top = n00 + u * (n10 - n00)
                bottom = n01 + u * (n11 - n01)
                acc[j] += amp * (top + v * (bottom - top))
        for j in range(cols):
            out[i, j] = acc[j]
