"""Re-bakes: after an edit or a new light, the pyramid equals a fresh bake's, tile for tile."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from conftest import data_file
from test_update_store import write_patch

from approxtree.cli import main
from approxtree.errors import InvalidParameterError, StoreError
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.io import read_grid
from approxtree.textures.bake import bake
from approxtree.textures.pyramid import TexturePyramid
from approxtree.textures.rebake import rebake
from approxtree.tree.approximation_tree import ApproximationTree

TILE = 512


def same_pyramid(a: Path, b: Path) -> None:
    """Two pyramids hold the same texels and tile checksums on every level."""
    pa, pb = TexturePyramid(a), TexturePyramid(b)
    assert len(pa) == len(pb)
    for k in range(len(pa)):
        assert pa.tile_crc32c[k] == pb.tile_crc32c[k], k
        np.testing.assert_array_equal(pa.level(k), pb.level(k))


def cells_rect(grid: Grid, r0: int, c0: int, rows: int, cols: int) -> Rect:
    """The world rect of the grid's cells r0..r0+rows, c0..c0+cols (on cell edges)."""
    t = grid.transform
    x0, y0 = t @ (c0, r0)
    x1, y1 = t @ (c0 + cols, r0 + rows)
    return Rect(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))


def reached_tiles(window: tuple[int, int, int, int], pyramid: TexturePyramid) -> list[set]:
    """Per level, the (row, col) tiles that the cells r0..r1, c0..c1 (half-open, level-0
    texels) reach: one texel more for the 3 × 3 gradient, then halved outwards level by level."""
    r0, r1, c0, c1 = window
    lv0 = pyramid.levels[0]
    r0, r1 = max(r0 - 1, 0), min(r1 + 1, lv0.height)
    c0, c1 = max(c0 - 1, 0), min(c1 + 1, lv0.width)
    out = []
    for _ in pyramid.levels:
        rows = range(r0 // TILE, -(-r1 // TILE))
        out.append({(i, j) for i in rows for j in range(c0 // TILE, -(-c1 // TILE))})
        r0, r1, c0, c1 = r0 // 2, -(-r1 // 2), c0 // 2, -(-c1 // 2)
    return out


def raw_tiles(path: Path) -> dict[tuple[int, int, int], bytes]:
    """The compressed bytes of every tile of every band of a level file, by (band, row, col)."""
    data = path.read_bytes()
    out = {}
    with rasterio.open(path) as ds:
        for band in ds.indexes:
            for (i, j), _ in ds.block_windows(band):
                offset = int(ds.get_tag_item(f"BLOCK_OFFSET_{j}_{i}", "TIFF", bidx=band))
                size = int(ds.get_tag_item(f"BLOCK_SIZE_{j}_{i}", "TIFF", bidx=band))
                out[band, i, j] = data[offset : offset + size]
    return out


def edit_and_compare(tmp_path: Path, grid: Grid, edits, max_texture_size: int, **bake_args):
    """Bake ``grid``, apply each (r0, c0, heights) edit with a re-bake, compare with a fresh
    bake of the edited grid after each; returns the re-bakes."""
    folder = tmp_path / "pyramid"
    bake(grid, folder, gl=False, max_texture_size=max_texture_size, **bake_args)
    heights = np.array(grid.heights_array("test"), dtype=np.float64)
    done = []
    for i, (r0, c0, patch) in enumerate(edits):
        heights[r0 : r0 + patch.shape[0], c0 : c0 + patch.shape[1]] = patch
        edited = Grid(heights.astype(np.float32), grid.transform, grid.crs, allow_empty=True)
        rect = cells_rect(grid, r0, c0, *patch.shape)
        done.append(rebake(folder, edited, rect))
        fresh = tmp_path / f"fresh{i}"
        bake(edited, fresh, gl=False, max_texture_size=max_texture_size, **bake_args)
        same_pyramid(folder, fresh)
    return done


@pytest.fixture
def nc(data_dir) -> Grid:
    """The NC DEM (500 × 450, 30 m cells)."""
    return read_grid(data_file(data_dir, "nc/elev_ned_30m.tif"))


def random_edits(grid: Grid, seed: int, count: int, largest: int) -> list:
    """``count`` seeded random windows of the grid, each dug or raised, some with nodata."""
    rng = np.random.default_rng(seed)
    z = np.array(grid.heights_array("test"), dtype=np.float64)
    edits = []
    for _ in range(count):
        rows, cols = rng.integers(1, largest, size=2)
        r0 = int(rng.integers(0, grid.height - rows + 1))
        c0 = int(rng.integers(0, grid.width - cols + 1))
        patch = (
            z[r0 : r0 + rows, c0 : c0 + cols] + rng.normal(0, 20) + rng.normal(0, 2, (rows, cols))
        )
        if rng.random() < 0.5:
            patch[rng.random(patch.shape) < 0.2] = np.nan
        edits.append((r0, c0, patch))
    return edits


def test_nc_random_windows_equal_fresh_bakes(nc, tmp_path) -> None:
    """Random windows (nodata, edges) on the NC DEM: after each re-bake the pyramid is a fresh
    bake's, texel for texel and checksum for checksum, and only the reached tiles are written."""
    edits = random_edits(nc, seed=29, count=4, largest=90)
    edits.append((0, 430, np.full((20, 70), 60.0)))  # the north-east corner
    done = edit_and_compare(tmp_path, nc, edits, max_texture_size=64)
    pyramid = TexturePyramid(tmp_path / "pyramid")
    for (r0, c0, patch), result in zip(edits, done, strict=True):
        window = (r0, r0 + patch.shape[0], c0, c0 + patch.shape[1])
        assert not result.whole
        assert result.tiles == [len(t) for t in reached_tiles(window, pyramid)]


def test_fractal_with_holes_rewrites_only_reached_tiles(tmp_path) -> None:
    """A 1200 × 1100 fractal with a nodata hole, windows across tile edges: equal to fresh bakes,
    with fewer tiles written than the levels hold."""
    from approxtree.datasets import fractal_terrain

    grid = fractal_terrain(1200, 1100, seed=3)
    z = np.array(grid.heights)
    z[300:340, 700:760] = np.nan
    grid = Grid(z, grid.transform, allow_empty=True)
    edits = [
        (500, 490, np.full((40, 50), 300.0)),  # across the tile edge at row and column 512
        (1150, 1030, np.array(z[1150:1200, 1030:1100]) - 50.0),  # the south-east corner
        (290, 690, np.full((20, 30), np.nan)),  # more nodata beside the hole
    ]
    bake(grid, tmp_path / "before", gl=False, max_texture_size=128)
    done = edit_and_compare(tmp_path, grid, edits, max_texture_size=128)
    pyramid = TexturePyramid(tmp_path / "pyramid")
    reached = [set() for _ in pyramid.levels]
    for (r0, c0, patch), result in zip(edits, done, strict=True):
        window = (r0, r0 + patch.shape[0], c0, c0 + patch.shape[1])
        tiles = reached_tiles(window, pyramid)
        assert result.tiles == [len(t) for t in tiles]
        assert sum(result.tiles) < sum(result.tiles_total)
        reached = [a | b for a, b in zip(reached, tiles, strict=True)]
    assert done[0].tiles[0] == 4 and done[1].tiles[0] == 1
    # Every tile no edit reached keeps its very bytes in the level files (the base file: no
    # delta holds it, and a level written whole again encodes it the same).
    for k, lv in enumerate(pyramid.levels):
        old, new = raw_tiles(tmp_path / "before" / f"level{k}.tif"), raw_tiles(lv.path)
        kept = [key for key in old if key[1:] not in reached[k]]
        assert all(old[key] == new[key] for key in kept), k
        assert kept or k > 0


def test_resampled_lattice_equals_fresh_bake(nc, tmp_path) -> None:
    """Texels three times finer than the cells (h_T interpolated): re-bakes equal fresh bakes."""
    edits = random_edits(nc, seed=7, count=2, largest=40)
    done = edit_and_compare(tmp_path, nc, edits, max_texture_size=256, texel_size=10.0)
    assert all(not d.whole and sum(d.tiles) < sum(d.tiles_total) for d in done)


def test_slope_weight_is_local_shadows_rebake_whole(nc, tmp_path) -> None:
    """A slope-weighted shading follows tile by tile; cast shadows re-bake the pyramid whole;
    both equal fresh bakes."""
    edits = random_edits(nc, seed=11, count=1, largest=50)
    (tmp_path / "slope").mkdir()
    (tmp_path / "shadows").mkdir()
    local = edit_and_compare(
        tmp_path / "slope", nc, edits, 64, shading_options={"slope_weight": 0.5}
    )
    whole = edit_and_compare(tmp_path / "shadows", nc, edits, 64, shading_options={"shadows": True})
    assert not local[0].whole and whole[0].whole


def test_new_light_equals_fresh_bake(nc, tmp_path) -> None:
    """A new azimuth and altitude re-bake the shading whole, as a fresh bake with that light,
    and the recipe keeps the light for the next re-bake."""
    bake(nc, tmp_path / "p", gl=False, max_texture_size=128, shading_options={"z_factor": 2.0})
    result = rebake(tmp_path / "p", nc, shading_options={"azimuth": 200.0, "altitude": 30.0})
    assert result.whole
    light = {"z_factor": 2.0, "azimuth": 200.0, "altitude": 30.0}
    bake(nc, tmp_path / "q", gl=False, max_texture_size=128, shading_options=light)
    same_pyramid(tmp_path / "p", tmp_path / "q")
    assert TexturePyramid(tmp_path / "p").recipe["shading_options"] == light


def test_refuses_array_pyramids_and_other_terrains(nc, tmp_path) -> None:
    """An array-built pyramid and another terrain's are refused with a reason (pyramids with
    thematic layers and overlays re-bake: test_rebake_layers.py)."""
    rgba = np.zeros((8, 8, 4), dtype=np.uint8)
    TexturePyramid.build(rgba, tmp_path / "array", transform=nc.transform)
    with pytest.raises(StoreError, match="no bake recipe"):
        rebake(tmp_path / "array", nc, cells_rect(nc, 0, 0, 2, 2))
    bake(nc, tmp_path / "p", gl=False, max_texture_size=128)
    other = nc.window(0, 99, 0, 99)
    with pytest.raises(InvalidParameterError, match="not baked from this terrain"):
        rebake(tmp_path / "p", Grid(np.array(other.heights), nc.transform), None)


@pytest.fixture
def stored(nc, tmp_path):
    """The NC DEM's tree as a store, its pyramid (10 m texels), a pit patch, and a fresh bake
    of the edited DEM."""
    store = tmp_path / "dem.zarr"
    ApproximationTree.build(nc, epsilon=2.0, max_points=33 * 33).save(store)
    textures = tmp_path / "textures"
    terrain = ApproximationTree.load(store).terrain
    bake(terrain, textures, gl=False, max_texture_size=256, texel_size=10.0)
    r0, c0 = 200, 120
    pit = np.array(nc.heights[r0 : r0 + 50, c0 : c0 + 70], dtype=np.float64) - 30.0
    pit[:4, :6] = np.nan
    patch = tmp_path / "pit.tif"
    write_patch(patch, nc, r0, c0, pit)
    edited = np.array(nc.heights, dtype=np.float64)
    edited[r0 : r0 + 50, c0 : c0 + 70] = pit
    fresh = tmp_path / "fresh"
    grid = Grid(edited.astype(np.float32), nc.transform, nc.crs, nc.nodata)
    bake(grid, fresh, gl=False, max_texture_size=256, texel_size=10.0)
    return store, textures, patch, fresh


def test_cli_update_textures_equals_fresh_bake(stored) -> None:
    """``update STORE PATCH --textures DIR`` leaves the pyramid a fresh bake of the edited DEM
    writes, and says how many tiles it re-baked."""
    store, textures, patch, fresh = stored
    args = ["update", str(store), str(patch), "--textures", str(textures), "--json"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    assert 0 < figures["textures"]["tiles"] < figures["textures"]["tiles_total"]
    same_pyramid(textures, fresh)


def test_cli_new_light_without_patch(stored, tmp_path) -> None:
    """``update STORE --textures DIR --azimuth A --altitude H`` is a fresh bake with that light."""
    store, textures, _, _ = stored
    args = [
        "update",
        str(store),
        "--textures",
        str(textures),
        "--azimuth",
        "90",
        "--altitude",
        "20",
    ]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert "whole" in result.output
    terrain = ApproximationTree.load(store).terrain
    light = {"azimuth": 90.0, "altitude": 20.0}
    bake(
        terrain,
        tmp_path / "lit",
        gl=False,
        max_texture_size=256,
        texel_size=10.0,
        shading_options=light,
    )
    same_pyramid(textures, tmp_path / "lit")


def _update_in_a_process(
    code: str, store: Path, patch: Path, textures: Path, kill: str | None = None
) -> subprocess.CompletedProcess:
    """``update STORE PATCH --textures DIR`` run by ``python -c CODE`` in a process of its own
    (this checkout first on the path; ``kill``: APPROXTREE_UPDATE_KILL's stage)."""
    env = dict(os.environ)
    if kill is not None:
        env["APPROXTREE_UPDATE_KILL"] = kill
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    argv = ["update", str(store), str(patch), "--textures", str(textures)]
    return subprocess.run(
        [sys.executable, "-c", code, *argv], env=env, capture_output=True, text=True, check=False
    )


def test_killed_between_store_and_textures(stored) -> None:
    """A kill after the store swap leaves the new tree with the old, intact pyramid; the
    update without a patch then re-bakes it to the fresh bake's texels."""
    store, textures, patch, fresh = stored
    before = {k: TexturePyramid(textures).tile_crc32c[k] for k in range(2)}
    proc = _update_in_a_process(
        "from approxtree.cli import main; main()", store, patch, textures, "saved"
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert {k: TexturePyramid(textures).tile_crc32c[k] for k in range(2)} == before
    result = CliRunner().invoke(main, ["update", str(store), "--textures", str(textures)])
    assert result.exit_code == 0, result.output
    same_pyramid(textures, fresh)


def test_rising_water_level_equals_fresh_bakes(nc, tmp_path) -> None:
    """A flood (water layer under the shading) rising step by step, with a terrain edit in
    between: each re-bake equals a fresh bake with that level, tile for tile."""
    levels = [60.0, 75.0, 75.5, 90.0]
    bake(nc, tmp_path / "p", gl=False, max_texture_size=256, texel_size=10.0, water_level=50.0)
    heights = np.array(nc.heights, dtype=np.float64)
    for i, level in enumerate(levels):
        if i == 2:
            heights[200:260, 100:180] -= 40.0
        grid = Grid(heights.astype(np.float32), nc.transform, nc.crs)
        rect = cells_rect(nc, 200, 100, 60, 80) if i == 2 else None
        result = rebake(tmp_path / "p", grid, rect, water_level=level)
        assert not result.whole and sum(result.tiles) <= sum(result.tiles_total)
        fresh = tmp_path / f"fresh{i}"
        bake(grid, fresh, gl=False, max_texture_size=256, texel_size=10.0, water_level=level)
        same_pyramid(tmp_path / "p", fresh)
        assert TexturePyramid(tmp_path / "p").recipe["water_level"] == level
    # Drained below every height (55 m at least), then lowered again: that changes no texel,
    # nothing is written, and the level is kept.
    rebake(tmp_path / "p", grid, water_level=50.0)
    result = rebake(tmp_path / "p", grid, water_level=40.0)
    assert sum(result.tiles) == 0 and TexturePyramid(tmp_path / "p").recipe["water_level"] == 40.0


KILL_MID_REBAKE = """
import os, signal, sys
import approxtree.textures.rebake as rebake
calls = [0]
original = rebake._write_tiles
def write_tiles(*args, **kwargs):
    calls[0] += 1
    if calls[0] == 2:
        os.kill(os.getpid(), signal.SIGKILL)
    return original(*args, **kwargs)
rebake._write_tiles = write_tiles
from approxtree.cli import main
main(sys.argv[1:])
"""


def strays(textures: Path) -> set[str]:
    """Files of a pyramid folder that its pyramid.json does not list."""
    return set(os.listdir(textures)) - TexturePyramid(textures).files - {"pyramid.json"}


def test_killed_rebake_leaves_old_pyramid(stored) -> None:
    """SIGKILL between two level writes of a re-bake (after the store swap) leaves the old
    pyramid whole (every tile checks); the next update re-bakes it and removes the killed
    writer's files."""
    store, textures, patch, fresh = stored
    before = TexturePyramid(textures)
    old = [before.level(k) for k in range(len(before))]
    result = CliRunner().invoke(main, ["update", str(store), str(patch)])
    assert result.exit_code == 0, result.output
    proc = _update_in_a_process(KILL_MID_REBAKE, store, patch, textures)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    after = TexturePyramid(textures)
    for k, texels in enumerate(old):
        np.testing.assert_array_equal(after.level(k), texels)
    assert strays(textures)
    result = CliRunner().invoke(main, ["update", str(store), "--textures", str(textures)])
    assert result.exit_code == 0, result.output
    same_pyramid(textures, fresh)
    assert not strays(textures)
    assert not [p for p in textures.parent.iterdir() if p.name.startswith(".textures.")]


@pytest.mark.parametrize("stage", ["rebake-written", "rebake-committed"])
def test_killed_before_and_after_commit(stored, stage) -> None:
    """SIGKILL with every delta written but pyramid.json not yet replaced leaves the old
    pyramid; right after the commit, the new one (a fresh bake's texels); either way the
    next re-bake removes the files no pyramid.json lists."""
    store, textures, patch, fresh = stored
    before = TexturePyramid(textures)
    old = [before.level(k) for k in range(len(before))]
    # A first re-bake elsewhere, so that the killed one has deltas to replace.
    result = CliRunner().invoke(
        main, ["update", str(store), str(patch), "--textures", str(textures)]
    )
    assert result.exit_code == 0, result.output
    meta = json.loads((textures / "pyramid.json").read_text())
    proc = _update_in_a_process(
        "from approxtree.cli import main; main()", store, patch, textures, stage
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    if stage == "rebake-written":
        assert json.loads((textures / "pyramid.json").read_text()) == meta
        assert strays(textures)
    else:
        assert json.loads((textures / "pyramid.json").read_text())["build"] != meta["build"]
    same_pyramid(textures, fresh)
    assert any((TexturePyramid(textures).level(k) != texels).any() for k, texels in enumerate(old))
    result = CliRunner().invoke(
        main, ["update", str(store), str(patch), "--textures", str(textures)]
    )
    assert result.exit_code == 0, result.output
    same_pyramid(textures, fresh)
    assert not strays(textures)


def test_cli_bake_and_update_water_level(nc, tmp_path) -> None:
    """``bake --water-level`` then ``update STORE --textures DIR --water-level Z`` leave the
    pyramid a fresh bake with level Z writes, re-baking fewer tiles than the pyramid holds."""
    store = tmp_path / "dem.zarr"
    ApproximationTree.build(nc, epsilon=2.0, max_points=33 * 33).save(store)
    textures = tmp_path / "flood"
    args = ["bake", str(store), "--out", str(textures), "--texel", "10", "--no-gl"]
    args += ["--max-texture-size", "256", "--water-level", "60", "--quiet"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    args = ["update", str(store), "--textures", str(textures), "--water-level", "66", "--json"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)["textures"]
    assert not figures["whole"] and 0 < figures["tiles"] < figures["tiles_total"]
    terrain = ApproximationTree.load(store).terrain
    bake(
        terrain,
        tmp_path / "fresh",
        gl=False,
        max_texture_size=256,
        texel_size=10.0,
        water_level=66.0,
    )
    same_pyramid(textures, tmp_path / "fresh")


def test_level_files_stay_compact_over_many_rebakes(nc, tmp_path) -> None:
    """Rewritten tiles go to deltas beside a level file; after many re-bakes each level's files
    stay within GROWTH times its size when last written whole, and the pyramid is still a
    fresh bake's."""
    from approxtree.textures.rebake import GROWTH

    folder = tmp_path / "p"
    bake(nc, folder, gl=False, max_texture_size=256, texel_size=10.0)
    heights = np.array(nc.heights, dtype=np.float64)
    first = TexturePyramid(folder).levels[0].path.stat().st_size
    # Four windows, each across a different 2 × 2 of level 0's 3 × 3 tiles (170.7 cells a
    # tile): no delta covers another, so they pile up until the level is written whole.
    for i in range(8):
        r0, c0 = (160, 330)[i % 2], (160, 330)[i // 2 % 2]
        heights[r0 : r0 + 20, c0 : c0 + 20] -= 3.0
        grid = Grid(heights.astype(np.float32), nc.transform, nc.crs)
        rebake(folder, grid, cells_rect(nc, r0, c0, 20, 20))
    entries = json.loads((folder / "pyramid.json").read_text())["levels"]
    for entry in entries:
        total = entry["bytes"] + sum(d["bytes"] for d in entry.get("deltas", []))
        assert total <= GROWTH * entry["compact_bytes"]
    assert entries[0]["compact_bytes"] != first  # level 0 was written whole again at least once
    bake(grid, tmp_path / "fresh", gl=False, max_texture_size=256, texel_size=10.0)
    same_pyramid(folder, tmp_path / "fresh")


def test_level_written_whole_again_equals_fresh_bake(nc, tmp_path, monkeypatch) -> None:
    """With no delta allowed every re-bake writes each level whole again (its other tile rows
    read from the pyramid): an edit in the first tile row only still gives a fresh bake's
    texels, and the old level files go."""
    import approxtree.textures.rebake as module

    monkeypatch.setattr(module, "MAX_DELTAS", 0)
    edits = [(10, 20, np.full((15, 25), 90.0)), (400, 300, np.full((30, 30), np.nan))]
    edit_and_compare(tmp_path, nc, edits, max_texture_size=256, texel_size=10.0)
    meta = json.loads((tmp_path / "pyramid" / "pyramid.json").read_text())
    assert all(
        not lv["deltas"] and lv["file"] != f"level{k}.tif" for k, lv in enumerate(meta["levels"])
    )
    assert not strays(tmp_path / "pyramid")
