"""An Engine follows ApproximationTree.update: exact cache invalidation, crack-free frames."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import binary_erosion
from test_update import cell_rect

from approxtree import ApproximationTree
from approxtree.datasets import fractal_terrain
from approxtree.geometry.grid import Grid
from approxtree.render import Camera, Cut, Engine
from approxtree.render.cache_keys import NODE, MeshKey, TextureKey
from approxtree.render.context import create_context
from approxtree.textures.bake import bake
from approxtree.textures.pyramid import TexturePyramid
from approxtree.textures.rebake import rebake

PARAMS = {"epsilon": 0.5, "max_points": 17 * 17}
SIZE = (360, 360)
WINDOW = (100, 120, 40, 48)  # r0, c0, rows, cols


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the module's GL tests."""
    ctx = create_context()
    yield ctx
    ctx.release()


def camera(tree) -> Camera:
    """An oblique view over the whole terrain."""
    c = tree.terrain.domain.center
    return Camera.look_at((c[0] - 300, c[1] - 1400, 1600), (c[0], c[1], 0), fov=60)


def edited(grid: Grid) -> tuple[object, np.ndarray]:
    """(rect, heights) of a mound raised inside the terrain's z range (global figures keep)."""
    r0, c0, rows, cols = WINDOW
    old = np.array(grid.heights[r0 : r0 + rows, c0 : c0 + cols], dtype=np.float64)
    yy, xx = np.mgrid[:rows, :cols]
    mound = 25.0 * np.exp(-(((yy - rows / 2) / 8) ** 2 + ((xx - cols / 2) / 8) ** 2))
    return cell_rect(grid, r0, c0, rows, cols), old + mound


def mesh_nodes(engine: Engine) -> set[int]:
    """Node ids whose meshes are on the GPU."""
    return {k.item for k in engine.cache.keys() if isinstance(k, MeshKey) and k.kind == NODE}


def test_engine_reuploads_exactly_the_changed_nodes(gl_context) -> None:
    """After an update, the next frame uploads only drawn nodes whose payload changed (or
    that were not resident), and every kept payload equals a freshly built one."""
    grid = fractal_terrain(257, seed=5, relief=300.0)
    tree = ApproximationTree.build(grid, **PARAMS)
    eng = Engine(tree, context=gl_context, offscreen=True)
    try:
        cam = camera(tree)
        eng.render(cam, SIZE, Cut(alpha=1.0, gamma=math.inf))
        before = mesh_nodes(eng)
        depths, base = eng.source.skirt_depths.copy(), eng.source.skirt_base
        report = tree.update(*edited(grid))
        eng.follow_tree()
        # The kept meshes: old resident nodes neither rebuilt nor with new skirts.
        new = report.old_to_new
        changed_skirts = {
            int(new[i])
            for i in before
            if new[i] >= 0 and depths[i] != eng.source.skirt_depths[new[i]]
        }
        assert eng.source.skirt_base == base
        kept = {int(new[i]) for i in before if new[i] >= 0} - changed_skirts
        assert mesh_nodes(eng) == kept
        assert eng.update_figures["gpu_dropped"] == len(before) - len(kept) > 0
        uploads = eng.cache.uploads
        frame = eng.render(cam, SIZE, Cut(alpha=1.0, gamma=math.inf))
        drawn = set(frame.selection.nodes.tolist())
        assert eng.cache.uploads - uploads == len(drawn - kept)
        assert drawn & set(report.rebuilt.tolist())
        # Kept CPU payloads are what a load of the updated tree builds now.
        for key in eng.provider.keys():
            if isinstance(key, MeshKey):
                cached = eng.provider.get(key)
                fresh = eng.source._build(key)
                np.testing.assert_array_equal(cached.vertices, fresh.vertices)
    finally:
        eng.release()


def test_updated_frames_equal_a_fresh_engine_and_have_no_cracks(gl_context) -> None:
    """Frames of an engine that followed updates equal a fresh engine's on a fresh build of
    the edited terrain, pixel for pixel, and show no background inside the footprint."""
    grid = fractal_terrain(257, seed=5, relief=300.0)
    tree = ApproximationTree.build(grid, **PARAMS)
    eng = Engine(tree, context=gl_context, offscreen=True)
    fresh_eng = None
    try:
        cam = camera(tree)
        cut = Cut(alpha=1.0, gamma=math.inf)
        eng.render(cam, SIZE, cut)
        tree.update(*edited(grid))
        frame = eng.render(cam, SIZE, cut)
        fresh = ApproximationTree.build(Grid(np.array(grid.heights), grid.transform), **PARAMS)
        fresh_eng = Engine(fresh, context=gl_context, offscreen=True)
        expected = fresh_eng.render(cam, SIZE, cut)
        np.testing.assert_array_equal(frame.selection.nodes, expected.selection.nodes)
        np.testing.assert_array_equal(frame.image, expected.image)
        full = eng.render(cam, SIZE, Cut(full_resolution=True))
        inner = binary_erosion(full.image[..., 3] > 0, iterations=2)
        assert inner.sum() > 30_000
        assert int((inner & (frame.image[..., 3] == 0)).sum()) == 0
    finally:
        eng.release()
        if fresh_eng is not None:
            fresh_eng.release()


TILE = 512  # the pyramid's tile side (textures/pyramid.py)


