"""Fractal DEMs made block by block: seeded, crop-consistent, tiled and compressed, atomic,
and written in memory bounded by a few blocks."""

from __future__ import annotations

import json
import os
import tracemalloc

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from approxtree.cli import main
from approxtree.datasets import FractalHeights, write_fractal_terrain
from approxtree.errors import InvalidParameterError, StoreError
from approxtree.io.raster import read_raster


def _band(path) -> np.ndarray:
    with rasterio.open(path) as ds:
        return ds.read(1)


def test_same_seed_same_heights_other_seed_other_heights(tmp_path):
    a = write_fractal_terrain(tmp_path / "a.tif", 600, 520, seed=7, block=512)
    b = write_fractal_terrain(tmp_path / "b.tif", 600, 520, seed=7, block=1024, workers=1)
    c = write_fractal_terrain(tmp_path / "c.tif", 600, 520, seed=8, block=512)
    za, zb, zc = _band(a), _band(b), _band(c)
    # Block size and thread count do not change a single bit.
    assert np.array_equal(za, zb)
    assert np.abs(za - zc).mean() > 1.0


def test_a_small_dem_is_a_crop_of_a_large_one(tmp_path):
    small = _band(write_fractal_terrain(tmp_path / "s.tif", 700, 600, seed=3, block=512))
    large = _band(write_fractal_terrain(tmp_path / "l.tif", 1500, 1300, seed=3, block=1024))
    assert np.array_equal(large[:700, :600], small)
    # Any window read on its own equals the same window of the file.
    window = FractalHeights((1500, 1300), seed=3).read(650, 1100, 480, 1300)
    assert np.array_equal(window, large[650:1100, 480:1300])


def test_heights_look_like_terrain_in_metres():
    z = FractalHeights((2048, 2048), seed=1).read(0, 2048, 0, 2048).astype(np.float64)
    # Hundreds of metres of relief over the raster, centimetres to a metre between neighbours.
    assert 50.0 < z.max() - z.min() < 1000.0
    steps = np.abs(np.diff(z, axis=1))
    assert 0.01 < np.median(steps) < 1.0
    assert np.isfinite(z).all()


def test_tiled_compressed_georeferenced_file(tmp_path):
    path = write_fractal_terrain(
        tmp_path / "dem.tif", 1100, 900, seed=2, cell_size=2.5, crs="EPSG:32633",
        origin=(500_000.0, 5_200_000.0), compress="zstd",
    )  # fmt: skip
    with rasterio.open(path) as ds:
        assert ds.profile["tiled"]
        assert (ds.profile["blockxsize"], ds.profile["blockysize"]) == (512, 512)
        assert ds.profile["compress"] == "zstd"
        assert ds.tags(ns="IMAGE_STRUCTURE")["PREDICTOR"] == "3"
        assert ds.dtypes[0] == "float32"
        assert ds.crs.to_epsg() == 32633
        assert tuple(ds.transform)[:6] == (2.5, 0.0, 500_000.0, 0.0, -2.5, 5_200_000.0)
    assert os.path.getsize(path) < 1100 * 900 * 4
    grid = read_raster(path)
    d = grid.domain
    assert (d.xmin, d.ymax) == (500_001.25, 5_199_998.75)


def test_cog_layout_with_overviews(tmp_path):
    path = write_fractal_terrain(tmp_path / "dem.tif", 1500, seed=4, cog=True)
    with rasterio.open(path) as ds:
        assert ds.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert ds.overviews(1)
        assert ds.profile["blockxsize"] == 512
        z = ds.read(1)
    assert np.array_equal(z, FractalHeights((1500, 1500), seed=4).read(0, 1500, 0, 1500))
    # The tiled file the COG was copied from is gone: only the DEM is left.
    assert os.listdir(tmp_path) == ["dem.tif"]


def test_holes_are_nan_nodata_and_crop_consistent(tmp_path):
    path = write_fractal_terrain(
        tmp_path / "h.tif", 1200, seed=5, holes=0.2, wavelength=1024, block=512
    )
    with rasterio.open(path) as ds:
        assert np.isnan(ds.nodata)
        z = ds.read(1)
    fraction = np.isnan(z).mean()
    assert 0.05 < fraction < 0.4
    crop = FractalHeights((300, 300), seed=5, holes=0.2, wavelength=1024).read(0, 300, 0, 300)
    assert np.array_equal(crop, z[:300, :300], equal_nan=True)
    assert read_raster(path).nodata_count == np.isnan(z).sum()


