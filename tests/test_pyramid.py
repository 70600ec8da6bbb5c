"""Texture pyramid levels on disk and texture patches chosen per node (core paper, 3.3)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from approxtree import ApproximationTree, InvalidParameterError, StoreError
from approxtree.datasets import fractal_terrain
from approxtree.textures import TexturePatch, TexturePyramid, TopographicShading


@pytest.fixture(scope="module")
def terrain():
    return fractal_terrain(777, 1000, seed=11, relief=400.0)


@pytest.fixture(scope="module")
def pyramid(terrain, tmp_path_factory):
    """A shading pyramid of a 1000 × 777 fractal with a 256-texel limit."""
    folder = tmp_path_factory.mktemp("pyramid")
    return TexturePyramid.build(TopographicShading(terrain), folder, max_texture_size=256)


def test_levels_halve_until_they_fit(pyramid):
    """Level sizes halve (rounding up) until the last fits the maximum texture size."""
    sizes = [(lv.width, lv.height) for lv in pyramid.levels]
    assert sizes == [(1000, 777), (500, 389), (250, 195)]
    assert len(json.loads((pyramid.folder / "pyramid.json").read_text())["levels"]) == 3


def test_levels_share_one_domain_and_are_georeferenced(pyramid, terrain):
    """Every level covers the texture's domain; the GeoTIFFs carry the transform."""
    extents = []
    for lv in pyramid.levels:
        with rasterio.open(lv.path) as ds:
            assert ds.transform.almost_equals(lv.transform)
            assert ds.count == 4
            extents.append(tuple(np.round(ds.bounds, 6)))
    # Odd sizes round up, so coarser levels may reach up to one texel further.
    x0, y0, x1, y1 = extents[0]
    for e in extents[1:]:
        assert e[0] == x0 and e[3] == y1
        assert x1 <= e[2] <= x1 + 4 * terrain.cell_size[0]
        assert y0 - 4 * terrain.cell_size[1] <= e[1] <= y0


def test_memory_map_equals_the_geotiff(pyramid):
    """The memory-mapped level holds exactly the pixels GDAL reads from the file."""
    for k, lv in enumerate(pyramid.levels):
        with rasterio.open(lv.path) as ds:
            np.testing.assert_array_equal(pyramid.level(k), np.moveaxis(ds.read(), 0, -1))


def test_halving_is_an_alpha_weighted_box_filter(pyramid):
    """A coarse texel is the alpha-weighted mean of its four finer texels."""
    fine = pyramid.level(0).astype(float)
    coarse = pyramid.level(1)
    for r, c in [(5, 7), (100, 200), (300, 400)]:
        quad = fine[2 * r : 2 * r + 2, 2 * c : 2 * c + 2].reshape(4, 4)
        w = quad[:, 3]
        if w.sum() == 0:
            continue
        want = np.round((quad[:, :3] * w[:, None]).sum(0) / w.sum())
        np.testing.assert_array_equal(coarse[r, c, :3], want)
        assert coarse[r, c, 3] == np.round(w.mean())


def test_patches_cover_their_node_with_power_of_two_sizes(pyramid, terrain):
    """Per node: power-of-two size within the limit, covers D_N, finest level that fits."""
    tree = ApproximationTree.build(terrain, epsilon=2.0, max_points=33 * 33)
    for node in tree.nodes():
        patch = TexturePatch.for_rect(pyramid, node.rect)
        assert patch.width & (patch.width - 1) == 0 and patch.height & (patch.height - 1) == 0
        assert max(patch.width, patch.height) <= pyramid.max_texture_size
        e, r = patch.extent, node.rect
        assert e.xmin <= r.xmin and e.ymin <= r.ymin and e.xmax >= r.xmax and e.ymax >= r.ymax
        if patch.level > 0:
            finer = pyramid.levels[patch.level - 1]
            span = (r.width / finer.texel_size[0], r.height / finer.texel_size[1])
            assert max(span) > pyramid.max_texture_size / 2
        assert patch.texels().shape == (patch.height, patch.width, 4)
    # Leaves are small enough for the full-resolution level.
    assert TexturePatch.for_rect(pyramid, tree.node(int(tree.leaves[0])).rect).level == 0


def test_patch_texels_reference_the_level(pyramid):
    """A patch's texels are the level's texels in its window."""
    patch = TexturePatch(pyramid, 0, 10, 20, 64, 32)
    np.testing.assert_array_equal(patch.texels(), pyramid.level(0)[20:52, 10:74])


def test_bad_pyramids_are_reported(tmp_path):
    """A folder without pyramid.json, a malformed one, or a bad size limit are clear errors."""
    with pytest.raises(StoreError, match=r"pyramid\.json"):
        TexturePyramid(tmp_path)
    (tmp_path / "pyramid.json").write_text("{not json")
    with pytest.raises(StoreError, match="malformed"):
        TexturePyramid(tmp_path)
    with pytest.raises(InvalidParameterError, match="power of two"):
        TexturePyramid.build(np.zeros((4, 4, 4), np.uint8), tmp_path, max_texture_size=100)


def test_levels_with_empty_strips_stay_memory_mappable(tmp_path):
    """A level taller than one write chunk with all-zero rows (nodata borders) keeps its
    strips in order, so it memory-maps and reads back exactly."""
    from affine import Affine

    rgba = np.random.default_rng(1).integers(1, 255, (2100, 2049, 4), dtype=np.uint8)
    rgba[0] = 0
    rgba[-1] = 0
    rgba[1000:1010] = 0
    pyramid = TexturePyramid.build(
        rgba, tmp_path, max_texture_size=1024, transform=Affine(10, 0, 0, 0, -10, 21000)
    )
    np.testing.assert_array_equal(pyramid.level(0), rgba)
    assert len(pyramid) == 3
