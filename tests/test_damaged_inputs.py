"""Damaged inputs end in one clear error (issue 24, item 3), never a traceback, silent garbage
or a runaway job: tree stores with a deleted or damaged chunk, texture pyramids with damaged
tiles, corrupt rasters, requests larger than the machine, runaway options, and a relative path
to a zipped SRTM tile."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from click.testing import CliRunner
from conftest import data_file

from approxtree import ApproximationTree, load_tree
from approxtree.cli import main
from approxtree.datasets import fractal_heights
from approxtree.errors import StoreError
from approxtree.geometry import Grid


def run(*args: object) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the CLI run in-process."""
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def assert_one_error_line(code: int, stderr: str, *words: str) -> None:
    """Exit 2 and a single ``Error:`` line holding every one of ``words``."""
    assert code == 2, stderr
    assert stderr.startswith("Error: "), stderr
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr, stderr
    for w in words:
        assert w in stderr, (w, stderr)


def flip_middle(path: Path, count: int = 1) -> None:
    """Flip ``count`` bytes in the middle of a file."""
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    for i in range(mid, mid + count):
        data[i] ^= 0x5A
    path.write_bytes(bytes(data))


def zip_folder(folder: Path, target: Path) -> Path:
    """A zip store holding the files of a folder store (stored, as the writer does)."""
    with zipfile.ZipFile(target, "w", compression=zipfile.ZIP_STORED) as z:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(folder).as_posix())
    return target


# -- tree stores -------------------------------------------------------------------------------

#: Chunks whose deletion went unnoticed by info and tiles (a ZeroDivisionError for the index).
DELETED = [
    "patches/grid/z_data/c/0",
    "terrain/heights/c/0/0",
    "nodes/errors/c/0",
    "patches/grid/index/c/0/0",
    "nodes/patch_slot/c/0",
]


@pytest.fixture(scope="module")
def good_store(tmp_path_factory) -> Path:
    """A small grid tree store over a 129 × 129 fractal placed in degrees (tiles both formats)."""
    heights = fractal_heights(129, seed=5) * 200.0
    grid = Grid(heights, Affine(0.0005, 0, -72.0, 0, -0.0005, 45.0), crs="EPSG:4326")
    tree = ApproximationTree.build(grid, epsilon=0.5, max_points=81, policy="grid", progress=False)
    path = tmp_path_factory.mktemp("store") / "good.zarr"
    tree.save(path)
    for key in DELETED:
        assert (path / key).is_file(), key
    return path


def damaged_copy(good: Path, tmp_path: Path, key: str, kind: str) -> Path:
    """A copy of the store without the chunk file ``key``, as a folder or a zip store."""
    folder = tmp_path / "damaged.zarr"
    shutil.copytree(good, folder)
    (folder / key).unlink()
    if kind == "dir":
        return folder
    return zip_folder(folder, tmp_path / "damaged.zarr.zip")


@pytest.mark.parametrize("kind", ["dir", "zip"])
@pytest.mark.parametrize("key", DELETED)
def test_every_store_reader_refuses_a_deleted_chunk(good_store, tmp_path, key, kind):
    """info, tiles (both formats), render, convert and load_tree name the missing chunk."""
    store = damaged_copy(good_store, tmp_path, key, kind)
    array, chunk = key.split("/c/")
    words = (str(store), array, f"c/{chunk}", "missing")
    with pytest.raises(StoreError, match="missing"):
        load_tree(store)
    for args in [
        ("info", store),
        ("tiles", store, "--out", tmp_path / "t3", "--format", "3dtiles"),
        ("tiles", store, "--out", tmp_path / "qm", "--format", "quantized-mesh"),
        ("render", store, "--out", tmp_path / "r.png", "--size", "64x48"),
        ("convert", store, tmp_path / "copy.zarr"),
    ]:
        code, _, err = run(*args)
        assert_one_error_line(code, err, *words)
    assert not (tmp_path / "t3").exists() and not (tmp_path / "qm").exists()


@pytest.mark.parametrize("fmt", ["3dtiles", "quantized-mesh"])
@pytest.mark.parametrize("key", ["terrain/heights/c/0/0", "patches/grid/index/c/0/0"])
def test_tiles_refuse_a_damaged_chunk_read_lazily(good_store, tmp_path, key, fmt):
    """A flipped byte in a chunk that tiles read as they go (terrain windows, patches) is one
    Error line naming the chunk, not different tiles."""
    store = tmp_path / "flipped.zarr"
    shutil.copytree(good_store, store)
    flip_middle(store / key)
    code, _, err = run("tiles", store, "--out", tmp_path / "out", "--format", fmt)
    if fmt == "quantized-mesh" and key.startswith("patches/"):
        # Quantized-mesh tiles sample the stored terrain only: the patches are never read.
        assert code == 0, err
        return
    array, chunk = key.split("/c/")
    assert_one_error_line(code, err, "corrupted", array, f"c/{chunk}")


