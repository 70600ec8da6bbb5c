"""Normal patches: the untextured shading of a grid over the normal map's side is a pyramid.

A grid larger than NORMAL_MAP_MAX a side gets a strided normal map, coarser than its data;
each node is then shaded by its normal patch (render/normal_map.py, ``NormalPatches``): the
finest pyramid level's window covering D_N within the texture side, computed from the heights
on demand, shared by descendants within γ. The tests shrink NORMAL_MAP_MAX to 128 so that a
257² fractal is "large" (the side is half the grid's, as 4096 is of an 8193² grid).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from approxtree import ApproximationTree
from approxtree.datasets import fractal_terrain
from approxtree.render import Camera, Cut, Engine, Paging, display_scale, full_resolution
from approxtree.render import normal_map as normal_map_module
from approxtree.render.context import create_context
from approxtree.render.normal_map import NormalKey, NormalPatches, normal_texels, normals

SIZE = (640, 360)
SIDE = 128


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the GL tests of this module."""
    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="module")
def tree() -> ApproximationTree:
    """A 257² fractal at ε = 0.5 with small patches (a deep tree)."""
    terrain = fractal_terrain(257, seed=5, relief=200.0)
    return ApproximationTree.build(terrain, epsilon=0.5, max_points=9 * 9, progress=False)


@pytest.fixture
def small_map(monkeypatch):
    """NORMAL_MAP_MAX = 128: the 257² grid's normal map is strided by 3."""
    monkeypatch.setattr(normal_map_module, "NORMAL_MAP_MAX", SIDE)


def low_camera(tree, corner: float = 0.05, height: float = 0.03) -> Camera:
    """Low over the south-west corner (``corner`` of the width in, ``height`` of it above the
    top), looking across the terrain."""
    x0, y0, z0, x1, y1, z1 = tree.bboxes[0]
    w = max(x1 - x0, y1 - y0)
    return Camera.look_at(
        (x0 + corner * w, y0 + corner * w, z1 + height * w),
        (0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (z0 + z1)),
        fov=45.0,
    )


def test_near_nodes_get_patches_finer_than_the_map(gl_context, tree, small_map):
    """Near the camera the frame shades with normal patches whose texels are finer than the
    strided normal map's (the root's)."""
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        patches = eng.source.shading.normals
        assert patches.active
        frame = eng.render(low_camera(tree), SIZE, Cut(alpha=2.0))
        texels = patches.texels[frame.texture_nodes]
        assert (texels[:, 0] < patches.texels[0, 0]).any()
        assert frame.stats["texture_patches"] > 0
        assert any(isinstance(k, NormalKey) for k in eng.cache.keys())


