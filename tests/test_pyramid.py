"""Texture pyramid levels on disk and texture patches chosen per node (core paper, 3.3)."""

from __future__ import annotations

import json
import os
import shutil
import signal

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
            # A shading is grey: stored as grey and alpha.
            assert ds.count == 2
            extents.append(tuple(np.round(ds.bounds, 6)))
    # Odd sizes round up, so coarser levels may reach up to one texel further.
    x0, y0, x1, y1 = extents[0]
    for e in extents[1:]:
        assert e[0] == x0 and e[3] == y1
        assert x1 <= e[2] <= x1 + 4 * terrain.cell_size[0]
        assert y0 - 4 * terrain.cell_size[1] <= e[1] <= y0


def test_levels_read_as_the_geotiff_in_rgba(pyramid):
    """A level reads as exactly the pixels GDAL reads from the file, grey spread to R, G, B."""
    for k, lv in enumerate(pyramid.levels):
        with rasterio.open(lv.path) as ds:
            grey, alpha = ds.read()
        np.testing.assert_array_equal(pyramid.level(k), np.stack([grey, grey, grey, alpha], -1))


def test_levels_are_tiled_and_compressed(pyramid, tmp_path):
    """Levels follow the COG conventions: 512² tiles, ZSTD, grey + alpha for a shading
    (a quarter of RGBA's bytes before compression), RGBA for a colour texture."""
    from affine import Affine

    rgba = np.random.default_rng(2).integers(0, 255, (600, 700, 4), dtype=np.uint8)
    colour = TexturePyramid.build(rgba, tmp_path, 256, transform=Affine(1, 0, 0, 0, -1, 600))
    for p, bands in ((pyramid, 2), (colour, 4)):
        assert p.bands == bands
        for lv in p.levels:
            with rasterio.open(lv.path) as ds:
                assert ds.count == bands
                assert ds.block_shapes == [(512, 512)] * bands
                assert ds.compression.name.lower() == "zstd"
    assert pyramid.nbytes < 0.5 * sum(lv.width * lv.height * 2 for lv in pyramid.levels)
    np.testing.assert_array_equal(colour.level(0), rgba)


def test_windows_read_as_slices_of_the_level(pyramid):
    """``read`` gives the texels of a window, transparent past the level's edges."""
    level = pyramid.level(1)
    np.testing.assert_array_equal(pyramid.read(1, 30, 40, 64, 32), level[30:94, 40:72])
    edge = pyramid.read(1, 380, 490, 16, 16)
    np.testing.assert_array_equal(edge[:9, :10], level[380:, 490:])
    assert not edge[9:].any() and not edge[:, 10:].any()


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


def test_levels_mark_their_last_band_as_alpha(pyramid):
    """Every level's last band is an alpha band for GDAL (and viewers), not a colour."""
    from rasterio.enums import ColorInterp

    for lv in pyramid.levels:
        with rasterio.open(lv.path) as ds:
            assert tuple(ds.colorinterp) == (ColorInterp.gray, ColorInterp.alpha), lv.path


def test_bake_streams_the_texture_without_its_whole_rgba(terrain, tmp_path, monkeypatch):
    """Level 0 is written from strips of the grey levels: the full-size RGBA array of the
    texture (``rgba()``) is never made, and the levels equal the whole-array bake."""
    whole = TexturePyramid.build(
        TopographicShading(terrain).rgba(),
        tmp_path / "whole",
        max_texture_size=256,
        transform=TopographicShading(terrain).transform,
    )

    def no_whole_rgba(self):
        raise AssertionError("the pyramid asked for the whole RGBA array")

    monkeypatch.setattr(TopographicShading, "rgba", no_whole_rgba)
    streamed = TexturePyramid.build(
        TopographicShading(terrain), tmp_path / "streamed", max_texture_size=256
    )
    assert len(streamed) == len(whole) == 3
    for k in range(len(whole)):
        np.testing.assert_array_equal(streamed.level(k), whole.level(k))


