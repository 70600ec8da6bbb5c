"""γ on the texels a node is drawn with: the default γ never turns into a mesh-density rule.

The untextured shading (the normal map) is one texture patch shading every node, so refining
the geometry makes no texel finer: γ refines nothing there, and α alone decides the cut. With
a texture pyramid γ refines only where a descendant's texture patch has finer texels.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from approxtree import ApproximationTree
from approxtree.datasets import fractal_terrain
from approxtree.render import Cut, Engine, FrameState, display_scale, framing_camera, select
from approxtree.render import normal_map as normal_map_module
from approxtree.render.context import create_context
from approxtree.render.normal_map import normal_texels, shading_lattice, shading_texels
from approxtree.render.selector import finer_below

SIZE = (1280, 720)


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the GL tests of this module."""
    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="module")
def tree() -> ApproximationTree:
    """A 513² fractal at ε = 0.5: its cells grow to a few pixels at 1280 × 720."""
    terrain = fractal_terrain(513, seed=3, relief=300.0)
    return ApproximationTree.build(terrain, epsilon=0.5, max_points=33 * 33, progress=False)


def test_default_gamma_lets_alpha_decide_the_cut(gl_context, tree):
    """Untextured, default γ = 2: α 2 and α 4 draw different cuts, each with at most 1.25× the
    triangles of the γ-off cut, and the frame's largest drawn α and γ stay within both
    thresholds."""
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        cam = framing_camera(tree.bboxes[0], eng.scale, SIZE)
        cuts = {}
        for alpha in (2.0, 4.0):
            on = eng.render(cam, SIZE, Cut(alpha=alpha))
            off = eng.render(cam, SIZE, Cut(alpha=alpha, gamma=math.inf))
            assert on.stats["triangles"] <= 1.25 * off.stats["triangles"]
            assert on.stats["max_alpha"] <= alpha
            assert 0.0 < on.stats["max_gamma"] <= Cut().gamma
            cuts[alpha] = on.selection.nodes.tolist()
        assert cuts[2.0] != cuts[4.0]


def test_gamma_refines_nothing_where_no_descendant_has_finer_texels(tree):
    """One texel for every node: a γ threshold far below every γ_N selects the cut of γ off,
    and γ_N is still reported as it is."""
    scale = display_scale(tree.terrain)
    fs = FrameState.from_camera(
        framing_camera(tree.bboxes[0], scale, SIZE), SIZE, tree.bboxes[0], tree.origin, scale
    )
    texels = shading_texels(tree.terrain, len(tree))
    assert not finer_below(tree, texels).any()
    tiny = select(tree, fs, 2.0, 1e-9, texels)
    off = select(tree, fs, 2.0, math.inf, texels)
    assert tiny.nodes.tolist() == off.nodes.tolist()
    assert tiny.stats["max_gamma"] > 1e-9


def test_gamma_refines_down_to_the_finest_texels_only(tree):
    """Texels halving per level down to depth 2, then constant: γ refines to depth 2 where
    it is over the threshold, never deeper for γ's sake."""
    levels = np.asarray(tree.levels)
    base = float(tree.rects[0, 2] - tree.rects[0, 0]) / 16
    side = base / 2.0 ** np.minimum(levels, 2)
    texels = np.column_stack([side, side])
    finer = finer_below(tree, texels)
    assert finer[levels < 2].all() and not finer[levels >= 2].any()
    scale = display_scale(tree.terrain)
    fs = FrameState.from_camera(
        framing_camera(tree.bboxes[0], scale, SIZE), SIZE, tree.bboxes[0], tree.origin, scale
    )
    # α out of the way: only γ decides, and it stops at depth 2 (or a shallower leaf).
    sel = select(tree, fs, 1e9, 1e-9, texels)
    drawn = levels[sel.nodes]
    assert (drawn <= 2).all() and (drawn == 2).any()


def test_small_grids_shade_with_finer_texels_than_their_cells(monkeypatch):
    """A grid within the normal map's side is sampled UPSAMPLE_MAX times finer than its cells
    (bilinear between the data's normals, equal to them on the data lines); a grid over it
    keeps its stride and no upsampling."""
    terrain = fractal_terrain(65, seed=1)
    lattice = shading_lattice(terrain)
    u = normal_map_module.UPSAMPLE_MAX
    assert lattice.upsample == u and lattice.shape == (64 * u + 1, 64 * u + 1)
    cell = abs(terrain.cell_size[0])
    assert lattice.texel == pytest.approx((cell / u, cell / u))
    z = np.asarray(terrain.heights, dtype=np.float64)[::-1]
    xs = np.arange(65) * cell
    fine = normal_texels(z, xs, xs, u)
    np.testing.assert_array_equal(fine[::u, ::u], normal_texels(z, xs, xs))
    # Half way between two data columns: the mean of their normals (to the uint8 rounding).
    mid = (fine[::u, :-u:u].astype(float) + fine[::u, u::u]) / 2
    assert np.abs(fine[::u, u // 2 :: u].astype(float) - mid).max() <= 1.0
    monkeypatch.setattr(normal_map_module, "NORMAL_MAP_MAX", 32)
    strided = shading_lattice(terrain)
    assert strided.upsample == 1 and strided.texel == pytest.approx((3 * cell, 3 * cell))


def test_upsampled_shading_is_only_resampling(gl_context, tree, monkeypatch):
    """The full-resolution frame shaded by the upsampled normal map differs from the one
    shaded at the data's own texels by the shading's resampling only (PSNR > 40 dB)."""
    cam_size = (640, 360)
    images = []
    for upsample in (1, normal_map_module.UPSAMPLE_MAX):
        monkeypatch.setattr(normal_map_module, "UPSAMPLE_MAX", upsample)
        with Engine(tree, context=gl_context, offscreen=True) as eng:
            cam = framing_camera(tree.bboxes[0], eng.scale, cam_size)
            images.append(eng.render(cam, cam_size, Cut(full_resolution=True)).image)
    a, b = (im[..., :3].astype(np.float64) for im in images)
    assert (images[0][..., 3] == images[1][..., 3]).all()
    mse = float(np.mean((a - b) ** 2))
    assert mse == 0.0 or 10 * math.log10(255.0**2 / mse) > 40.0


def test_baked_pyramid_gamma_stops_at_its_finest_level(gl_context, tree, tmp_path):
    """A baked hillshade of 128-texel patches seen from low: γ refines nodes whose descendants
    have finer texels until γ is met, and draws nodes still over γ only at the finest texels
    below them (where refining adds triangles, not texels)."""
    from approxtree.render import Camera
    from approxtree.textures.bake import bake

    pyramid = bake(tree.terrain, tmp_path / "hillshade", max_texture_size=128, gl=False).pyramid
    assert len(pyramid) > 2
    d = tree.terrain.domain
    top = float(tree.bboxes[0, 5])
    low = Camera.look_at((d.xmin, d.ymin, top + 20.0), (*d.center, float(tree.bboxes[0, 2])))
    with Engine(tree, textures=pyramid, context=gl_context, offscreen=True) as eng:
        frame = eng.render(low, (640, 360), Cut(alpha=1e6, gamma=2.0))
        finer = finer_below(tree, eng.texels)
    sel = frame.selection
    over = sel.gammas > 2.0
    assert len(sel.nodes) > 1 and over.any()
    assert not finer[sel.nodes[over]].any()
    # Some of them have children: the texels ran out, not the tree.
    assert (tree.child_count[sel.nodes[over]] > 0).any()
