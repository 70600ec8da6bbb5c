"""Textured rendering: texture patches per node, ancestor sharing, decal/lit drawing, land use.

GL tests share one EGL context; where EGL is missing they fail with the install hint.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from conftest import data_file
from scipy.ndimage import maximum_filter, minimum_filter

import approxtree as at
from approxtree import ApproximationTree, InvalidParameterError
from approxtree.cli import main as cli_main
from approxtree.datasets import fractal_terrain
from approxtree.render import Camera, Cut, Engine, Style, overview_camera, select
from approxtree.render.context import create_context
from approxtree.render.frame import STAT_KEYS
from approxtree.render.selector import SelectionResult
from approxtree.render.texture_sharing import texture_nodes
from approxtree.textures import TexturePatch, TexturePyramid, TopographicShading
from approxtree.textures.bake import bake
from approxtree.textures.patch import patch_levels, patch_texel_sizes
from approxtree.textures.thematic import ClassTable


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the GL tests of this module."""
    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="module")
def terrain():
    return fractal_terrain(513, seed=3, relief=300.0)


@pytest.fixture(scope="module")
def tree(terrain) -> ApproximationTree:
    return ApproximationTree.build(terrain, epsilon=1.0, max_points=33 * 33, progress=False)


@pytest.fixture(scope="module")
def pyramid(terrain, tmp_path_factory) -> TexturePyramid:
    """A hillshade pyramid of the 513² fractal with a 128-texel limit (4 levels)."""
    folder = tmp_path_factory.mktemp("pyramid")
    return TexturePyramid.build(TopographicShading(terrain), folder, max_texture_size=128)


def views(tree) -> list[Camera]:
    """An overview and two low oblique views close to the terrain."""
    c = tree.terrain.domain.center
    box = tree.bboxes[0]
    return [
        overview_camera(box, np.ones(3)),
        Camera.look_at((c[0] - 500, c[1] - 3000, 900), (c[0], c[1], 0), fov=60),
        Camera.look_at((c[0] + 1500, c[1] + 200, 400), (c[0] - 1000, c[1], 0), fov=50),
    ]


def test_patch_levels_equal_for_rect_and_patches_are_well_formed(tree, pyramid):
    """Per node: the vectorized level equals for_rect's; power-of-two size within the limit;
    the patch covers D_N; the level is the finest whose exact cover fits the limit."""
    levels = patch_levels(pyramid, tree.rects)
    texels = patch_texel_sizes(pyramid, tree.rects)
    limit = pyramid.max_texture_size
    for i, node in enumerate(tree.nodes()):
        patch = TexturePatch.for_rect(pyramid, node.rect)
        assert patch.level == levels[i]
        assert patch.texel_size == tuple(texels[i])
        assert patch.width & (patch.width - 1) == 0 and patch.height & (patch.height - 1) == 0
        assert max(patch.width, patch.height) <= limit
        e, r = patch.extent, node.rect
        assert e.xmin <= r.xmin and e.ymin <= r.ymin and e.xmax >= r.xmax and e.ymax >= r.ymax
        if patch.level > 0:
            finer = pyramid.levels[patch.level - 1]
            span = max(r.width / finer.texel_size[0], r.height / finer.texel_size[1])
            assert span > limit - 2
    assert set(levels.tolist()) >= {0, 2}


def test_gamma_follows_the_texture_patch(tree, pyramid):
    """With a pyramid, selection's γ uses the texture patch texels: the root's texel is the
    coarse level's, and γ_root scales with the texel area (up to perspective)."""
    texels = patch_texel_sizes(pyramid, tree.rects)
    assert tuple(texels[0]) == pyramid.levels[-1].texel_size
    cam = views(tree)[0]
    from approxtree.render.frame_state import FrameState
    from approxtree.render.visual_error import texel_sizes, visual_errors

    fs = FrameState.from_camera(cam, (400, 300), tree.bboxes[0], tree.origin, np.ones(3))
    _, g_tex = visual_errors(tree.bboxes[:1], tree.errors[:1], texels[:1], fs)
    data = texel_sizes(tree)
    _, g_data = visual_errors(tree.bboxes[:1], tree.errors[:1], data[:1], fs)
    ratio = np.prod(texels[0]) / np.prod(data[0])
    assert g_tex[0] == pytest.approx(g_data[0] * ratio, rel=1e-3)
    assert abs(ratio - 1.0) > 0.5