def test_memory_stays_at_a_few_blocks(tmp_path):
    """Writing a 4096² DEM (a 64 MiB band) in 512² blocks allocates a few MiB at most."""
    # Kernels compiled and dask, GDAL and tqdm imported before measuring.
    write_fractal_terrain(tmp_path / "warm.tif", 600, seed=0, block=512)
    tracemalloc.start()
    try:
        write_fractal_terrain(tmp_path / "big.tif", 4096, seed=0, block=512, workers=2)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    band = 4096 * 4096 * 4
    assert peak < band / 8, f"peak {peak / 2**20:.1f} MiB for a {band / 2**20:.0f} MiB band"


class _Boom(RuntimeError):
    pass


def test_a_failed_write_leaves_the_old_file_and_no_temp(tmp_path, monkeypatch):
    target = tmp_path / "dem.tif"
    target.write_bytes(b"old")
    calls = []
    read = FractalHeights.read

    def failing(self, *window):
        calls.append(window)
        if len(calls) == 3:
            raise _Boom("disk on fire")
        return read(self, *window)

    monkeypatch.setattr(FractalHeights, "read", failing)
    with pytest.raises(_Boom):
        write_fractal_terrain(target, 2048, seed=1, block=512, workers=1)
    assert target.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["dem.tif"]


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"rows": 1}, "2 × 2"),
        ({"rows": 64, "cols": 0}, "2 × 2"),
        ({"rows": 64, "hurst": 0.0}, "hurst"),
        ({"rows": 64, "relief": -1.0}, "relief"),
        ({"rows": 64, "holes": 1.0}, "holes"),
        ({"rows": 64, "wavelength": 1.0}, "wavelength"),
        ({"rows": 64, "cell_size": 0.0}, "cell_size"),
        ({"rows": 64, "block": 1000}, "multiple of 512"),
        ({"rows": 64, "workers": 0}, "workers"),
        ({"rows": 64, "compress": "jpeg"}, "compression"),
        ({"rows": 64, "crs": "EPSG:nope"}, "CRS"),
    ],
)
def test_bad_parameters_say_what_is_wrong(tmp_path, kwargs, words):
    with pytest.raises(InvalidParameterError, match=words):
        write_fractal_terrain(tmp_path / "x.tif", **kwargs)
    assert not os.listdir(tmp_path)


def test_missing_folder_is_a_store_error(tmp_path):
    with pytest.raises(StoreError, match="does not exist"):
        write_fractal_terrain(tmp_path / "no" / "x.tif", 64)


def test_cli_writes_the_dem_and_reports_figures(tmp_path):
    out = tmp_path / "dem.tif"
    result = CliRunner().invoke(
        main,
        [
            "fractal", str(out), "--size", "700", "--cols", "600", "--seed", "3",
            "--cell-size", "2", "--crs", "EPSG:32633", "--block", "512", "--json",
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    figures = json.loads(result.stdout)
    assert (figures["rows"], figures["cols"]) == (700, 600)
    assert figures["bytes"] == os.path.getsize(out)
    assert np.array_equal(_band(out), FractalHeights((700, 600), seed=3).read(0, 700, 0, 600))
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 32633
        assert ds.res == (2.0, 2.0)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--size", "1"], "2 × 2"),
        (["--size", "64", "--block", "100"], "multiple of 512"),
        (["--size", "64", "--crs", "nope"], "CRS"),
        (["--size", "64", "--holes", "2"], "holes"),
    ],
)
def test_cli_bad_parameters_give_one_error_line(tmp_path, args, words):
    result = CliRunner().invoke(main, ["fractal", str(tmp_path / "x.tif"), *args])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error:") and words in lines[0]
    assert not os.listdir(tmp_path)


def test_heights_pickle_as_their_parameters():
    """dask ships the source to its workers: a 32768² source pickles in a few hundred bytes."""
    import pickle

    source = FractalHeights((32768, 32768), seed=9, holes=0.1)
    window = source.read(30000, 30100, 100, 300)
    blob = pickle.dumps(source)
    assert len(blob) < 1000
    assert np.array_equal(pickle.loads(blob).read(30000, 30100, 100, 300), window, equal_nan=True)


