"""``approxtree verify`` on texture pyramids of ``approxtree bake``: every level listed present
and decoding tile by tile, each coarser level the alpha-weighted 2 × 2 box filter of the finer
(recomputed in numpy), level 0 covering the source and, for a plain hillshade bake, equal to
``gdaldem hillshade``; tile checksums (pyramid format 4) when listed. A changed texel, a
deleted level or a wrong checksum fails (exit 1) naming it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner
from conftest import data_file
from test_verify_mesh import crop

from approxtree.cli import main
from approxtree.verify.pyramid import halve


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def sources(data_dir, tmp_path_factory) -> dict[str, Path]:
    """Odd-sized crops: NC (projected), SRTM (degrees), Mount St Helens (nodata inside)."""
    folder = tmp_path_factory.mktemp("sources")
    return {
        "nc": crop(data_file(data_dir, "nc/elev_ned_30m.tif"), folder / "nc.tif", 0, 0, 121, 161),
        "srtm": crop(data_file(data_dir, "srtm/N44W072.hgt"), folder / "s.tif", 700, 600, 99, 133),
        "helens": data_file(data_dir, "edge/SainteHelens.dem"),
    }


def bake(source: Path, out: Path, *extra) -> Path:
    made = run("bake", source, "--out", out, "--no-gl", "--max-texture-size", 32, "-q", *extra)
    assert made.exit_code == 0, made.output
    return out


@pytest.mark.parametrize("name", ["nc", "srtm", "helens"])
def test_verify_passes_on_a_hillshade_bake(sources, tmp_path, name):
    """A default bake passes every check, level 0 against gdaldem's hillshade included."""
    out = bake(sources[name], tmp_path / "pyr")
    result = run("verify", out, "--source", sources[name], "--hillshade", "--json")
    doc = json.loads(result.output)
    assert result.exit_code == 0, doc
    checks = {c["name"]: c["items"] for c in doc["checks"]}
    assert checks["halving"] >= 3 and checks["hillshade"] == 1 and checks["coverage"] == 1
    assert doc["figures"]["levels"] >= 4


@pytest.mark.parametrize("relative", ["lidar/autzen_trim.laz", "tin/9_533_383.terrain"])
def test_hillshade_of_a_point_cloud_or_tin_bake_is_listed_not_checked(data_dir, tmp_path, relative):
    """A bake of a point cloud or a TIN (rasterized by the bake) has no raster for gdaldem:
    --hillshade lists it as not checked (an AttributeError traceback before)."""
    source = data_file(data_dir, relative)
    out = bake(source, tmp_path / "pyr")
    result = run("verify", out, "--source", source, "--hillshade", "--json")
    doc = json.loads(result.output)
    assert result.exit_code == 0, doc
    assert any(s.startswith("hillshade: the source is a") for s in doc["not_checked"])


def test_verify_passes_on_a_thematic_bake(sources, data_dir, tmp_path):
    """An RGBA bake (land use under the shading) halves within 1 per channel; without
    --hillshade level 0's content is listed as not checked, with it it fails (its texels are
    the land use's 10 m cells, not the DEM's)."""
    thematic = data_file(data_dir, "nc/landuse_r.tif")
    out = bake(sources["nc"], tmp_path / "pyr", "--thematic", thematic)
    doc = json.loads(run("verify", out, "--source", sources["nc"], "--json").output)
    assert doc["ok"] and doc["figures"]["bands"] == 4
    assert any("level 0's texels" in line for line in doc["not_checked"])
    result = run("verify", out, "--source", sources["nc"], "--hillshade")
    assert result.exit_code == 1 and "hillshade  level 0  " in result.output


@pytest.fixture
def pyramid(sources, tmp_path) -> Path:
    return bake(sources["nc"], tmp_path / "pyr")


def _edit_texel(path: Path, band: int, row: int, col: int, value: int) -> None:
    with rasterio.open(path, "r+") as ds:
        from rasterio.windows import Window

        ds.write(np.array([[value]], dtype=np.uint8), band, window=Window(col, row, 1, 1))


def test_a_changed_texel_fails_naming_it(pyramid, sources):
    """A level-1 texel rewritten (a valid file: it still decodes) is not the box filter of
    level 0: exit 1 naming the level and texel."""
    with rasterio.open(pyramid / "level1.tif") as ds:
        old = int(ds.read(1)[20, 30])
    _edit_texel(pyramid / "level1.tif", 1, 20, 30, (old + 128) % 256)
    result = run("verify", pyramid, "--source", sources["nc"])
    assert result.exit_code == 1
    assert "halving  level 1 texel (20, 30) band 0" in result.output