def texture_keys(keys) -> set[TextureKey]:
    """The TextureKeys among cache keys."""
    return {k for k in keys if isinstance(k, TextureKey)}


def differing_tiles(old: list[np.ndarray], new: list[np.ndarray]) -> list[set]:
    """Per level, the (row, col) 512² tiles whose texels differ between two pyramids' levels
    (whole (h, w, 4) arrays), found by comparing the texels themselves."""
    out = []
    for a, b in zip(old, new, strict=True):
        rows, cols = -(-a.shape[0] // TILE), -(-a.shape[1] // TILE)
        out.append(
            {
                (i, j)
                for i in range(rows)
                for j in range(cols)
                if not np.array_equal(
                    a[i * TILE : (i + 1) * TILE, j * TILE : (j + 1) * TILE],
                    b[i * TILE : (i + 1) * TILE, j * TILE : (j + 1) * TILE],
                )
            }
        )
    return out


def meets(key: TextureKey, tiles: set) -> bool:
    """Whether a texture patch's window meets one of ``tiles`` of its level."""
    rows = range(key.row0 // TILE, (key.row0 + key.height - 1) // TILE + 1)
    cols = range(key.col0 // TILE, (key.col0 + key.width - 1) // TILE + 1)
    return any(i in rows and j in cols for i, j in tiles)


def test_rebake_drops_exactly_the_texture_patches_meeting_changed_tiles(
    gl_context, tmp_path
) -> None:
    """After an update and a re-bake, set_textures drops from the GPU and CPU caches exactly
    the texture patches meeting a tile whose texels changed (found by comparing the levels),
    and the next frame equals a fresh Engine's on a fresh build and bake, pixel for pixel,
    within α and without cracks."""
    grid = fractal_terrain(513, seed=7, relief=300.0)
    tree = ApproximationTree.build(grid, **PARAMS)
    # Half-cell texels: level 0 is 1026² texels (3 × 3 tiles), three levels.
    texel = abs(grid.transform.a) / 2
    pyramid = bake(grid, tmp_path / "tex", gl=False, texel_size=texel, max_texture_size=512)
    pyramid = pyramid.pyramid
    eng = Engine(tree, textures=pyramid, context=gl_context, offscreen=True)
    fresh_eng = None
    try:
        c = tree.terrain.domain.center
        cams = [
            Camera.look_at((c[0] - 300, c[1] - 2600, 2400), (c[0], c[1], 0), fov=60),
            Camera.look_at((c[0] + 900, c[1] + 700, 900), (c[0] + 1500, c[1] + 1500, 0), fov=50),
        ]
        cut = Cut(alpha=1.0, gamma=1.0)
        for cam in cams:
            eng.render(cam, SIZE, cut)
        gpu_before = texture_keys(eng.cache.keys())
        cpu_before = texture_keys(eng.provider.keys())
        old_levels = [pyramid.level(k) for k in range(len(pyramid))]
        # A mound in the south-west quarter: only some tiles of each level change.
        r0, c0, rows, cols = 300, 60, 60, 70
        heights = np.array(grid.heights[r0 : r0 + rows, c0 : c0 + cols], dtype=np.float64)
        yy, xx = np.mgrid[:rows, :cols]
        heights += 30.0 * np.exp(-(((yy - rows / 2) / 10) ** 2 + ((xx - cols / 2) / 10) ** 2))
        rect = cell_rect(grid, r0, c0, rows, cols)
        tree.update(rect, heights)
        done = rebake(pyramid.folder, tree.terrain, rect)
        new_levels = [done.pyramid.level(k) for k in range(len(done.pyramid))]
        changed = differing_tiles(old_levels, new_levels)
        assert all(len(t) <= n for t, n in zip(changed, done.tiles, strict=True))
        assert any(changed) and sum(map(len, changed)) < sum(done.tiles_total)
        eng.set_textures(done.pyramid)
        # Exactly the patches meeting a changed tile of their own level left each cache.
        for before, after in (
            (gpu_before, texture_keys(eng.cache.keys())),
            (cpu_before, texture_keys(eng.provider.keys())),
        ):
            stale = {k for k in before if meets(k, changed[k.level])}
            assert stale and before - stale
            assert after == before - stale
        assert eng.update_figures["texture_gpu_dropped"] == len(
            {k for k in gpu_before if meets(k, changed[k.level])}
        )
        fresh = ApproximationTree.build(Grid(np.array(grid.heights), grid.transform), **PARAMS)
        fresh_eng = Engine(
            fresh, textures=TexturePyramid(pyramid.folder), context=gl_context, offscreen=True
        )
        for cam in cams:
            frame = eng.render(cam, SIZE, cut)
            expected = fresh_eng.render(cam, SIZE, cut)
            np.testing.assert_array_equal(frame.selection.nodes, expected.selection.nodes)
            np.testing.assert_array_equal(frame.image, expected.image)
            assert frame.selection.stats["max_alpha"] <= cut.alpha
            full = eng.render(cam, SIZE, Cut(full_resolution=True))
            inner = binary_erosion(full.image[..., 3] > 0, iterations=2)
            assert int((inner & (frame.image[..., 3] == 0)).sum()) == 0
    finally:
        eng.release()
        if fresh_eng is not None:
            fresh_eng.release()