@pytest.mark.parametrize(("alpha", "gamma"), [(0.1, 4.0), (0.5, 1.0), (2.0, 0.5)])
def test_shared_textures_stay_within_gamma(tree, pyramid, alpha, gamma):
    """A selected node textured by an ancestor gets the ancestor closest to the root whose γ
    is within the threshold; every shared γ is <= gamma, and sharing never adds patches."""
    from approxtree.render.frame_state import FrameState

    texels = patch_texel_sizes(pyramid, tree.rects)
    shared_any = False
    for cam in views(tree):
        fs = FrameState.from_camera(cam, (640, 480), tree.bboxes[0], tree.origin, np.ones(3))
        sel = select(tree, fs, alpha, gamma, texels)
        owners, gammas = texture_nodes(tree.parents, sel, gamma)
        own, _ = texture_nodes(tree.parents, sel, gamma, share=False)
        assert np.array_equal(own, sel.nodes)
        g_of = dict(zip(sel.visited.tolist(), sel.visited_gammas.tolist(), strict=True))
        for node, owner, g in zip(sel.nodes, owners, gammas, strict=True):
            # Walk from the root to the node: the owner is the first ancestor within gamma.
            path = [int(node)]
            while tree.parents[path[-1]] >= 0:
                path.append(int(tree.parents[path[-1]]))
            path = path[::-1]
            ok = [a for a in path[:-1] if g_of[a] <= gamma]
            assert owner == (ok[0] if ok else node)
            if owner != node:
                shared_any = True
                assert g <= gamma and g == g_of[int(owner)]
                assert sel.result_of(int(owner)) == SelectionResult.REFINED
        assert len(set(owners.tolist())) <= len(set(own.tolist()))
    if alpha < gamma:
        assert shared_any


def test_textured_frames_report_patches_and_switches(gl_context, tree, pyramid):
    """Stats carry texture_patches and texture_switches (one bind per patch); sharing binds
    fewer textures; without a pyramid both are 0; set_textures switches at run time."""
    with Engine(tree, textures=pyramid, context=gl_context, offscreen=True) as eng:
        cam = views(tree)[1]
        shared = eng.render(cam, (480, 360), Cut(alpha=0.1, gamma=4.0))
        alone = eng.render(cam, (480, 360), Cut(alpha=0.1, gamma=4.0, share_textures=False))
        assert set(shared.stats) == set(STAT_KEYS)
        assert np.array_equal(eng.texels, patch_texel_sizes(pyramid, tree.rects))
        for f in (shared, alone):
            assert f.stats["texture_switches"] == f.stats["texture_patches"] > 0
            inner = tree.child_count[f.selection.nodes] > 0
            assert (f.selection.gammas[inner] <= 4.0).all()
        assert shared.stats["texture_switches"] < alone.stats["texture_switches"]
        assert alone.stats["texture_patches"] == len(
            {
                (p.level, p.col0, p.row0)
                for p in (eng.texture_patch(int(i)) for i in alone.selection.nodes)
            }
        )
        textured = shared.image
        eng.set_textures(None)
        plain = eng.render(cam, (480, 360), Cut(alpha=0.1, gamma=4.0))
        assert plain.stats["texture_patches"] == plain.stats["texture_switches"] == 0
        assert plain.texture_nodes is None
        assert (np.any(plain.image != textured, axis=-1)).mean() > 0.3
        eng.set_textures(pyramid.folder)
        again = eng.render(cam, (480, 360), Cut(alpha=0.1, gamma=4.0))
        assert np.array_equal(again.image, textured)


def test_textured_frames_under_a_small_cache_and_at_full_resolution(gl_context, tree, pyramid):
    """A cache budget far below one frame's meshes and textures still draws the same picture
    (textures stay pinned while their meshes are drawn); full resolution is textured too."""
    cam = views(tree)[1]
    with Engine(tree, textures=pyramid, context=gl_context, offscreen=True) as big:
        expected = big.render(cam, (320, 240), Cut(alpha=0.5, gamma=2.0))
        full = big.render(cam, (320, 240), Cut(full_resolution=True))
    with Engine(
        tree, textures=pyramid, context=gl_context, offscreen=True, cache_bytes=300_000
    ) as small:
        frame = small.render(cam, (320, 240), Cut(alpha=0.5, gamma=2.0))
        assert small.cache.evictions > 0
    assert expected.stats["gpu_bytes"] > 1_000_000
    assert np.array_equal(frame.image, expected.image)
    assert frame.stats["texture_switches"] == expected.stats["texture_switches"]
    assert full.stats["texture_patches"] >= 1
    assert (full.image[..., 3] > 0).mean() > 0.3


