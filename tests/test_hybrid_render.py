"""Hybrid trees (grid and TIN nodes side by side) render without cracks: skirts hang across
strategy boundaries exactly as across resolution boundaries."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import binary_erosion
from test_render import gl_context, holes_in_footprint  # noqa: F401 (shared GL fixture)

from approxtree import ApproximationTree, GridRefinement
from approxtree.datasets import case_study_terrain, fractal_terrain
from approxtree.render import Camera, Cut, Engine


def strategies_drawn(tree: ApproximationTree, nodes: np.ndarray) -> set[str]:
    return {tree.strategy_names[int(s)] for s in tree.strategies[nodes]}


def test_no_cracks_in_a_hybrid_grid_and_tin_tree(gl_context):  # noqa: F811
    """level:grid@0-3,tin with exact leaves: mixed grid/tin nodes on screen, 0 background
    pixels inside the terrain's footprint with skirts (and cracks without them)."""
    terrain = fractal_terrain(257, seed=5, relief=300.0)
    tree = ApproximationTree.build(
        terrain, epsilon=0.0, max_points=17 * 17, policy="level:grid@0-3,tin", progress=False
    )
    assert set(tree.strategy_counts) == {"grid", "tin"}
    eng = Engine(tree, context=gl_context, offscreen=True)
    try:
        c = terrain.domain.center
        cam = Camera.look_at((c[0] - 300, c[1] - 1400, 1600), (c[0], c[1], 0), fov=60)
        lod = eng.render(cam, (400, 400), Cut(alpha=1.0, gamma=math.inf))
    finally:
        eng.release()
    assert strategies_drawn(tree, lod.selection.nodes) == {"grid", "tin"}
    holes, footprint, levels = holes_in_footprint(gl_context, tree, skirts=True)
    assert levels >= 2 and footprint > 50_000
    assert holes == 0
    holes_without, _, _ = holes_in_footprint(gl_context, tree, skirts=False)
    assert holes_without > 0


@pytest.mark.parametrize("alpha", [1.0, 4.0])
def test_no_cracks_in_a_grid_refinement_tree(gl_context, alpha):  # noqa: F811
    """Grid nodes beside microstructure TIN nodes (semantic:tin@2,grid) leave no background
    pixel inside the footprint of the full-resolution terrain (without skirts they do)."""
    grid, tins = case_study_terrain(seed=4, rows=81, cols=161, microstructures=600)
    tree = ApproximationTree.build(
        GridRefinement(grid, tins), 0.5, 9 * 9, policy="semantic:tin@2,grid", progress=False
    )
    d = tree.terrain.domain
    (cx, cy), z0 = d.center, tree.terrain.z_range[1]
    cam = Camera.look_at(
        (cx - 0.1 * d.width, cy - 1.2 * d.height, z0 + 0.3 * d.width), (cx, cy, z0 - 300), fov=60
    )
    holes = {}
    for skirts in (True, False):
        eng = Engine(tree, context=gl_context, offscreen=True, skirts=skirts)
        try:
            full = eng.render(cam, (480, 360), Cut(full_resolution=True))
            lod = eng.render(cam, (480, 360), Cut(alpha=alpha, gamma=math.inf))
        finally:
            eng.release()
        assert strategies_drawn(tree, lod.selection.nodes) == {"grid", "tin"}
        inner = binary_erosion(full.image[..., 3] > 0, iterations=2)
        assert inner.sum() > 40_000
        holes[skirts] = int((inner & (lod.image[..., 3] == 0)).sum())
    assert holes[True] == 0
    assert holes[False] > 0
