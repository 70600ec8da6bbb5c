"""Holes look like holes: around nodata the LOD frame is as see-through as the full terrain.

Skirts hang only from node borders (never along nodata), and no patch covers a nodata point
with a triangle. Checked on real DEMs with voids: the same view drawn at α = 1 and at full
resolution shows the same number of background pixels around a void (within 10 %), and no
drawn pixel of the LOD frame lies over a void cell (its world x, y from the position buffer;
the one-cell ring around a void, where the full terrain's own triangles end, is allowed).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import data_file
from scipy import ndimage
from test_render import gl_context  # noqa: F401 (shared GL fixture)

import approxtree as at
from approxtree import ApproximationTree
from approxtree.geometry.grid import Grid
from approxtree.render import Camera, Cut, Engine
from approxtree.render.frame_state import display_scale

#: (file, crop rows r0:r1 and columns c0:c1 or None, void window (r0, r1, c0, c1) to frame).
VOIDS = {
    # SRTM voids in Kauai's mountains (709 and 583 cells side by side).
    "kauai": ("srtm/N22W160v2.3a.hgt.zip", (900, 1200, 300, 700), (95, 160, 72, 236)),
    # The no-data corner of a USGS DEM quadrangle.
    "helens": ("edge/SainteHelens.dem", None, None),
    # Small holes in a 2 m lidar DTM (48 cells) and along its south border.
    "dtm": ("edge/dtm.tif", None, (91, 101, 183, 190)),
    # A coast: NaN sea beside land, and a lake.
    "nz": ("edge/nz_elev.tif", (650, 850, 700, 900), (102, 113, 86, 98)),
    # Luxembourg inside its nodata surroundings.
    "lux": ("roads/lux_elev.tif", None, None),
    # A survey site inside nodata.
    "hugo": ("edge/hugo_site.asc", None, None),
}
SIZE = (320, 240)


def void_terrain(data_dir, name: str) -> Grid:
    relative, crop, _ = VOIDS[name]
    grid = at.open_terrain(data_file(data_dir, relative))
    if crop is not None:
        r0, r1, c0, c1 = crop
        t = grid.transform @ grid.transform.translation(c0, r0)
        grid = Grid(grid.heights[r0:r1, c0:c1], t, grid.crs)
    return grid


def void_window(grid: Grid, name: str) -> tuple[int, int, int, int]:
    """(r0, r1, c0, c1) of the void to look at: given, or the largest nodata region."""
    window = VOIDS[name][2]
    if window is not None:
        return window
    labels, n = ndimage.label(~np.isfinite(grid.heights))
    sizes = ndimage.sum(labels > 0, labels, range(1, n + 1))
    sl = ndimage.find_objects(labels)[int(np.argmax(sizes))]
    return sl[0].start, sl[0].stop, sl[1].start, sl[1].stop


def views(grid: Grid, window: tuple[int, int, int, int]) -> dict[str, tuple[Camera, tuple]]:
    """Top-down and oblique cameras on the void window padded by half its size (clipped to
    the grid), each with that padded window (r0, r1, c0, c1)."""
    r0, r1, c0, c1 = window
    pad = max(r1 - r0, c1 - c0) // 2 + 3
    rows, cols = grid.shape
    r0, r1 = max(r0 - pad, 0), min(r1 + pad, rows - 1)
    c0, c1 = max(c0 - pad, 0), min(c1 + pad, cols - 1)
    xa, ya = grid.transform @ (c0, r0)
    xb, yb = grid.transform @ (c1, r1)
    cx, cy = (xa + xb) / 2, (ya + yb) / 2
    s = display_scale(grid)
    half = max(abs(xb - xa) * s[0], abs(yb - ya) * s[1]) / 2
    z0, z1 = grid.z_range
    top = Camera.look_at(
        (cx, cy, z1 + half / math.tan(math.radians(20))), (cx, cy, z0), fov=40, up=(0, 1, 0)
    )
    d = 2.2 * half
    oblique = Camera.look_at((cx, cy - 0.8 * d / s[1], z1 + 0.6 * d), (cx, cy, (z0 + z1) / 2), 50)
    return {"top": (top, (r0, r1, c0, c1)), "oblique": (oblique, (r0, r1, c0, c1))}


def around(frame, grid: Grid, window: tuple[int, int, int, int]) -> np.ndarray:
    """(h, w) bool: pixels whose ray meets the plane at the window's median height inside
    the window — the image of the void and its surroundings, wherever terrain is drawn."""
    r0, r1, c0, c1 = window
    z = grid.heights[r0 : r1 + 1, c0 : c1 + 1]
    zref = float(np.nanmedian(z))
    fs = frame.frame_state
    w, h = fs.viewport
    inv = np.linalg.inv(fs.world_to_clip)
    px, py = np.meshgrid((np.arange(w) + 0.5) / w * 2 - 1, 1 - (np.arange(h) + 0.5) / h * 2)
    ends = []
    for zn in (-1.0, 1.0):
        p = np.stack([px, py, np.full_like(px, zn), np.ones_like(px)], axis=-1) @ inv.T
        ends.append(p[..., :3] / p[..., 3:])
    a, b = ends
    t = (zref - a[..., 2]) / (b[..., 2] - a[..., 2])
    x = a[..., 0] + t * (b[..., 0] - a[..., 0])
    y = a[..., 1] + t * (b[..., 1] - a[..., 1])
    fr, fc = grid.fractional_index(x, y)
    return (t > 0) & (fr >= r0) & (fr <= r1) & (fc >= c0) & (fc <= c1)


def over_void(frame, grid: Grid) -> int:
    """Drawn pixels (surface or skirt) whose nearest data point is nodata, the one-cell ring
    around each void left out."""
    pos = frame.positions
    drawn = pos[..., 3] > -0.5
    fr, fc = grid.fractional_index(pos[..., 0][drawn], pos[..., 1][drawn])
    rows, cols = grid.shape
    r = np.clip(np.rint(fr).astype(np.int64), 0, rows - 1)
    c = np.clip(np.rint(fc).astype(np.int64), 0, cols - 1)
    core = ndimage.binary_erosion(~np.isfinite(grid.heights), np.ones((3, 3)), border_value=1)
    return int(np.count_nonzero(core[r, c]))


@pytest.mark.parametrize("name", list(VOIDS))
def test_voids_are_as_see_through_at_alpha_1_as_at_full_resolution(
    gl_context,  # noqa: F811
    data_dir,
    name,
):
    """Background pixels around a void: LOD (α = 1) within 10 % of full resolution, in a
    top-down and an oblique view; no LOD pixel lies over a void cell."""
    grid = void_terrain(data_dir, name)
    tree = ApproximationTree.build(grid, epsilon=1.0, progress=False)
    eng = Engine(tree, context=gl_context, offscreen=True)
    try:
        for view, (camera, window) in views(grid, void_window(grid, name)).items():
            full = eng.render(camera, SIZE, Cut(full_resolution=True))
            eng.world_positions(full)
            lod = eng.render(camera, SIZE, Cut(alpha=1.0, gamma=math.inf))
            eng.world_positions(lod)
            roi = around(full, grid, window)
            bg_full = int(np.count_nonzero(roi & (full.image[..., 3] == 0)))
            bg_lod = int(np.count_nonzero(roi & (lod.image[..., 3] == 0)))
            assert bg_full >= 100, (name, view, bg_full)
            assert abs(bg_lod - bg_full) <= 0.1 * bg_full, (name, view, bg_full, bg_lod)
            assert (over_void(full, grid), over_void(lod, grid)) == (0, 0), (name, view)
    finally:
        eng.release()


@pytest.mark.parametrize("strategy", ["grid", "nonregular", "tin", "rtin"])
def test_no_patch_covers_nodata(data_dir, strategy):
    """Coarse patches (s = 9², ε = 20 m) over Kauai's voids: every node a cut may draw (finite
    ε_T(N)) leaves each nodata point of its rectangle outside its triangles."""
    from helpers import nodata_points
    from matplotlib.tri import Triangulation

    grid = void_terrain(data_dir, "kauai")
    r0, r1, c0, c1 = 60, 200, 40, 260
    t = grid.transform @ grid.transform.translation(c0, r0)
    grid = Grid(grid.heights[r0:r1, c0:c1], t, grid.crs)
    tree = ApproximationTree.build(
        grid, epsilon=20.0, max_points=9 * 9, policy=strategy, progress=False
    )
    checked = 0
    for i in np.flatnonzero(np.isfinite(tree.errors)):
        patch = tree.patch(int(i))
        holes = nodata_points(grid, patch.rect)
        if len(holes) == 0 or len(patch.triangles) == 0:
            continue
        v = patch.vertices
        found = Triangulation(v[:, 0], v[:, 1], patch.triangles).get_trifinder()(
            holes[:, 0], holes[:, 1]
        )
        assert (found < 0).all(), (strategy, int(i), int(np.count_nonzero(found >= 0)))
        checked += 1
    assert checked > 0


@pytest.mark.parametrize("alpha", [1.0, 8.0])
def test_coarse_cuts_draw_nothing_over_voids(gl_context, data_dir, alpha):  # noqa: F811
    """A coarse tree (s = 9², ε = 20 m) cut at α = 1 and 8, top-down and oblique: no drawn
    pixel lies over a void cell of Kauai."""
    grid = void_terrain(data_dir, "kauai")
    tree = ApproximationTree.build(grid, epsilon=20.0, max_points=9 * 9, progress=False)
    eng = Engine(tree, context=gl_context, offscreen=True)
    try:
        for view, (camera, _) in views(grid, void_window(grid, "kauai")).items():
            lod = eng.render(camera, SIZE, Cut(alpha=alpha, gamma=math.inf))
            eng.world_positions(lod)
            assert lod.stats["triangles"] > 0
            bad = over_void(lod, grid)
            assert bad == 0, (view, alpha, bad)
    finally:
        eng.release()


def test_neighbour_errors_match_brute_force():
    """kernels.rect_neighbours: per node, the largest finite error of the nodes touching a
    side of its rectangle from outside along a stretch — against a double loop over pairs."""
    from approxtree.datasets import fractal_terrain
    from approxtree.kernels.rect_neighbours import neighbour_max_errors

    heights = fractal_terrain(65, seed=3, relief=200.0).heights.copy()
    heights[20:30, 35:41] = np.nan  # some nodes of infinite error
    tree = ApproximationTree.build(Grid(heights), epsilon=0.5, max_points=5 * 5, progress=False)
    rects = np.asarray(tree.rects, dtype=np.float64)
    errors = tree.errors
    assert np.isinf(errors).any() and len(tree) > 50
    expected = np.zeros(len(tree))
    for a, (ax0, ay0, ax1, ay1) in enumerate(rects):
        for b, (bx0, by0, bx1, by1) in enumerate(rects):
            side_x = (ax1 == bx0 or bx1 == ax0) and min(ay1, by1) > max(ay0, by0)
            side_y = (ay1 == by0 or by1 == ay0) and min(ax1, bx1) > max(ax0, bx0)
            if (side_x or side_y) and np.isfinite(errors[b]):
                expected[a] = max(expected[a], errors[b])
    got = neighbour_max_errors(rects, np.asarray(errors, dtype=np.float64))
    np.testing.assert_array_equal(got, expected)
    assert (got < np.nanmax(np.where(np.isfinite(errors), errors, np.nan))).any()