def _halve_reference(a: np.ndarray) -> np.ndarray:
    """The float64 alpha-weighted 2 × 2 box filter, odd sizes repeating their last texel."""
    a = a.astype(np.float64)
    if a.shape[0] % 2:
        a = np.concatenate([a, a[-1:]], axis=0)
    if a.shape[1] % 2:
        a = np.concatenate([a, a[:, -1:]], axis=1)
    q = a.reshape(a.shape[0] // 2, 2, a.shape[1] // 2, 2, 4)
    w = q[..., 3].sum(axis=(1, 3))
    rgb = (q[..., :3] * q[..., 3:]).sum(axis=(1, 3)) / np.maximum(w, 1e-12)[..., None]
    out = np.empty((*w.shape, 4))
    out[..., :3] = np.where(w[..., None] > 0, rgb, 0.0)
    out[..., 3] = q[..., 3].mean(axis=(1, 3))
    return np.round(out).astype(np.uint8)


@pytest.mark.parametrize("shape", [(1, 1), (2, 2), (7, 9), (64, 33), (3, 128)])
def test_uint8_halving_equals_the_float64_filter_on_every_texel(shape):
    """The integer kernel gives the float64 formula's texels exactly, ties and odd sizes
    included, for any mix of opaque, transparent and partial alpha."""
    from approxtree.kernels.rgba import halve_bands

    rng = np.random.default_rng(sum(shape))
    for _ in range(20):
        a = rng.integers(0, 256, (*shape, 4)).astype(np.uint8)
        a[..., 3] = rng.choice([0, 255, 255, 255, 1, 2, 3, 128, 254], size=shape)
        want = _halve_reference(a)
        got = np.empty((4, *want.shape[:2]), np.uint8)
        halve_bands(np.ascontiguousarray(np.moveaxis(a, -1, 0)), got)
        np.testing.assert_array_equal(np.moveaxis(got, 0, -1), want)


@pytest.mark.parametrize("bands", [2, 4])
@pytest.mark.parametrize("shape", [(2, 2), (9, 7), (64, 33), (6, 1001), (512, 130)])
def test_uint8_halving_of_mostly_opaque_planes_equals_the_float64_filter(shape, bands):
    """Mostly opaque planes (a hillshade: transparent border, a few holes) take the plain
    mean of four and redo only the texels with a non-opaque alpha among their four: every
    texel is still the float64 formula's, for grey + alpha and RGBA, odd sizes included."""
    from approxtree.kernels.rgba import halve_bands

    rng = np.random.default_rng(shape[0] * 1000 + shape[1] + bands)
    for _ in range(10):
        a = np.zeros((*shape, 4), np.uint8)
        a[..., :3] = rng.integers(0, 256, (*shape, 3))
        if bands == 2:
            a[..., 1] = a[..., 2] = a[..., 0]
        a[..., 3] = 255
        # Transparent border columns, and scattered partial or transparent texels.
        a[:, 0, 3] = a[:, -1, 3] = 0
        holes = rng.random(shape) < 0.02
        a[..., 3][holes] = rng.choice([0, 1, 2, 127, 128, 253, 254], size=int(holes.sum()))
        want = _halve_reference(a)
        planes = np.moveaxis(a, -1, 0)[[0, 3]] if bands == 2 else np.moveaxis(a, -1, 0)
        got = np.empty((bands, *want.shape[:2]), np.uint8)
        halve_bands(np.ascontiguousarray(planes), got)
        expected = np.moveaxis(want, -1, 0)[[0, 3]] if bands == 2 else np.moveaxis(want, -1, 0)
        np.testing.assert_array_equal(got, expected)


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


def test_levels_with_empty_strips_read_back_exactly(tmp_path):
    """A level taller than one write chunk with all-zero rows (nodata borders) reads back
    exactly."""
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


# -- all or nothing ------------------------------------------------------------------------------

_SHAPE = (300, 200)  # levels 300 × 200, 150 × 100, 75 × 50, 38 × 25 at a 64-texel limit

_KILLED_BAKE = """
import os, signal, sys
import numpy as np
from affine import Affine
import approxtree.io.atomic as atomic
import approxtree.textures.pyramid as pyramid

folder, value, at, how = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
write_level, exchange = pyramid._write_level, getattr(atomic, "_exchange", None)

def die():
    os.kill(os.getpid(), getattr(signal, how))

def killing_write(path, *args):
    sums = write_level(path, *args)
    if at == "level1" and path.name == "level1.tif":
        die()
    return sums

def killing_exchange(a, b):
    if at == "swap":
        die()
    done = exchange(a, b)
    if at == "swapped":
        die()
    return done

pyramid._write_level = killing_write
atomic._exchange = killing_exchange
rgba = np.full((300, 200, 4), value, np.uint8)
rgba[..., 3] = 255
transform = Affine(1, 0, 0, 0, -1, 300)
pyramid.TexturePyramid.build(rgba, folder, max_texture_size=64, transform=transform)
"""


def _constant_pyramid(folder, value: int) -> TexturePyramid:
    from affine import Affine

    rgba = np.full((*_SHAPE, 4), value, np.uint8)
    rgba[..., 3] = 255
    return TexturePyramid.build(
        rgba, folder, max_texture_size=64, transform=Affine(1, 0, 0, 0, -1, 300)
    )


def _values(folder) -> set[int]:
    """The grey values found in all levels of the pyramid in ``folder`` (opened afresh)."""
    p = TexturePyramid(folder)
    assert len(p) == 4
    return {int(v) for k in range(len(p)) for v in np.unique(p.level(k)[..., :3])}


def test_killed_bakes_leave_a_whole_pyramid(tmp_path):
    """A bake killed (SIGKILL) while writing levels or just before the swap leaves the old
    pyramid whole; killed just after the swap, the new one; the next bake removes what the
    killed ones left beside the folder. A bake stopped by SIGTERM cleans up at once."""
    import subprocess
    import sys

    folder = tmp_path / "pyr"
    _constant_pyramid(folder, 200)
    runs = [
        (5, "level1", "SIGTERM", 200),
        (7, "level1", "SIGKILL", 200),
        (9, "swap", "SIGKILL", 200),
        (11, "swapped", "SIGKILL", 11),
    ]
    for value, at, how, expected in runs:
        args = [str(folder), str(value), at, how]
        done = subprocess.run([sys.executable, "-c", _KILLED_BAKE, *args], capture_output=True)
        assert done.returncode == -getattr(signal, how), done.stderr.decode()
        assert _values(folder) == {expected}, at
        if how == "SIGTERM":
            assert os.listdir(tmp_path) == ["pyr"]
    _constant_pyramid(folder, 13)
    assert _values(folder) == {13}
    assert os.listdir(tmp_path) == ["pyr"]
    assert sorted(os.listdir(folder)) == [
        "level0.tif",
        "level1.tif",
        "level2.tif",
        "level3.tif",
        "pyramid.json",
    ]


def _swap_level(folder, other):
    shutil.copy(other / "level0.tif", folder / "level0.tif")
    # Compressed levels of other texels differ in bytes: list the swapped file's, so that
    # only its build tag tells it apart.
    meta = json.loads((folder / "pyramid.json").read_text())
    meta["levels"][0]["bytes"] = (folder / "level0.tif").stat().st_size
    (folder / "pyramid.json").write_text(json.dumps(meta))


def _drop_level(folder, other):
    (folder / "level2.tif").unlink()


def _extra_level(folder, other):
    shutil.copy(folder / "level3.tif", folder / "level4.tif")


def _truncate_level(folder, other):
    data = (folder / "level1.tif").read_bytes()
    (folder / "level1.tif").write_bytes(data[:-100])


def _wrong_size(folder, other):
    meta = json.loads((folder / "pyramid.json").read_text())
    meta["levels"][0]["width"] = 201
    (folder / "pyramid.json").write_text(json.dumps(meta))


def _old_format(folder, other):
    meta = json.loads((folder / "pyramid.json").read_text())
    for key in ("format", "build"):
        meta.pop(key, None)
    for lv in meta["levels"]:
        lv.pop("bytes", None)
    (folder / "pyramid.json").write_text(json.dumps(meta))


def _format_2(folder, other):
    meta = json.loads((folder / "pyramid.json").read_text())
    meta["format"] = 2
    meta.pop("bands")
    (folder / "pyramid.json").write_text(json.dumps(meta))


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (_swap_level, "another bake"),
        (_drop_level, "missing"),
        (_extra_level, "not listed"),
        (_truncate_level, "bytes"),
        (_wrong_size, "201"),
        (_old_format, "format 1"),
        (_format_2, "format 2.*Rebake"),
    ],
)
def test_levels_that_do_not_match_pyramid_json_are_refused(tmp_path, damage, message):
    """A level of another bake (same size), a missing, extra or truncated level, a size unlike
    pyramid.json says, or a pyramid.json without level fingerprints: a StoreError on open,
    never a pyramid that drapes the wrong texels."""
    folder, other = tmp_path / "a", tmp_path / "b"
    _constant_pyramid(folder, 200)
    _constant_pyramid(other, 7)
    damage(folder, other)
    with pytest.raises(StoreError, match=message):
        TexturePyramid(folder)