def test_a_deleted_level_fails(pyramid, sources):
    """A level file pyramid.json lists, deleted: the levels check names it."""
    (pyramid / "level2.tif").unlink()
    result = run("verify", pyramid, "--source", sources["nc"])
    assert result.exit_code == 1
    assert "levels  level 2 (level2.tif)  a file  missing" in result.output


def test_halve_is_the_alpha_weighted_box_filter():
    """The reference halving: transparent texels do not darken their neighbours, odd sizes
    repeat the last row and column, alpha is the mean."""
    fine = np.zeros((2, 3, 3), dtype=np.uint8)
    fine[0] = [[200, 100, 50], [0, 0, 10], [90, 90, 90]]
    fine[1] = [[255, 255, 255], [0, 0, 255], [255, 255, 255]]
    out = halve(fine)
    assert out.shape == (2, 2, 2)
    assert out[:, 0, 0].tolist() == [150, 128]  # (200 + 100) / 2, alpha 510 / 4 → 128 (even)
    assert out[:, 0, 1].tolist() == [30, 255]  # 50 and 10, each twice
    assert out[:, 1, 1].tolist() == [90, 255]


def _checksummed(folder: Path) -> Path:
    """A format-4 pyramid: 1100 × 1300 RGBA (3 × 3 tiles of 512 at level 0) with every level's
    tile_crc32c computed here from its decoded texels."""
    import crc32c

    from approxtree.textures.pyramid import TexturePyramid

    rows, cols = np.mgrid[0:1100, 0:1300]
    rgba = np.empty((1100, 1300, 4), dtype=np.uint8)
    rgba[..., 0] = (rows // 3) % 256
    rgba[..., 1] = (cols // 5) % 256
    rgba[..., 2] = (rows + cols) % 251
    rgba[..., 3] = np.where((rows - 500) ** 2 + (cols - 700) ** 2 < 200**2, 0, 255)
    TexturePyramid.build(rgba, folder, 512, Affine(1.0, 0, 0, 0, -1.0, 1100.0), None)
    meta = json.loads((folder / "pyramid.json").read_text())
    for lv in meta["levels"]:
        with rasterio.open(folder / lv["file"]) as ds:
            texels = ds.read()
        lv["tile_crc32c"] = [
            [
                crc32c.crc32c(np.ascontiguousarray(texels[:, r : r + 512, c : c + 512]))
                for c in range(0, lv["width"], 512)
            ]
            for r in range(0, lv["height"], 512)
        ]
    meta["format"] = 4
    (folder / "pyramid.json").write_text(json.dumps(meta))
    return folder


def test_tile_checksums_are_checked_tile_by_tile(tmp_path):
    """Format 4: every tile's CRC-32C of its decoded texels (band-sequential, edge tiles
    clipped) matches; a wrong one names its level and (row, col) of tiles."""
    folder = _checksummed(tmp_path / "pyr")
    doc = json.loads(run("verify", folder, "--json").output)
    checks = {c["name"]: c for c in doc["checks"]}
    assert doc["ok"] and checks["checksums"]["items"] == 9 + 4 + 1
    meta = json.loads((folder / "pyramid.json").read_text())
    meta["levels"][0]["tile_crc32c"][1][2] ^= 1
    (folder / "pyramid.json").write_text(json.dumps(meta))
    result = run("verify", folder)
    assert result.exit_code == 1 and "checksums  level 0 tile (1, 2)" in result.output


def test_a_changed_texel_of_the_last_level_fails_its_checksum(tmp_path):
    """The coarsest level has no coarser one to betray it: its checksum and the halving of
    the level above do."""
    folder = _checksummed(tmp_path / "pyr")
    _edit_texel(folder / "level2.tif", 2, 100, 100, 7)
    report_doc = json.loads(run("verify", folder, "--json").output)
    failed = {c["name"]: c for c in report_doc["checks"] if not c["ok"]}
    assert failed["checksums"]["offenders"][0]["address"] == "level 2 tile (0, 0)"
    assert failed["halving"]["offenders"][0]["address"] == "level 2 texel (100, 100) band 1"
