"""An Engine follows a store and a pyramid that `approxtree update` swaps under it (live)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_update_render import PARAMS, SIZE, differing_tiles, meets, texture_keys
from test_update_store import write_patch

from approxtree import ApproximationTree
from approxtree.cli import main
from approxtree.datasets import fractal_terrain
from approxtree.render import Camera, Cut, Engine
from approxtree.render.cache_keys import NODE, MeshKey
from approxtree.render.context import create_context
from approxtree.render.live import HeightDigests, LiveFollower, StoreChangedError
from approxtree.textures.bake import bake
from approxtree.textures.pyramid import TexturePyramid

# The edited window, on 8-cell blocks (render/live.py's BLOCK): the cells it changes and the
# blocks the digests see are the same.
WINDOW = (304, 64, 64, 72)  # r0, c0, rows, cols


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the module's GL tests."""
    ctx = create_context()
    yield ctx
    ctx.release()


def store_and_pyramid(tmp_path: Path) -> tuple[Path, Path, object]:
    """A tree store of a 513² fractal and its pyramid (half-cell texels: 3 × 3 tiles)."""
    grid = fractal_terrain(513, seed=7, relief=300.0)
    store = tmp_path / "t.zarr"
    ApproximationTree.build(grid, **PARAMS).save(store)
    texel = abs(grid.transform.a) / 2
    bake(grid, tmp_path / "tex", gl=False, texel_size=texel, max_texture_size=512)
    return store, tmp_path / "tex", grid


def patch_file(tmp_path: Path, grid) -> Path:
    """A GeoTIFF raising every cell of WINDOW (a mound on a 5 m step)."""
    r0, c0, rows, cols = WINDOW
    heights = np.array(grid.heights[r0 : r0 + rows, c0 : c0 + cols], dtype=np.float64)
    yy, xx = np.mgrid[:rows, :cols]
    heights += 5.0 + 30.0 * np.exp(-(((yy - rows / 2) / 10) ** 2 + ((xx - cols / 2) / 10) ** 2))
    path = tmp_path / "patch.tif"
    write_patch(path, grid, r0, c0, heights)
    return path


def cameras(tree) -> list[Camera]:
    """An oblique overview and a closer view over the edit."""
    c = tree.terrain.domain.center
    return [
        Camera.look_at((c[0] - 300, c[1] - 2600, 2400), (c[0], c[1], 0), fov=60),
        Camera.look_at((c[0] - 900, c[1] - 1500, 700), (c[0] - 1400, c[1] - 900, 0), fov=50),
    ]