def test_a_folder_with_other_files_is_refused_before_the_work(tmp_path, terrain):
    """A bake replaces its whole folder, so a folder holding other files is refused (before
    any shading is computed) and left as it was."""
    from approxtree.textures.bake import bake

    (tmp_path / "notes.txt").write_text("keep me")
    with pytest.raises(StoreError, match=r"notes\.txt"):
        bake(terrain, tmp_path, gl=False)
    assert os.listdir(tmp_path) == ["notes.txt"]
    # Files of a pyramid (and temp files an older bake left inside it) may be replaced.
    old = tmp_path / "old"
    old.mkdir()
    for name in ("pyramid.json", "level0.tif", "level0.tif.aux.xml", ".level1.tif.tmp"):
        (old / name).write_text("x")
    _constant_pyramid(old, 3)
    assert _values(old) == {3}


def test_pyramid_files_get_umask_permissions_and_the_folder_keeps_its_mode(tmp_path):
    """Under umask 022 a new pyramid folder is 0755 and its files 0644 (pyramid.json was
    0600); a rebake keeps the folder's mode."""
    import stat

    saved = os.umask(0o022)
    try:
        folder = tmp_path / "pyr"
        _constant_pyramid(folder, 1)
        mode = lambda p: stat.S_IMODE(os.stat(p).st_mode)  # noqa: E731
        assert mode(folder) == 0o755
        assert {n: mode(folder / n) for n in os.listdir(folder)} == {
            n: 0o644 for n in os.listdir(folder)
        }
        folder.chmod(0o750)
        _constant_pyramid(folder, 2)
        assert mode(folder) == 0o750
    finally:
        os.umask(saved)