def test_a_patch_covers_its_node(tree, small_map):
    """Every node's patch window holds the data lines of D_N (up to the level's last line at
    the grid's edge), and its texel is the level's: cell × step / upsample."""
    grid = tree.terrain
    patches = NormalPatches(grid, np.asarray(tree.rects))
    ranges = grid.index_ranges(np.asarray(tree.rects))
    rows, cols = grid.shape
    cell = np.array(grid.cell_size)
    own = np.flatnonzero(patches.levels >= 0)
    assert len(own) > 0 and patches.levels[0] == -1
    for i in own:
        key = patches.key(int(i), 1.0)
        s, u = key.step, key.upsample
        r0, r1, c0, c1 = ranges[i]
        assert key.row0 * s <= r0 and key.col0 * s <= c0
        assert (key.row0 + key.rows - 1) * s >= min(r1, (rows - 1) // s * s)
        assert (key.col0 + key.cols - 1) * s >= min(c1, (cols - 1) // s * s)
        assert max(key.shape) <= SIDE
        np.testing.assert_allclose(patches.texels[i], cell * s / u)


def test_patch_texels_equal_the_whole_level(tree, small_map):
    """A patch computed from its window (with halo) holds the texels of the same lines of the
    level computed over the whole grid, and its uv puts the texel centres on those lines."""
    grid = tree.terrain
    patches = NormalPatches(grid, np.asarray(tree.rects))
    origin = np.asarray(tree.origin)
    scale = np.array([1.0, 1.0, 2.0])
    z = np.asarray(grid.heights, dtype=np.float64)[::-1]  # rows south to north
    xs, ys = grid.x_coords, grid.y_coords[::-1]
    checked = set()
    for i in np.flatnonzero(patches.levels >= 0):
        key = patches.key(int(i), scale[2])
        if (key.step, key.upsample) in checked or key.step != 1:
            continue
        checked.add((key.step, key.upsample))
        u = key.upsample
        whole = normal_texels(z * scale[2], xs - origin[0], ys - origin[1], u)
        # The patch's rows, south to north: raster rows row0 + rows − 1 .. row0.
        south = grid.height - 1 - (key.row0 + key.rows - 1)
        h, w = key.shape
        want = whole[south * u : south * u + h, key.col0 * u : key.col0 * u + w]
        got = patches.texels_of(key, origin, scale)
        np.testing.assert_array_equal(got[..., :2], want)
        t = patches.uv(key, origin)
        x_first = xs[key.col0] - origin[0]
        y_first = ys[south] - origin[1]
        assert x_first * t[0] + t[2] == pytest.approx(0.5 / w)
        assert y_first * t[1] + t[3] == pytest.approx(0.5 / h)
    assert {1} == {s for s, _ in checked} and len(checked) >= 2


def test_descendants_share_an_ancestors_patch(gl_context, tree, small_map):
    """Nodes drawn with an ancestor's patch lie inside that ancestor, and some frame groups
    several meshes under one patch."""
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        frame = eng.render(low_camera(tree), SIZE, Cut(alpha=4.0))
        nodes, owners = frame.selection.nodes, frame.texture_nodes
        shared = np.flatnonzero(owners != nodes)
        assert len(shared) > 0
        parents = np.asarray(tree.parents)
        for j in shared:
            i = int(nodes[j])
            while i >= 0 and i != owners[j]:
                i = int(parents[i])
            assert i == owners[j]
        assert len(set(owners.tolist())) < len(nodes)


def test_gamma_stays_within_its_threshold(gl_context, tree, small_map):
    """From a view whose finest texels suffice, the frame's largest α and γ are within their
    thresholds, with at most 1.25× the triangles of the γ-off cut."""
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        cam = low_camera(tree, 0.0, 0.2)
        on = eng.render(cam, SIZE, Cut(alpha=2.0))
        off = eng.render(cam, SIZE, Cut(alpha=2.0, gamma=math.inf))
        assert on.stats["max_alpha"] <= 2.0
        assert on.stats["max_gamma"] <= Cut().gamma
        assert on.stats["triangles"] <= 1.25 * off.stats["triangles"]
        assert on.stats["texture_patches"] > 0


def test_interactive_frame_stands_in_with_the_map(gl_context, tree, small_map):
    """An interactive frame draws patches not loaded yet with the normal map (key None) and
    requests them; a frame that waits draws them all."""
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        cam, cut = low_camera(tree), Cut(alpha=2.0)
        settled = eng.render(cam, SIZE, cut)
        # The meshes stay resident, the normal patches leave both caches.
        eng.cache.drop(lambda key: isinstance(key, NormalKey))
        eng.provider.drop(lambda key: isinstance(key, NormalKey))
        frame = eng.render(cam, SIZE, cut, paging=Paging(wait=False))
        assert frame.stats["stand_ins"] == 0
        assert frame.stats["texture_stand_ins"] == settled.stats["texture_patches"] > 0
        assert frame.stats["texture_patches"] == 0


def test_exaggeration_makes_new_patches(gl_context, tree, small_map):
    """Patch keys carry the display z scale: a new exaggeration computes new normals."""
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        eng.render(low_camera(tree), SIZE, Cut(alpha=2.0))
        before = {k for k in eng.cache.keys() if isinstance(k, NormalKey)}
        eng.set_vertical_exaggeration(3.0)
        eng.render(low_camera(tree), SIZE, Cut(alpha=2.0))
        after = {k for k in eng.cache.keys() if isinstance(k, NormalKey)} - before
        z = display_scale(tree.terrain)[2]
        assert before and after
        assert [k.zscale for k in before] == pytest.approx([z] * len(before))
        assert [k.zscale for k in after] == pytest.approx([3.0 * z] * len(after))


def test_grids_within_the_map_side_have_no_patches(tree):
    """At the real NORMAL_MAP_MAX a 257² grid is shaded by its one normal map: no patch."""
    patches = NormalPatches(tree.terrain, np.asarray(tree.rects))
    assert not patches.active and (patches.levels == -1).all()
    assert np.ptp(patches.texels, axis=0).max() == 0.0


@pytest.mark.parametrize("uniform", [True, False])
def test_compiled_normals_equal_numpys(uniform):
    """normal_texels (compiled) encodes exactly the numpy normals of ``normals`` (np.gradient
    and the norm), holes included, on uniform and round-off-uneven axes."""
    rng = np.random.default_rng(7)
    z = rng.normal(size=(40, 57)).cumsum(0).cumsum(1)
    z[5, 6] = np.nan
    if uniform:
        xs, ys = np.arange(57) * 2.0, np.arange(40) * 3.0
    else:
        xs, ys = np.arange(57) * 0.7 + 3.1, np.arange(40) * 1.3 - 2.2
    want = np.rint((normals(z, xs, ys)[..., :2] * 0.5 + 0.5) * 255.0).astype(np.uint8)
    np.testing.assert_array_equal(normal_texels(z, xs, ys), want)


def test_uploaded_patch_is_every_upsample_th_texel(tree, small_map):
    """A patch's texture (``upload_texels``) holds its lattice lines' normals, the texels of
    its level at every ``upsample``-th texel, and its uv maps a point to the same place on
    that lattice: the GPU's bilinear filter upsamples as ``normal_texels`` does."""
    patches = NormalPatches(tree.terrain, np.asarray(tree.rects))
    origin = np.asarray(tree.origin)
    scale = np.array([1.0, 1.0, 2.0])
    levels = set()
    for i in np.flatnonzero(patches.levels >= 0):
        key = patches.key(int(i), scale[2])
        if (key.step, key.upsample) in levels:
            continue
        levels.add((key.step, key.upsample))
        u = key.upsample
        level, texture = (
            patches.texels_of(key, origin, scale),
            patches.upload_texels(key, origin, scale),
        )
        assert texture.shape == (key.rows, key.cols, 4)
        np.testing.assert_array_equal(level[::u, ::u], texture)
        a, b = patches.uv(key, origin), patches.upload_uv(key, origin)
        x = float(tree.bboxes[i, 0] - origin[0]) + 1.7
        on_level = (x * a[0] + a[2]) * level.shape[1] - 0.5
        on_texture = (x * b[0] + b[2]) * texture.shape[1] - 0.5
        assert on_level == pytest.approx(u * on_texture)
    assert {u for _, u in levels} >= {1, normal_map_module.PATCH_UPSAMPLE_MAX}


def test_full_resolution_frames_use_normal_patches(gl_context, tree, small_map, monkeypatch):
    """Full-resolution chunks of a grid whose normal map is strided are shaded each by its
    own normal patch (finer than the map), not by the strided map."""
    monkeypatch.setattr(full_resolution, "CHUNK", 33)
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        frame = eng.render(low_camera(tree), SIZE, Cut(full_resolution=True))
        keys = [k for k in eng.cache.keys() if isinstance(k, NormalKey)]
        assert frame.stats["texture_patches"] == len(keys) == frame.stats["patches"] > 1
        map_texel = eng.source.shading.normals.texels[0, 0]
        assert all(k.step * abs(tree.terrain.cell_size[0]) / k.upsample < map_texel for k in keys)


def test_low_view_gamma_within_threshold_with_the_finest_level(
    gl_context, tree, small_map, monkeypatch
):
    """In a low view where the ×4 patches' texels still project over γ, the ×8 level keeps the
    frame's largest γ (and α) within their thresholds at α 2 and 4, with at most 1.25× the
    triangles of the γ-off cut."""
    cam = low_camera(tree, 0.1, 0.1)
    for alpha in (2.0, 4.0):
        with Engine(tree, context=gl_context, offscreen=True) as eng:
            on = eng.render(cam, SIZE, Cut(alpha=alpha))
            off = eng.render(cam, SIZE, Cut(alpha=alpha, gamma=math.inf))
        assert on.stats["max_gamma"] <= Cut().gamma
        assert on.stats["max_alpha"] <= alpha
        assert on.stats["triangles"] <= 1.25 * off.stats["triangles"]
    # The same view without the ×8 level draws γ over the threshold.
    monkeypatch.setattr(normal_map_module, "PATCH_UPSAMPLE_MAX", 4)
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        assert eng.render(cam, SIZE, Cut(alpha=4.0)).stats["max_gamma"] > Cut().gamma


def test_lit_textured_frames_bind_normal_patches(gl_context, tree, small_map, tmp_path):
    """A textured frame lit at runtime lights its groups with normal patches (an unlit one
    computes none), and γ refines wherever the texture or the normal patch runs over γ with a
    finer one of its kind below: every node drawn over γ has neither."""
    from approxtree.render import Style
    from approxtree.render.selector import finer_below
    from approxtree.textures.bake import bake

    pyramid = bake(tree.terrain, tmp_path / "hillshade", max_texture_size=128, gl=False).pyramid
    cam, cut = low_camera(tree, 0.1, 0.1), Cut(alpha=2.0)
    with Engine(tree, textures=pyramid, context=gl_context, offscreen=True) as eng:
        unlit = eng.render(cam, SIZE, cut)
        assert not any(isinstance(k, NormalKey) for k in eng.cache.keys())
        lit = eng.render(cam, SIZE, cut, style=Style(lighting=True))
        assert any(isinstance(k, NormalKey) for k in eng.cache.keys())
        finer = finer_below(tree, eng.texels) | finer_below(tree, eng.source.shading.normals.texels)
    assert not np.array_equal(lit.image, unlit.image)
    assert lit.stats["max_alpha"] <= cut.alpha
    over = lit.selection.nodes[lit.selection.gammas > cut.gamma]
    assert not finer[over].any()


def test_interactive_lit_textured_frame_requests_its_normal_patches(
    gl_context, tree, small_map, tmp_path
):
    """An interactive lit textured frame lights groups whose normal patch is not loaded yet
    with the normal map and requests them; once loaded, a frame binds them."""
    from approxtree.render import Style
    from approxtree.textures.bake import bake

    pyramid = bake(tree.terrain, tmp_path / "hillshade", max_texture_size=128, gl=False).pyramid
    cam, cut, style = low_camera(tree, 0.1, 0.1), Cut(alpha=2.0), Style(lighting=True)
    with Engine(tree, textures=pyramid, context=gl_context, offscreen=True) as eng:
        settled = eng.render(cam, SIZE, cut, style=style)
        bound = {k for k in eng.cache.keys() if isinstance(k, NormalKey)}
        eng.cache.drop(lambda key: isinstance(key, NormalKey))
        eng.provider.drop(lambda key: isinstance(key, NormalKey))
        frame = eng.render(cam, SIZE, cut, style=style, paging=Paging(wait=False))
        assert not any(isinstance(k, NormalKey) for k in eng.cache.keys())
        assert frame.stats["texture_stand_ins"] >= len(bound) > 0
        again = eng.render(cam, SIZE, cut, style=style)
    np.testing.assert_array_equal(again.image, settled.image)