def test_a_damaged_chunk_on_dask_workers_is_one_line(good_store, tmp_path):
    """With --workers 2 the workers' own logs of the failed tasks do not bury the Error line."""
    store = tmp_path / "flipped.zarr"
    shutil.copytree(good_store, store)
    flip_middle(store / "terrain/heights/c/0/0")
    args = ["tiles", store, "--out", tmp_path / "out", "--format", "quantized-mesh"]
    done = subprocess.run(
        [sys.executable, "-m", "approxtree", *map(str, args), "--workers", "2"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert_one_error_line(done.returncode, done.stderr, "corrupted", "terrain/heights", "c/0/0")


# -- texture pyramids --------------------------------------------------------------------------


def flip_in_first_tile(level: Path, count: int) -> None:
    """Flip ``count`` bytes inside the compressed data of tile (0, 0), band 1, of a level."""
    import rasterio

    with rasterio.open(level) as ds:
        offset = int(ds.get_tag_item("BLOCK_OFFSET_0_0", "TIFF", bidx=1))
        size = int(ds.get_tag_item("BLOCK_SIZE_0_0", "TIFF", bidx=1))
    data = bytearray(level.read_bytes())
    for i in range(offset + size // 2, offset + size // 2 + count):
        data[i] ^= 0x5A
    level.write_bytes(bytes(data))


@pytest.fixture(scope="module")
def baked(good_store, tmp_path_factory) -> Path:
    """The shading pyramid (grey and alpha, one tile) of the good store."""
    folder = tmp_path_factory.mktemp("tex") / "tex"
    code, _, err = run("bake", good_store, "--out", folder, "--no-gl", "-q")
    assert code == 0, err
    return folder


@pytest.mark.parametrize("count", [1, 64])
def test_render_and_tiles_refuse_a_damaged_pyramid(good_store, baked, tmp_path, count):
    """render --textures and tiles --textures on a pyramid whose level has flipped bytes: one
    Error line naming the level and tile (a ZSTD traceback, or the damaged texels drawn with
    exit 0, before)."""
    tex = tmp_path / "tex"
    shutil.copytree(baked, tex)
    flip_in_first_tile(tex / "level0.tif", count)
    words = ("level0.tif is damaged", "tile (0, 0)", "rebake")
    code, _, err = run(
        "render", good_store, "--textures", tex, "--out", tmp_path / "r.png", "--size", "64x48"
    )
    assert_one_error_line(code, err, *words)
    out = tmp_path / "t3"
    code, _, err = run("tiles", good_store, "--textures", tex, "--out", out, "--format", "3dtiles")
    assert_one_error_line(code, err, *words)


# -- corrupt rasters and vector layers -----------------------------------------------------------


def classes_tif(path: Path) -> Path:
    """A 120 × 140 uint8 class raster with a colour table, over the good store's domain."""
    import rasterio

    values = (np.arange(120 * 140).reshape(120, 140) // 3000 % 4 + 1).astype(np.uint8)
    transform = Affine(0.064 / 140, 0, -72.0, 0, -0.064 / 120, 45.0)
    with rasterio.open(
        path, "w", driver="GTiff", width=140, height=120, count=1, dtype="uint8",
        crs="EPSG:4326", transform=transform,
    ) as ds:  # fmt: skip
        ds.write(values, 1)
        ds.write_colormap(1, {1: (200, 0, 0), 2: (0, 200, 0), 3: (0, 0, 200), 4: (90, 90, 90)})
    return path


def damaged_files(tmp_path: Path) -> dict[str, Path]:
    """A class raster cut in half (its header intact) and one that is no raster at all."""
    good = classes_tif(tmp_path / "classes.tif")
    data = good.read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[: len(data) // 2])
    (tmp_path / "junk.tif").write_bytes(b"not a raster " * 64)
    return {"cut": tmp_path / "cut.tif", "junk": tmp_path / "junk.tif"}


@pytest.mark.parametrize("damage", ["cut", "junk"])
def test_a_corrupt_thematic_raster_is_one_error_line(good_store, tmp_path, damage):
    """bake --thematic with a truncated or non-raster file: one Error line naming it as a
    thematic raster (a RasterioIOError traceback before), as the same file is as a DEM and as
    a water mask."""
    bad = damaged_files(tmp_path)[damage]
    for texel in ([], ["--texel", "0.0005"]):
        code, _, err = run("bake", good_store, "--thematic", bad, "--out", tmp_path / "t", *texel)
        assert_one_error_line(code, err, str(bad), "thematic raster")
    code, _, err = run("info", bad)
    assert_one_error_line(code, err, str(bad))
    out = tmp_path / "qm"
    code, _, err = run(
        "tiles", good_store, "--format", "quantized-mesh", "--water-mask", bad, "--out", out
    )
    assert_one_error_line(code, err, str(bad))


def test_a_truncated_shapefile_is_refused_not_half_drawn(good_store, data_dir, tmp_path):
    """A shapefile cut short (GDAL reads the features past the cut as having no geometry,
    without a word) is refused as --roads, --water and --microstructures: one Error line."""

    streams = data_file(data_dir, "nc/streams.shp")
    cut = tmp_path / "cut.shp"
    cut.write_bytes(streams.read_bytes()[:3000])
    for ext in (".shx", ".dbf", ".prj"):
        shutil.copy(streams.with_suffix(ext), cut.with_suffix(ext))
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    for args in [
        ("bake", dem, "--roads", cut, "--out", tmp_path / "t"),
        ("bake", dem, "--water", cut, "--out", tmp_path / "t"),
        ("build", dem, "--microstructures", cut, "--out", tmp_path / "b.zarr"),
    ]:
        code, _, err = run(*args)
        assert_one_error_line(code, err, "cut.shp is truncated", "3000")


# -- requests larger than the machine --------------------------------------------------------------


def test_bake_refuses_a_texel_no_machine_can_hold(data_dir, tmp_path):
    """bake --texel 1e-6 on a 15 km DEM: one Error line saying what it would take (texture
    size, memory, the GeoTIFF side limit) and the texel that fits, before any work (an
    _ArrayMemoryError of 112 GiB before); the folder is not created."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    code, _, err = run("bake", dem, "--texel", "1e-6", "--out", tmp_path / "t")
    assert_one_error_line(code, err, "15000000000 × 13500000000", "memory", "texels a side")
    assert "Use a texel of at least" in err and not (tmp_path / "t").exists()


def test_bake_budget_counts_memory_disk_and_names_the_texel_that_fits(tmp_path):
    """check_bake_size: memory from the measured bytes per texel of each layer, disk from the
    uncompressed pyramid (refused only past the best compression), and the texel it names
    passes the same check."""
    from approxtree.errors import InvalidParameterError
    from approxtree.textures.bake_budget import (
        BEST_COMPRESSION,
        BYTES_PER_TEXEL,
        EXTRA_LAYER_BYTES,
        check_bake_size,
    )

    shape, layers = (20_000, 30_000), ["resampled", "thematic"]
    per_texel = max(BYTES_PER_TEXEL[k] for k in layers) + EXTRA_LAYER_BYTES
    need = 20_000 * 30_000 * per_texel
    args = dict(cell=30.0, layers=layers, bands=4, max_texture_size=4096, folder=tmp_path)
    check_bake_size(shape, 1.0, memory=need, free_disk=10**15, **args)
    said = rf"about {need / 1e9:.3g} GB in memory.*{per_texel} bytes"
    with pytest.raises(InvalidParameterError, match=said) as e:
        check_bake_size(shape, 1.0, memory=need // 4, free_disk=10**15, **args)
    fits = float(str(e.value).split("at least ")[1].split(" ")[0])
    assert 2.0 <= fits <= 2.1
    rows, cols = round(20_000 / fits), round(30_000 / fits)
    check_bake_size((rows, cols), fits, memory=need // 4, free_disk=10**15, **args)
    raw = sum(-(-20_000 // 2**k) * -(-30_000 // 2**k) for k in range(4)) * 4
    check_bake_size(shape, 1.0, memory=need, free_disk=raw // BEST_COMPRESSION + 1, **args)
    with pytest.raises(InvalidParameterError, match="uncompressed"):
        check_bake_size(shape, 1.0, memory=need, free_disk=raw // BEST_COMPRESSION - 10, **args)


# -- runaway options ---------------------------------------------------------------------------


@pytest.fixture
def no_cluster(monkeypatch):
    """Starting a local dask cluster fails the test (a runaway --workers must be refused
    before one starts)."""
    import approxtree.tiles.parallel as parallel
    import approxtree.tree.distributed as distributed

    def refuse(*args, **kwargs):
        raise AssertionError(f"a dask cluster was started with {args}")

    monkeypatch.setattr(distributed, "dask_client", refuse)
    monkeypatch.setattr(parallel, "dask_client", refuse)


def test_runaway_workers_are_refused_before_a_cluster_starts(good_store, tmp_path, no_cluster):
    """build, tiles (both formats) and fractal --workers 100000: one Error line with the most
    this machine takes (4 a core), before any worker starts."""
    import os

    most = str(4 * (os.cpu_count() or 1))
    dem = tmp_path / "dem.npy"
    np.save(dem, fractal_heights(40, seed=1))
    for args in [
        ("build", dem, "--out", tmp_path / "b.zarr", "--workers", "100000"),
        (
            "tiles",
            good_store,
            "--out",
            tmp_path / "t",
            "--format",
            "3dtiles",
            "--workers",
            "100000",
        ),
        (
            "tiles",
            good_store,
            "--out",
            tmp_path / "q",
            "--format",
            "quantized-mesh",
            "--workers",
            "100000",
        ),
        ("fractal", tmp_path / "f.tif", "--size", "64", "--workers", "100000"),
    ]:
        code, _, err = run(*args)
        assert_one_error_line(code, err, "100000", f"at most {most}")


def test_a_local_cluster_has_no_more_workers_than_tasks(monkeypatch):
    """A build of 4 blocks on workers=8 starts 4 workers (the others would only wait)."""
    import contextlib

    import approxtree.tree.distributed as distributed
    from approxtree.tree.blocks import BlockTask

    started = []

    @contextlib.contextmanager
    def fake_client(workers, scheduler, processes=True):
        started.append(workers)
        raise RuntimeError("stop here")
        yield  # pragma: no cover

    monkeypatch.setattr(distributed, "dask_client", fake_client)
    monkeypatch.setattr(distributed.os, "cpu_count", lambda: 2)
    run_tasks = distributed.dask_runner(workers=8)
    tasks = [object.__new__(BlockTask) for _ in range(4)]
    with pytest.raises(RuntimeError, match="stop here"):
        run_tasks(tasks)
    assert started == [4]


def test_a_block_size_below_the_least_is_refused_with_its_reason(tmp_path):
    """build --block-size 1 (minutes on a 500 × 450 DEM): one Error line naming the least
    block size and why."""
    dem = tmp_path / "dem.npy"
    np.save(dem, fractal_heights(40, seed=1))
    code, _, err = run("build", dem, "--out", tmp_path / "b.zarr", "--block-size", "1")
    assert_one_error_line(code, err, "--block-size 1", "64", "schedule")
    assert not (tmp_path / "b.zarr").exists()
    code, _, err = run("build", dem, "--out", tmp_path / "b.zarr", "--block-size", "64", "-q")
    assert code == 0, err


def test_mesh_refuses_a_lattice_strategy_of_a_point_cloud_before_reading_it(
    data_dir, tmp_path, monkeypatch
):
    """mesh x.laz --strategy grid is refused from the format: the points are never read
    (reading triangulates them all: 70 s for 5 million, so a large cloud ran past 90 s before
    the refusal a small one got at once)."""
    import approxtree.io as io

    laz = data_file(data_dir, "lidar/autzen_trim.laz")

    def never(*args, **kwargs):
        raise AssertionError("the point cloud was read")

    monkeypatch.setitem(
        io.FORMATS, "LAS/LAZ point cloud", io.Format("LAS/LAZ point cloud", (".las", ".laz"), never)
    )
    code, _, err = run("mesh", laz, "--strategy", "grid", "--max-error", "1")
    assert_one_error_line(code, err, "--strategy grid needs a raster grid", "tinpointset")


def test_mesh_budgets_beyond_the_terrain_are_clamped_with_a_warning(tmp_path):
    """--max-points 99999999999 and --max-triangles 99999999999: one Warning line each, and
    the mesh of every point (no larger budget is carried into the kernels)."""
    import json

    dem = tmp_path / "dem.npy"
    np.save(dem, fractal_heights(33, seed=2))
    for goal, word in (("--max-points", "data points"), ("--max-triangles", "triangles")):
        code, out, err = run("mesh", dem, goal, "99999999999", "--json", "-q")
        assert code == 0, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("Warning: ") and word in lines[0], err
        figures = json.loads(out)
        assert figures["vertices"] <= 33 * 33 and figures["max_error"] == 0.0


# -- relative paths ----------------------------------------------------------------------------


def test_a_zipped_srtm_tile_opens_from_a_relative_path(data_dir, monkeypatch):
    """info and open_terrain of N22W160v2.3a.hgt.zip from its own folder (a relative path):
    the tile reads as from its absolute path ("/vsizip/... does not exist" before)."""
    import approxtree as at

    tile = data_file(data_dir, "srtm/N22W160v2.3a.hgt.zip")
    whole = at.open_terrain(tile)
    monkeypatch.chdir(tile.parent)
    near = at.open_terrain(tile.name)
    assert near.shape == whole.shape == (1201, 1201) and near.crs == whole.crs
    np.testing.assert_array_equal(np.asarray(near.heights), np.asarray(whole.heights))
    code, out, err = run("info", tile.name)
    assert code == 0 and "1201" in out, err