def test_coarser_levels_are_written_while_level_0_is_made(tmp_path):
    """Levels stream: each halving goes on to the next level's writer at once, so a texture
    that holds back its last strip until a coarser level has written rows still bakes (a
    pyramid written level after level would wait for that strip forever), and it equals the
    pyramid of the same texels given whole."""
    import threading

    from affine import Affine

    from approxtree.textures.base import TextureData

    # 2048 rows in strips of 512: level 1 (written in whole 512-row tile rows) can write its
    # first tile row once level 0 has written two strips.
    rgba = np.random.default_rng(5).integers(0, 256, (2048, 24, 4)).astype(np.uint8)
    rgba[..., 3] = 255
    written = threading.Event()
    given = [0]

    def progress(done: int, total: int) -> None:
        # Rows beyond those of level 0's strips handed out so far are a coarser level's.
        if done > given[0]:
            written.set()

    class HeldBack(TextureData):
        bands = 4

        def __init__(self) -> None:
            self.transform, self.shape, self.crs = Affine(1, 0, 0, 0, -1, 2048), (2048, 24), None

        def rgba(self) -> np.ndarray:
            return rgba

        def level_strips(self, rows: int):
            for r0 in range(0, 2048, 512):
                if r0 == 1536:
                    assert written.wait(30), "no coarser level written before level 0 ended"
                given[0] = r0 + 512
                yield np.ascontiguousarray(np.moveaxis(rgba[r0 : r0 + 512], -1, 0))

    streamed = TexturePyramid.build(HeldBack(), tmp_path / "s", 1024, progress=progress)
    whole = TexturePyramid.build(rgba, tmp_path / "w", 1024, transform=Affine(1, 0, 0, 0, -1, 2048))
    assert len(streamed) == len(whole) == 2
    for k in range(2):
        np.testing.assert_array_equal(streamed.level(k), whole.level(k))


def _level_tile_sums(path) -> list[list[int]]:
    """CRC-32C of each 512² tile of a level as GDAL decodes it (bands, rows, cols), edge tiles
    clipped: recomputed here without the pyramid's code."""
    import crc32c

    with rasterio.open(path) as ds:
        texels = ds.read()
    _, rows, cols = texels.shape
    return [
        [
            crc32c.crc32c(np.ascontiguousarray(texels[:, r0 : r0 + 512, c0 : c0 + 512]).tobytes())
            for c0 in range(0, cols, 512)
        ]
        for r0 in range(0, rows, 512)
    ]


def _odd_strips(rgba: np.ndarray, transform):
    """A TextureData of a (rows, cols, 4) texture handed out in strips of 98 rows, which
    straddle the 512-row tile rows."""
    from approxtree.textures.base import TextureData

    class OddStrips(TextureData):
        bands = 4

        def __init__(self) -> None:
            self.transform, self.shape, self.crs = transform, rgba.shape[:2], None

        def rgba(self) -> np.ndarray:
            return rgba

        def level_strips(self, rows: int):
            for r0 in range(0, rgba.shape[0], 98):
                yield np.ascontiguousarray(np.moveaxis(rgba[r0 : r0 + 98], -1, 0))

    return OddStrips()