def test_cli_output_under_a_file_is_one_error_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    result = CliRunner().invoke(main, ["fractal", str(blocker / "dem.tif"), "--size", "64"])
    assert result.exit_code == 2
    assert result.stderr.startswith("Error:") and "is a file, not a folder" in result.stderr


def test_an_interrupt_leaves_no_write_into_the_closed_dataset(tmp_path, monkeypatch):
    """Ctrl-C or SIGTERM raises in the main thread while dask's threads still compute blocks:
    once the dataset closes, those blocks write nothing (their writes into the closed file
    crashed the process with a segfault and left its temp file)."""
    import _thread
    import threading

    import dask.array as da
    from affine import Affine

    from approxtree.io import tiled_geotiff

    release, written = threading.Event(), threading.Event()
    writes: list[bool] = []

    class Recording:
        """The open dataset, recording each write and whether the file was closed then."""

        def __init__(self, ds):
            self.ds, self.height, self.width, self.dtypes = ds, ds.height, ds.width, ds.dtypes

        def write(self, *args, **kwargs):
            writes.append(self.ds.closed)
            if not self.ds.closed:
                self.ds.write(*args, **kwargs)

        def __getattr__(self, name):
            return getattr(self.ds, name)

    real_open = rasterio.open

    class Opened:
        """rasterio.open as _write_blocks uses it, giving the Recording dataset."""

        def __init__(self, *args, **kwargs):
            self.ds = real_open(*args, **kwargs)

        def __enter__(self):
            return Recording(self.ds)

        def __exit__(self, *exc):
            self.ds.close()

    monkeypatch.setattr(rasterio, "open", Opened)
    real_setitem = tiled_geotiff._BandWriter.__setitem__

    def setitem(self, key, block):
        real_setitem(self, key, block)
        written.set()

    monkeypatch.setattr(tiled_geotiff._BandWriter, "__setitem__", setitem)

    def first(block_info=None):
        # Block 0 interrupts the main thread (as Ctrl-C would) while block 1 still computes.
        _thread.interrupt_main()
        return np.zeros((8, 8), dtype=np.float32)

    def second(block_info=None):
        release.wait(30)
        return np.ones((8, 8), dtype=np.float32)

    blocks = da.concatenate(
        [
            da.map_blocks(first, chunks=((8,), (8,)), dtype=np.float32, meta=np.zeros((0, 0))),
            da.map_blocks(second, chunks=((8,), (8,)), dtype=np.float32, meta=np.zeros((0, 0))),
        ],
        axis=1,
    )
    profile = {
        "driver": "GTiff",
        "width": 16,
        "height": 8,
        "count": 1,
        "dtype": "float32",
        "transform": Affine(1.0, 0.0, 0.0, 0.0, -1.0, 8.0),
    }
    with pytest.raises(KeyboardInterrupt):
        tiled_geotiff._write_blocks(tmp_path / "f.tif", profile, blocks, None, 2)
    # Block 1 finishes only now, after the dataset closed: its write must not reach it.
    release.set()
    assert written.wait(30)
    assert True not in writes


def test_sigterm_twice_mid_write_removes_the_temp_and_keeps_the_old_file(tmp_path):
    """``timeout`` sends SIGTERM to the command and its process group: the first signal unwinds
    the write, a second one is ignored, and blocks dask's threads still compute write nothing
    into the closed dataset (it crashed with a segfault and left a 50 MB temp file)."""
    import signal
    import subprocess
    import sys

    out = tmp_path / "f.tif"
    out.write_bytes(b"old")
    cmd = [sys.executable, "-m", "approxtree", "fractal", str(out), "--size", "16385"]
    cmd += ["--overwrite"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    assert proc.stderr is not None
    # The progress bar (shown for more than 16 blocks) says when the first block is written.
    line = ""
    while "1/" not in line and proc.poll() is None:
        line = proc.stderr.read(64)
    proc.send_signal(signal.SIGTERM)
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=120)
    assert proc.returncode == -signal.SIGTERM
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.tif"]
    assert out.read_bytes() == b"old"