def test_engine_follows_a_store_and_pyramid_updated_by_the_cli(gl_context, tmp_path) -> None:
    """After `approxtree update STORE PATCH --textures DIR`, one poll gives the Engine the new
    tree: it keeps exactly the meshes of old nodes (same level and rect) whose cells the patch
    left alone and whose skirts did not move, and the texture patches meeting no changed
    tile; kept payloads equal fresh loads, and frames equal a fresh Engine's, pixel for
    pixel, without cracks."""
    store, tex, grid = store_and_pyramid(tmp_path)
    tree = ApproximationTree.load(store)
    old_heights = np.array(tree.terrain.heights[:, :], dtype=np.float64)
    eng = Engine(tree, textures=tex, context=gl_context, offscreen=True)
    fresh_eng = None
    try:
        live = LiveFollower(eng, store, [tex], ApproximationTree.load)
        cut = Cut(alpha=1.0, gamma=1.0)
        for cam in cameras(tree):
            eng.render(cam, SIZE, cut)
        live.settle()  # the first digests taken (on the follower's thread)
        assert not live.poll()  # nothing changed yet
        meshes = {k.item for k in eng.cache.keys() if isinstance(k, MeshKey)}
        textures = texture_keys(eng.cache.keys())
        old_levels = [TexturePyramid(tex).level(k) for k in range(3)]
        depths = eng.source.skirt_depths.copy()
        result = CliRunner().invoke(
            main, ["update", str(store), str(patch_file(tmp_path, grid)), "--textures", str(tex)]
        )
        assert result.exit_code == 0, result.output
        # A patch read now, before the poll, is refused (never cached under an old id).
        missing = next(i for i in range(len(tree)) if MeshKey(NODE, i) not in eng.provider)
        with pytest.raises(StoreChangedError):
            eng.provider.load(MeshKey(NODE, missing))
        change = live.poll()
        assert change.tree is not None and set(change.pyramids) == {tex}
        new = change.tree
        assert eng.tree is new
        # Expected, from the heights themselves: same level and rect, no changed cell among
        # the node's data points (closed rect), same skirt depth.
        new_heights = np.array(new.terrain.heights[:, :], dtype=np.float64)
        diff = ~((old_heights == new_heights) | (np.isnan(old_heights) & np.isnan(new_heights)))
        pairs = zip(new.levels, new.rects.tolist(), strict=True)
        ids = {(int(lv), *r): j for j, (lv, r) in enumerate(pairs)}
        ranges = new.terrain.index_ranges(np.asarray(tree.rects))
        expected = set()
        for i in meshes:
            j = ids.get((int(tree.levels[i]), *tree.rects[i].tolist()), -1)
            r0, r1, c0, c1 = ranges[i]
            if j >= 0 and not diff[r0 : r1 + 1, c0 : c1 + 1].any():
                if depths[i] == eng.source.skirt_depths[j]:
                    expected.add(j)
        assert expected and len(expected) < len(meshes)
        assert {k.item for k in eng.cache.keys() if isinstance(k, MeshKey)} == expected
        new_levels = [TexturePyramid(tex).level(k) for k in range(3)]
        changed = differing_tiles(old_levels, new_levels)
        kept_textures = {k for k in textures if not meets(k, changed[k.level])}
        assert kept_textures and kept_textures != textures
        assert texture_keys(eng.cache.keys()) == kept_textures
        for key in eng.provider.keys():
            if isinstance(key, MeshKey):
                fresh_payload = eng.source._build(key)
                np.testing.assert_array_equal(
                    eng.provider.get(key).vertices, fresh_payload.vertices
                )
        fresh_eng = Engine(
            ApproximationTree.load(store), textures=tex, context=gl_context, offscreen=True
        )
        for cam in cameras(tree):
            frame = eng.render(cam, SIZE, cut)
            expected_frame = fresh_eng.render(cam, SIZE, cut)
            np.testing.assert_array_equal(frame.image, expected_frame.image)
            assert frame.selection.stats["max_alpha"] <= cut.alpha
        assert not live.poll()
    finally:
        eng.release()
        if fresh_eng is not None:
            fresh_eng.release()


def test_height_digests_see_every_single_cell_change() -> None:
    """Changing any one cell (a value, or to no data) changes its block's digests, and only
    that block's."""
    grid = fractal_terrain(65, seed=3, relief=100.0)
    before = HeightDigests(grid)
    rng = np.random.default_rng(0)
    for r, c in rng.integers(0, 65, size=(20, 2)):
        heights = np.array(grid.heights)
        heights[r, c] = np.nan if (r + c) % 2 else heights[r, c] + 1e-3
        edited = type(grid)(heights, grid.transform)
        changed = before.changed(HeightDigests(edited))
        assert changed is not None
        assert np.flatnonzero(changed.ravel()).tolist() == [r // 8 * changed.shape[1] + c // 8]
    assert not before.changed(HeightDigests(grid)).any()
    assert math.isfinite(float(before.digests.sum(dtype=np.float64)))


def test_an_update_before_the_follower_started_is_followed(gl_context, tmp_path) -> None:
    """A store swapped after the drawn tree was loaded but before its follower started is
    noticed (the node table differs from a load now) and followed at the next poll keeping
    nothing; the frame then equals a fresh Engine's."""
    store, _, grid = store_and_pyramid(tmp_path)
    tree = ApproximationTree.load(store)
    result = CliRunner().invoke(main, ["update", str(store), str(patch_file(tmp_path, grid))])
    assert result.exit_code == 0, result.output
    eng = Engine(tree, context=gl_context, offscreen=True)
    fresh_eng = None
    try:
        live = LiveFollower(eng, store, [], ApproximationTree.load)
        live.settle()
        change = live.poll()
        assert change.tree is not None and change.kept is None
        cut = Cut(alpha=1.0, gamma=math.inf)
        fresh_eng = Engine(ApproximationTree.load(store), context=gl_context, offscreen=True)
        for cam in cameras(tree):
            frame = live.render(cam, SIZE, cut)
            np.testing.assert_array_equal(frame.image, fresh_eng.render(cam, SIZE, cut).image)
        assert not live.poll()
    finally:
        eng.release()
        if fresh_eng is not None:
            fresh_eng.release()
