"""The grid patch error kernel against independent recomputations.

``grid_patch_errors`` evaluates the patch row by row in branch-free runs (one per triangle of a
block), folds the rows column-wise and cuts coarse levels into bands of block rows. The errors
must stay exact: the true maximum of |z − h_TN| over every data point, with the patch heights
computed by the same float operations as the per-point reference. Here they are recomputed
with numpy, point by point, on random rasters (float32 and float64, odd sizes, last blocks
narrower than the step), and the per-point reference path (``_patch_error``) checks rasters
with nodata holes and ties of +0.0 and −0.0 at the z range's ends.
"""

from __future__ import annotations

import numpy as np
import pytest

from approxtree.kernels.grid_patch import _patch_error, grid_patch_errors


def _numpy_error(z: np.ndarray, r0: int, r1: int, c0: int, c1: int, sr: int, sc: int) -> float:
    """max |z − h_TN| over the non-vertex points of one patch of a raster without nodata."""

    def axis(lo: int, hi: int, step: int) -> tuple[np.ndarray, ...]:
        # Block index, block start, block end and offset of every line lo .. hi.
        idx = np.arange(lo, hi + 1)
        nb = (hi - lo + step - 1) // step
        k = np.minimum((idx - lo) // step, nb - 1)
        b = lo + k * step
        e = np.minimum(b + step, hi)
        return idx, b, e, idx - b

    r, rb, re, dr = (a[:, None] for a in axis(r0, r1, sr))
    c, cb, ce, dc = (a[None, :] for a in axis(c0, c1, sc))
    hr, wc = re - rb, ce - cb
    z64 = z.astype(np.float64)
    z00, z01, z10, z11 = z64[rb, cb], z64[rb, ce], z64[re, cb], z64[re, ce]
    # Same operands and order as the kernel, all in float64 whatever the raster's dtype (a
    # float32 corner difference is rounded: claimed errors fell short of the true ones).
    pa = z00 + (dc / wc) * (z01 - z00) + (dr / hr) * (z11 - z01)
    pb = z00 + (dr / hr) * (z10 - z00) + (dc / wc) * (z11 - z10)
    p = np.where(dc * hr >= dr * wc, pa, pb)
    vertex = ((dr == 0) | (r == re)) & ((dc == 0) | (c == ce))
    e = np.abs(z[r, c] - p)
    return float(np.max(np.where(vertex, 0.0, e)))


def _random_patches(rng: np.random.Generator, rows: int, cols: int, k: int, max_step: int):
    r0 = rng.integers(0, rows - 1, k)
    r1 = np.array([rng.integers(a + 1, rows) for a in r0])
    c0 = rng.integers(0, cols - 1, k)
    c1 = np.array([rng.integers(a + 1, cols) for a in c0])
    ranges = np.column_stack([r0, r1, c0, c1]).astype(np.int64)
    steps = rng.integers(1, max_step + 1, (k, 2)).astype(np.int64)
    return ranges, steps


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_errors_equal_numpy_recomputation(dtype: type) -> None:
    rng = np.random.default_rng(15)
    for rows, cols in [(97, 131), (300, 41), (2, 257)]:
        z = (rng.standard_normal((rows, cols)) * 50.0).astype(dtype)
        ranges, steps = _random_patches(rng, rows, cols, 40, 40)
        # The whole raster at a coarse step: one node, cut into bands of rows.
        ranges = np.vstack([ranges, [[0, rows - 1, 0, cols - 1]]])
        steps = np.vstack([steps, [[max(1, rows // 3), max(1, cols // 5)]]])
        err, zmin, zmax, count = grid_patch_errors(z, ranges, steps)
        for i, (r0, r1, c0, c1) in enumerate(ranges):
            sr, sc = steps[i]
            want = _numpy_error(z, r0, r1, c0, c1, sr, sc)
            assert err[i] == want, (i, ranges[i], steps[i])
            block = z[r0 : r1 + 1, c0 : c1 + 1]
            assert zmin[i] == block.min() and zmax[i] == block.max()
            assert count[i] == block.size


def test_step_one_patches_hold_every_point() -> None:
    # Every point is a vertex: error 0, even over nodata, while the z range is still measured.
    rng = np.random.default_rng(3)
    z = rng.standard_normal((40, 50))
    z[rng.random(z.shape) < 0.3] = np.nan
    ranges, _ = _random_patches(rng, 40, 50, 30, 1)
    err, zmin, zmax, count = grid_patch_errors(z, ranges, np.ones_like(ranges[:, :2]))
    assert np.all(err == 0.0)
    for i, (r0, r1, c0, c1) in enumerate(ranges):
        block = z[r0 : r1 + 1, c0 : c1 + 1]
        assert count[i] == np.count_nonzero(~np.isnan(block))
        if count[i]:
            assert zmin[i] == np.nanmin(block) and zmax[i] == np.nanmax(block)


def _reference(z: np.ndarray, ranges: np.ndarray, steps: np.ndarray) -> np.ndarray:
    out = np.empty((len(ranges), 4))
    for i, (r0, r1, c0, c1) in enumerate(ranges):
        e, lo, hi, k = _patch_error(z, r0, r1, c0, c1, steps[i, 0], steps[i, 1])
        out[i] = (e, lo if k else np.nan, hi if k else np.nan, k)
    return out


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_nodata_and_signed_zeros_match_reference_bits(dtype: type) -> None:
    rng = np.random.default_rng(7)
    for trial in range(30):
        rows, cols = rng.integers(2, 90, 2)
        z = np.abs(rng.standard_normal((rows, cols)) * 20.0).astype(dtype)
        # Holes of nodata, and +0.0 / −0.0 at the low end (the z range's first zero wins).
        z[rng.random(z.shape) < rng.random() * 0.25] = np.nan
        z[rng.random(z.shape) < 0.05] = 0.0
        z[rng.random(z.shape) < 0.05] = -0.0
        if trial % 2:
            z = -z
        ranges, steps = _random_patches(rng, rows, cols, 25, 30)
        got = np.column_stack(grid_patch_errors(z, ranges, steps)).astype(np.float64)
        want = _reference(z, ranges, steps)
        assert np.array_equal(got.view(np.int64), want.view(np.int64)), trial
        # A hole under a drawn triangle is infinite error, never a finite one.
        assert np.all(np.isinf(got[:, 0]) | np.isfinite(got[:, 0]))