def test_decal_mode_draws_the_texture_unlit(gl_context, tree, pyramid):
    """Seen straight from above, the unlit picture shows the baked hillshade's grey levels
    drawn once over the hypsometric palette (issue 17: a grey shading pyramid shades the
    palette, palette × (0.3 + 0.7 · shade / 0.707)), up to filtering, for the texel under
    each pixel; lighting on top only darkens."""
    c = tree.terrain.domain.center
    cam = Camera.look_at((c[0], c[1], 9000), (c[0], c[1], 0), fov=40)
    with Engine(tree, textures=pyramid, context=gl_context, offscreen=True) as eng:
        unlit = eng.render(cam, (400, 400), Cut(alpha=1.0, gamma=1.0), style=Style(lighting=False))
        eng.world_positions(unlit)
        lit = eng.render(cam, (400, 400), Cut(alpha=1.0, gamma=1.0), style=Style(lighting=True))
    img = unlit.image.astype(int)
    surface = unlit.positions[..., 3] == 1
    assert surface.mean() > 0.5
    level0 = pyramid.level(0)
    t = pyramid.levels[0].transform
    xy = unlit.positions[surface][:, :2]
    cols = np.floor((xy[:, 0] - t.c) / t.a).astype(int)
    rows = np.floor((xy[:, 1] - t.f) / t.e).astype(int)
    # Away from the hillshade's nodata border (alpha 0 there shows the hypsometric ramp).
    inside = (cols > 2) & (rows > 2) & (cols < 510) & (rows < 510)
    assert inside.mean() > 0.9
    drawn = img[surface][inside]
    shade = level0[rows[inside], cols[inside], 0] / 255.0
    z = unlit.positions[surface][inside][:, 2]
    tint = eng.palette.colours(z, tree.terrain.z_range)
    expected = 255.0 * tint * np.clip(0.3 + 0.7 * shade / 0.7071, 0.0, 1.25)[:, None]
    diff = np.abs(drawn[:, :3] - np.minimum(expected, 255.0))
    assert np.median(diff) <= 8
    # Lighting modulates: never brighter than the texel, darker on average.
    assert (lit.image[surface][:, 0].astype(int) <= img[surface][:, 0] + 1).all()
    assert lit.image[surface][:, 0].mean() < img[surface][:, 0].mean() - 5


def test_bad_textures_are_rejected(gl_context, tree, tmp_path):
    """A non-pyramid object, a folder without pyramid.json, or a pyramid elsewhere fail."""
    with pytest.raises(InvalidParameterError, match="TexturePyramid"):
        Engine(tree, textures=42, context=gl_context)
    with pytest.raises(at.StoreError, match=r"pyramid\.json"):
        Engine(tree, textures=tmp_path, context=gl_context)
    from affine import Affine

    far = TexturePyramid.build(
        np.zeros((4, 4, 4), np.uint8), tmp_path / "far", transform=Affine(1, 0, 1e7, 0, -1, 1e7)
    )
    with pytest.raises(InvalidParameterError, match="overlap"):
        Engine(tree, textures=far, context=gl_context)


@pytest.fixture(scope="module")
def nc_tree(data_dir) -> ApproximationTree:
    dem = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    return ApproximationTree.build(dem, epsilon=1.0, progress=False)


