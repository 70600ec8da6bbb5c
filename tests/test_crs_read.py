"""A CRS the raster declares is never lost without a word (issue 24, item 6).

GDAL reports a CRS it could not build from a GeoTIFF's keys as no CRS at all (rasterio's
``crs`` None), the answer it gives for a file without one. The tests make GDAL's answer empty
(``DatasetReader.read_crs`` returning None, as rasterio does for GDAL's empty projection) and
check that every path reading the DEM (in memory, windowed, zipped, build, tiles) refuses it,
naming the keys, instead of making a grid, a store or tiles without the CRS; a GeoTIFF that
really has no CRS still reads without one.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
import rasterio
import rasterio.io
from affine import Affine
from click.testing import CliRunner
from conftest import data_file

from approxtree.cli import main
from approxtree.errors import TerrainFormatError
from approxtree.io import open_terrain
from approxtree.io.geokeys import declared_model
from approxtree.io.raster import read_raster
from approxtree.tiles.sampling import TileSampler

LOST = "GeoTIFF keys declare a projected one"


@pytest.fixture
def nc_dem(data_dir) -> Path:
    return data_file(data_dir, "nc/elev_ned_30m.tif")


@pytest.fixture
def gdal_builds_no_crs(monkeypatch):
    """GDAL's projection comes back empty for every dataset opened (rasterio: crs None)."""
    monkeypatch.setattr(rasterio.io.DatasetReader, "read_crs", lambda self: None)


def _write_tif(path: Path, **options) -> Path:
    with rasterio.open(
        path, "w", driver="GTiff", width=4, height=3, count=1, dtype="float32", **options
    ) as ds:
        ds.write(np.arange(12, dtype="float32").reshape(3, 4), 1)
    return path


def test_geotiff_keys_declare_the_model(nc_dem, data_dir, tmp_path):
    """declared_model reads GTModelTypeGeoKey in classic and BigTIFF, either byte order, and
    answers None for files without GeoKeys, without a model, or not TIFF at all."""
    assert declared_model(nc_dem) == "projected"
    assert declared_model(data_file(data_dir, "roads/lux_elev.tif")) == "geographic"
    assert declared_model(data_file(data_dir, "srtm/N44W072.hgt")) is None
    at = Affine(1.0, 0.0, 0.0, 0.0, -1.0, 3.0)
    written = {
        "projected": dict(crs="EPSG:32119", transform=at),
        "geographic": dict(crs="EPSG:4326", transform=at, BIGTIFF="YES"),
        "geocentric": dict(crs="EPSG:4978", transform=at, ENDIANNESS="BIG"),
    }
    for model, options in written.items():
        assert declared_model(_write_tif(tmp_path / f"{model}.tif", **options)) == model
    big_endian_big = _write_tif(
        tmp_path / "mm.tif", crs="EPSG:32119", transform=at, BIGTIFF="YES", ENDIANNESS="BIG"
    )
    assert declared_model(big_endian_big) == "projected"
    # A transform without a CRS writes GeoKeys without a model; no transform, no GeoKeys.
    assert declared_model(_write_tif(tmp_path / "placed.tif", transform=at)) is None
    with pytest.warns(rasterio.errors.NotGeoreferencedWarning):
        bare = _write_tif(tmp_path / "bare.tif")
    assert declared_model(bare) is None
    # A damaged header is no witness either way.
    cut = tmp_path / "cut.tif"
    cut.write_bytes(nc_dem.read_bytes()[:12])
    assert declared_model(cut) is None
    assert declared_model(tmp_path / "missing.tif") is None


def test_a_crs_gdal_did_not_build_is_an_error_not_a_missing_crs(nc_dem, gdal_builds_no_crs):
    """With GDAL's CRS empty, the DEM whose keys declare one is refused in memory and
    windowed (it read as a grid with crs None before); a CRS given replaces it as ever."""
    for windowed in (False, True):
        with pytest.raises(TerrainFormatError, match=LOST) as err:
            read_raster(nc_dem, windowed=windowed)
        assert "--crs" in str(err.value)
    assert read_raster(nc_dem, crs="EPSG:32119").crs == "EPSG:32119"
    assert open_terrain(nc_dem, crs="EPSG:32119", windowed=True).crs == "EPSG:32119"


def test_a_zipped_geotiff_is_checked_inside_its_archive(nc_dem, gdal_builds_no_crs, tmp_path):
    """The keys of a zipped GeoTIFF are read from the archive's member."""
    archive = tmp_path / "dem.zip"
    with zipfile.ZipFile(archive, "w") as z:
        z.write(nc_dem, "elev.tif")
    with pytest.raises(TerrainFormatError, match=LOST):
        read_raster(archive)


def test_a_geotiff_without_a_crs_still_reads_without_one(gdal_builds_no_crs, tmp_path):
    """No false alarm: a GeoTIFF placed without a CRS reads as before (crs None)."""
    path = _write_tif(tmp_path / "placed.tif", transform=Affine(2.0, 0.0, 5.0, 0.0, -2.0, 9.0))
    grid = read_raster(path)
    assert grid.crs is None
    assert grid.transform == Affine(2.0, 0.0, 5.0, 0.0, -2.0, 9.0)


def test_build_writes_no_store_without_the_crs_the_dem_declares(
    nc_dem, gdal_builds_no_crs, tmp_path
):
    """`approxtree build` of the DEM is one Error line naming the keys and writes no store
    (it wrote a store whose terrain had crs null, which `tiles` then refused)."""
    store = tmp_path / "nc.zarr"
    r = CliRunner().invoke(main, ["build", str(nc_dem), "--out", str(store), "--epsilon", "2"])
    assert r.exit_code == 2, r.output
    assert LOST in r.output and "Traceback" not in r.output
    assert not store.exists()


def test_tiles_of_the_dem_name_the_lost_crs(nc_dem, gdal_builds_no_crs, tmp_path):
    """`tiles --format quantized-mesh` of the DEM says GDAL lost the declared CRS, not that
    the raster has none (the flaky test's message), and writes nothing."""
    out = tmp_path / "b"
    r = CliRunner().invoke(
        main, ["tiles", str(nc_dem), "--out", str(out), "--format", "quantized-mesh"]
    )
    assert r.exit_code == 2, r.output
    assert LOST in r.output
    assert "The terrain has no CRS" not in r.output
    assert not out.exists()


def test_workers_get_the_crs_with_the_terrain_not_from_gdal(nc_dem, monkeypatch):
    """A windowed DEM sent to a worker process carries its CRS as text: a worker whose GDAL
    would build none still sees it (its RasterSource reopens the file, the CRS is not read)."""
    sampler = TileSampler(read_raster(nc_dem, windowed=True))
    blob = pickle.dumps(sampler)
    monkeypatch.setattr(rasterio.io.DatasetReader, "read_crs", lambda self: None)
    copy = pickle.loads(blob)
    assert copy.terrain.crs == "EPSG:32119"
    assert copy.terrain.heights.source.crs is None
    np.testing.assert_array_equal(copy.terrain.heights[0:3, 0:4], sampler.terrain.heights[0:3, 0:4])
