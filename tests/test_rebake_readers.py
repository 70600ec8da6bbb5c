"""Readers of re-baked pyramids (deltas, pyramid format 5): ``approxtree verify``, imagery
tiles and their verify read the texels a fresh bake of the edited terrain holds, and a
damaged delta is found."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file

from approxtree.cli import main
from approxtree.errors import StoreError
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.io import read_grid
from approxtree.textures.bake import bake
from approxtree.textures.pyramid import TexturePyramid
from approxtree.textures.rebake import rebake
from approxtree.tiles.imagery import ImageryTiles
from approxtree.tiles.map_tiles import tile_plan, write_map_tiles
from approxtree.tiles.schemes import SCHEMES
from approxtree.verify import verify

BAKE = {"gl": False, "max_texture_size": 256, "texel_size": 10.0}


def cells_rect(grid: Grid, r0: int, c0: int, rows: int, cols: int) -> Rect:
    """The world rect of the grid's cells r0..r0+rows, c0..c0+cols (on cell edges)."""
    t = grid.transform
    x0, y0 = t @ (c0, r0)
    x1, y1 = t @ (c0 + cols, r0 + rows)
    return Rect(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))


@pytest.fixture(scope="module")
def rebaked(data_dir, tmp_path_factory) -> tuple[Path, Path]:
    """The NC DEM baked (3 × 3 tiles at level 0), then two pits dug and re-baked (deltas on
    every level), and a fresh bake of the dug DEM."""
    folder = tmp_path_factory.mktemp("rebaked")
    nc = read_grid(data_file(data_dir, "nc/elev_ned_30m.tif"))
    bake(nc, folder / "p", **BAKE)
    heights = np.array(nc.heights, dtype=np.float64)
    for r0, c0 in ((160, 160), (330, 100)):
        heights[r0 : r0 + 30, c0 : c0 + 40] -= 25.0
        grid = Grid(heights.astype(np.float32), nc.transform, nc.crs)
        rebake(folder / "p", grid, cells_rect(nc, r0, c0, 30, 40))
    bake(grid, folder / "fresh", **BAKE)
    return folder / "p", folder / "fresh"


def test_rebaked_pyramid_holds_deltas_and_verifies(rebaked) -> None:
    """After two re-bakes pyramid.json lists deltas on level 0, and ``approxtree verify``
    passes: every tile decodes and checks, each level halves the finer, deltas included."""
    folder, _ = rebaked
    meta = json.loads((folder / "pyramid.json").read_text())
    assert meta["format"] == 5 and len(meta["levels"][0]["deltas"]) == 2
    result = CliRunner().invoke(main, ["verify", str(folder), "--json"])
    doc = json.loads(result.output)
    assert result.exit_code == 0, doc
    checks = {c["name"]: c["items"] for c in doc["checks"]}
    assert checks["checksums"] == sum(
        len(row) for lv in meta["levels"] for row in lv["tile_crc32c"]
    )
    assert checks["halving"] > 0


def test_a_damaged_delta_fails_verify_and_reads(rebaked, tmp_path) -> None:
    """Bytes changed inside a delta (same size): verify exits 1 and a read of its tiles is a
    StoreError naming the delta's file, never its texels."""
    import shutil

    folder = tmp_path / "p"
    shutil.copytree(rebaked[0], folder)
    meta = json.loads((folder / "pyramid.json").read_text())
    delta = meta["levels"][0]["deltas"][-1]
    path = folder / delta["file"]
    data = bytearray(path.read_bytes())
    for at in range(len(data) // 2, len(data) // 2 + 64):
        data[at] ^= 0x5A
    path.write_bytes(bytes(data))
    result = CliRunner().invoke(main, ["verify", str(folder), "--json"])
    assert result.exit_code == 1, result.output
    tr0, tr1, tc0, tc1 = delta["tiles"]
    pyramid = TexturePyramid(folder)
    failures = []
    for tr in range(tr0, tr1):
        for tc in range(tc0, tc1):
            try:
                pyramid.read(0, tr * 512, tc * 512, 512, 512)
            except StoreError as exc:
                failures.append(str(exc))
    assert failures and all(delta["file"] in f for f in failures)


def test_imagery_of_a_rebaked_pyramid_equals_a_fresh_bakes(rebaked, tmp_path) -> None:
    """Imagery tiles cut from the re-baked pyramid have the pixels of those cut from a fresh
    bake, at the deepest zoom (level 0, its deltas) and a coarser one; written, they verify
    against the re-baked pyramid (verify reads its deltas too)."""
    folder, fresh = rebaked
    mine = ImageryTiles(TexturePyramid(folder), SCHEMES["webmercator"])
    theirs = ImageryTiles(TexturePyramid(fresh), SCHEMES["webmercator"])
    plan = tile_plan(mine)
    for z in (mine.maxzoom, mine.maxzoom - 2):
        for x, y in plan[z]:
            np.testing.assert_array_equal(mine.pixels(z, x, y), theirs.pixels(z, x, y))
    out = tmp_path / "tiles"
    z = mine.maxzoom
    write_map_tiles(ImageryTiles(TexturePyramid(folder), SCHEMES["webmercator"], minzoom=z), out)
    report = verify(out, textures=folder)
    assert report.ok, report.offenders[:3]
    assert report.checks["colours"].items > 0