def test_nc_land_use_lands_at_its_map_positions(gl_context, nc_tree, data_dir, tmp_path):
    """A decal render of the baked NC land use (no shading) shows, at the pixels away from
    class borders (by the pixel's texel footprint), the colour of the land-use class at that
    pixel's map x, y — seen from above and obliquely."""
    landuse = data_file(data_dir, "nc/landuse_r.tif")
    result = bake(nc_tree.terrain, tmp_path, shading=None, thematic=landuse, max_texture_size=1024)
    with rasterio.open(landuse) as ds:
        classes = ds.read(1)
        table = ds.colormap(1)
        inv = ~ds.transform
    # Per window size w: texels whose w × w land-use neighbourhood holds one class.
    windows = (5, 9, 17, 33)
    uniform = {w: maximum_filter(classes, w) == minimum_filter(classes, w) for w in windows}
    # The bake softens the embedded colour table by default (issue 17: legend colours quiet
    # enough for the shading); the pixels show the softened colours.
    lut = np.zeros((256, 3), dtype=np.int64)
    for k, c in ClassTable(table).softened().colours.items():
        lut[k] = c[:3]
    c = nc_tree.terrain.domain.center
    cams = [
        Camera.look_at((c[0] + 1000, c[1] - 500, 4000), (c[0] + 1000, c[1] - 499, 0), fov=45),
        Camera.look_at((c[0] - 3000, c[1] - 9000, 5000), (c[0] - 2000, c[1], 0), fov=45),
    ]
    with Engine(nc_tree, textures=result.pyramid, context=gl_context, offscreen=True) as eng:
        for cam in cams:
            frame = eng.render(
                cam, (500, 400), Cut(alpha=1.0, gamma=1.0), style=Style(lighting=False)
            )
            eng.world_positions(frame)
            # A pixel's footprint in texels: trilinear filtering mixes texels that far apart.
            pos = frame.positions[..., :2] / 10.0
            steps = [np.abs(np.gradient(pos[..., j], axis=a)) for j in (0, 1) for a in (0, 1)]
            footprint = np.max(steps, axis=0)
            surface = (frame.positions[..., 3] == 1) & np.isfinite(footprint)
            xy = frame.positions[surface][:, :2]
            cols = np.floor(inv.a * xy[:, 0] + inv.b * xy[:, 1] + inv.c).astype(int)
            rows = np.floor(inv.d * xy[:, 0] + inv.e * xy[:, 1] + inv.f).astype(int)
            inside = (rows >= 0) & (rows < classes.shape[0]) & (cols >= 0)
            inside &= cols < classes.shape[1]
            rows, cols = rows[inside], cols[inside]
            fp = footprint[surface][inside]
            k = classes[rows, cols]
            keep = np.zeros(len(k), dtype=bool)
            for w in windows:
                near = (2 * fp + 3 <= w) & ~keep
                keep[near] = uniform[w][rows[near], cols[near]]
            keep &= k != 255
            assert keep.sum() > 20_000
            drawn = frame.image[surface][inside][keep, :3].astype(np.int64)
            want = lut[k[keep]]
            close = np.abs(drawn - want).max(axis=1) <= 3
            print(f"land use: {close.mean():.4f} of {keep.sum()} pixels within ±3")
            assert close.mean() > 0.98, close.mean()
            # Several classes are seen, so the test can tell them apart.
            assert len(np.unique(k[keep])) >= 4


def test_cli_bake_and_render_with_textures(data_dir, tmp_path):
    """bake --json reports levels, sizes, bytes, seconds and writes pyramid.json and
    georeferenced levels (grey + alpha for pure shading, read as R = G = B); render --textures
    reports the texture figures."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    runner = CliRunner()
    tree_file = tmp_path / "nc.zarr"
    res = runner.invoke(cli_main, ["build", str(dem), "--out", str(tree_file)])
    assert res.exit_code == 0, res.output
    out = tmp_path / "tex"
    args = ["bake", str(tree_file), "--alg", "ZevenbergenThorne", "--max-texture-size", "256"]
    res = runner.invoke(cli_main, [*args, "--out", str(out), "--json"])
    assert res.exit_code == 0, res.output
    figures = json.loads(res.output)
    assert figures["levels"] == 2 and figures["sizes"] == [[500, 450], [250, 225]]
    assert figures["bytes"] == sum(f.stat().st_size for f in out.glob("level*.tif"))
    assert figures["seconds"] > 0
    assert (out / "pyramid.json").is_file()
    with rasterio.open(out / "level0.tif") as ds, rasterio.open(dem) as src:
        # Pure shading is grey: stored as grey and alpha, read back as RGBA with R = G = B.
        assert ds.count == 2 and ds.transform.almost_equals(src.transform)
        assert ds.crs == src.crs
    r, g, b, _ = np.moveaxis(TexturePyramid(out).level(0), -1, 0)
    assert np.array_equal(r, g) and np.array_equal(r, b) and r.std() > 5
    shade = TopographicShading(at.open_terrain(dem), algorithm="zevenbergen-thorne").shade()
    assert np.abs(r.astype(int) - shade).max() <= 1
    png = tmp_path / "nc.png"
    res = runner.invoke(
        cli_main,
        [
            *("render", str(tree_file), "--textures", str(out), "--no-lighting"),
            *("--size", "320x240", "--out", str(png), "--json"),
        ],
    )
    assert res.exit_code == 0, res.output
    stats = json.loads(res.output)
    assert set(stats) == {*STAT_KEYS, "image"}
    assert stats["texture_patches"] >= 1 and stats["texture_switches"] >= 1
    assert stats["max_gamma"] > 0
    res = runner.invoke(
        cli_main,
        ["bake", str(dem), "--shading", "phong", "--combined", "--out", str(tmp_path / "x")],
    )
    assert res.exit_code == 2 and "topographic" in res.output
