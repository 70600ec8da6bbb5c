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
from approxtree.render.cache_keys import NODE, MeshKey
from approxtree.render.context import create_context

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