def test_every_tile_carries_the_checksum_of_its_decoded_texels(pyramid, tmp_path):
    """pyramid.json (format 4) lists, per level, rows of tiles, each the CRC-32C of the tile's
    decoded texels (band-sequential, edge tiles clipped), for grey and RGBA pyramids, whole
    strips or strips that straddle tile rows."""
    from affine import Affine

    rgba = np.random.default_rng(3).integers(0, 256, (1100, 1300, 4)).astype(np.uint8)
    transform = Affine(1, 0, 0, 0, -1, 1100)
    whole = TexturePyramid.build(rgba, tmp_path / "whole", 512, transform=transform)
    odd = TexturePyramid.build(_odd_strips(rgba, transform), tmp_path / "odd", 512)
    for built in (pyramid, whole, odd):
        meta = json.loads((built.folder / "pyramid.json").read_text())
        assert meta["format"] == 4
        for entry, lv in zip(meta["levels"], built.levels, strict=True):
            assert entry["tile_crc32c"] == _level_tile_sums(lv.path), lv.path
    level0 = json.loads((tmp_path / "odd" / "pyramid.json").read_text())["levels"][0]
    assert [len(row) for row in level0["tile_crc32c"]] == [3, 3, 3]
    np.testing.assert_array_equal(odd.level(0), whole.level(0))


def _flip(path, at: int, count: int) -> None:
    data = bytearray(path.read_bytes())
    for i in range(at, at + count):
        data[i] ^= 0x5A
    path.write_bytes(bytes(data))


def _tile_bytes(path, tile: int) -> tuple[int, int]:
    """(offset, bytes) of a tile of band 1 in a level GeoTIFF."""
    with rasterio.open(path) as ds:
        offset = int(ds.get_tag_item("BLOCK_OFFSET_0_0", "TIFF", bidx=1) or 0)
        size = int(ds.get_tag_item("BLOCK_SIZE_0_0", "TIFF", bidx=1) or 0)
    assert tile == 0 and offset and size
    return offset, size


@pytest.mark.parametrize(("count", "found_by"), [(1, "checksum"), (64, "does not decode")])
def test_a_damaged_tile_is_a_store_error_never_drawn(tmp_path, count, found_by):
    """Bytes flipped inside a tile's compressed data: a StoreError naming the level's file and
    the tile, whether ZSTD notices (a decode error, no GDAL traceback) or the texels decode
    to something else (the checksum); other windows of the level still read."""
    from affine import Affine

    rgba = np.random.default_rng(4).integers(0, 256, (600, 700, 4)).astype(np.uint8)
    rgba[..., 3] = 255
    built = TexturePyramid.build(rgba, tmp_path / "p", 512, transform=Affine(1, 0, 0, 0, -1, 600))
    level0 = built.levels[0].path
    offset, size = _tile_bytes(level0, 0)
    _flip(level0, offset + size // 2, count)
    damaged = TexturePyramid(tmp_path / "p")
    with pytest.raises(StoreError, match=r"level0\.tif is damaged: tile \(0, 0\) of level 0") as e:
        damaged.read(0, 10, 10, 64, 64)
    assert found_by in str(e.value) and "rebake" in str(e.value)
    # Tile (1, 1) is whole: its window reads, equal to the texels baked.
    np.testing.assert_array_equal(damaged.read(0, 520, 520, 60, 60), rgba[520:580, 520:580])


def test_a_pyramid_of_format_3_asks_for_a_rebake(pyramid, tmp_path):
    """A pyramid.json of format 3 (no tile checksums) is refused with the rebake message."""
    folder = tmp_path / "old"
    shutil.copytree(pyramid.folder, folder)
    meta = json.loads((folder / "pyramid.json").read_text())
    meta["format"] = 3
    for lv in meta["levels"]:
        lv.pop("tile_crc32c")
    (folder / "pyramid.json").write_text(json.dumps(meta))
    with pytest.raises(StoreError, match=r"format 3.*Rebake"):
        TexturePyramid(folder)
    meta["format"] = 4
    (folder / "pyramid.json").write_text(json.dumps(meta))
    with pytest.raises(StoreError, match=r"malformed.*tile_crc32c"):
        TexturePyramid(folder)
