"""Terrain readers on the real files of ../shared/data (facts from its README) and on bad input."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
import rasterio.shutil
from affine import Affine
from conftest import data_file
from PIL import Image

from approxtree import (
    TIN,
    EmptyTerrainError,
    Grid,
    InvalidParameterError,
    TerrainDataWarning,
    TerrainFormatError,
    TINPointSet,
)
from approxtree.io import open_terrain, read_grid, tile_bounds

ARCSEC_3 = 1.0 / 1200.0  # 3″ in degrees
ARCSEC_30 = 1.0 / 120.0  # 30″ in degrees

# -- GDAL rasters ------------------------------------------------------------------------------

# (file, width, height, crs, cell size, nodata cells, z min, z max, z digits).
# z ranges are those of the data README where it states one; the others (marked *) were
# measured with rasterio's masked reads and guard against a nodata value leaking into heights.
RASTERS = [
    ("nc/elev_ned_30m.tif", 500, 450, "EPSG:32119", 30.0, 0, 55.17, 156.39, 2),
    ("srtm/N44W072.hgt", 1201, 1201, "EPSG:4326", ARCSEC_3, 0, 115, 1908, 0),
    ("srtm/N22W160v2.3a.hgt.zip", 1201, 1201, "EPSG:4326", ARCSEC_3, 4279, -34, 1579, 0),
    ("roads/lux_elev.tif", 95, 90, "EPSG:4326", ARCSEC_30, 3942, 141, 547, 0),  # z*
    ("edge/hugo_site.asc", 76, 55, None, 10.0, 2028, 1660, 1711, 0),  # z*
    ("edge/SainteHelens.dem", 327, 468, "EPSG:26710", 30.0, 4151, 682, 2543, 0),  # z*
    ("edge/nz_elev.tif", 1115, 1450, "WKT", 1000.0, 1_348_639, 0.0, 4140.33, 2),  # z*
    ("edge/dtm.tif", 283, 259, "EPSG:26918", 2.0, 276, 6.91, 22.12, 2),  # z*
]


@pytest.mark.parametrize(
    ("rel", "width", "height", "crs", "cell", "n_nodata", "zmin", "zmax", "digits"),
    RASTERS,
    ids=[r[0] for r in RASTERS],
)
def test_raster_facts(data_dir, rel, width, height, crs, cell, n_nodata, zmin, zmax, digits):
    """Each real raster reads with the README's size, CRS, cell size, nodata count and z range."""
    grid = open_terrain(data_file(data_dir, rel))
    assert isinstance(grid, Grid)
    assert (grid.width, grid.height) == (width, height)
    if crs == "WKT":
        # nz_elev has a custom transverse Mercator CRS that no EPSG code names.
        assert "Transverse_Mercator" in grid.crs and '"central_meridian",173' in grid.crs
    else:
        assert grid.crs == crs
    assert grid.cell_size == pytest.approx((cell, cell), rel=1e-9)
    assert grid.nodata_count == n_nodata
    assert tuple(round(z, digits) for z in grid.z_range) == (zmin, zmax)


@pytest.mark.parametrize("rel", [r[0] for r in RASTERS])
def test_nodata_is_never_a_data_point(data_dir, rel):
    """points() leaves every nodata cell out and never returns the file's nodata value."""
    grid = open_terrain(data_file(data_dir, rel))
    pts = grid.points()
    assert len(pts) == grid.width * grid.height - grid.nodata_count == grid.point_count
    assert np.isfinite(pts).all()
    if grid.nodata is not None and np.isfinite(grid.nodata):
        assert not np.any(pts[:, 2] == grid.nodata)


def test_nc_dem_keeps_georeference(data_dir):
    """The NC DEM keeps its affine transform; data points sit at cell centres (x 630015..644985)."""
    path = data_file(data_dir, "nc/elev_ned_30m.tif")
    grid = open_terrain(path)
    with rasterio.open(path) as ds:
        assert grid.transform == ds.transform
    d = grid.domain
    assert (d.xmin, d.xmax, d.ymin, d.ymax) == (630015.0, 644985.0, 215015.0, 228485.0)
    assert grid.y_coords[0] > grid.y_coords[-1]


def test_landuse_classes_stay_exact(data_dir):
    """uint8 classes survive as exact integers: the README's class counts and 7053 nodata cells."""
    grid = open_terrain(data_file(data_dir, "nc/landuse_r.tif"))
    assert (grid.width, grid.height, grid.nodata_count) == (1500, 1350, 7053)
    assert grid.crs == "EPSG:32119"
    classes = grid.heights[np.isfinite(grid.heights)]
    values, counts = np.unique(classes, return_counts=True)
    assert dict(zip(values.astype(int).tolist(), counts.tolist(), strict=True)) == {
        1: 592288, 2: 17347, 3: 206129, 4: 135994, 5: 1021725, 6: 42854, 7: 1610,
    }  # fmt: skip


def test_srtm_zip_matches_integer_values(data_dir):
    """The zipped Kauai tile reads the same int16 values rasterio reads, voids as NaN."""
    path = data_file(data_dir, "srtm/N22W160v2.3a.hgt.zip")
    grid = open_terrain(path)
    with rasterio.open(f"zip://{path}!N22W160.hgt") as ds:
        raw = ds.read(1)
        assert grid.transform == ds.transform
    voids = raw == -32768
    assert np.array_equal(np.isnan(grid.heights), voids)
    assert np.array_equal(grid.heights[~voids], raw[~voids].astype(np.float32))
    assert grid.nodata == -32768


def test_fill_policy_removes_holes_on_kauai(data_dir):
    """nodata="fill" fills all 4279 Kauai voids, keeps valid cells, and reports the policy."""
    path = data_file(data_dir, "srtm/N22W160v2.3a.hgt.zip")
    masked = open_terrain(path)
    filled = open_terrain(path, nodata="fill")
    assert masked.nodata_policy == "mask" and masked.filled_count == 0
    assert filled.nodata_policy == "fill" and filled.filled_count == 4279
    assert filled.nodata_count == 0
    valid = np.isfinite(masked.heights)
    assert np.array_equal(filled.heights[valid], masked.heights[valid])
    # Interpolated heights lie within the range of the heights they come from.
    holes = filled.heights[~valid]
    assert holes.min() >= masked.z_range[0] and holes.max() <= masked.z_range[1]


def test_fill_policy_leaves_unreachable_cells(tmp_path):
    """Cells farther than the fill search distance from any data stay NaN under "fill"."""
    z = np.full((300, 300), np.nan, dtype=np.float32)
    z[:3, :3] = 5.0
    np.save(tmp_path / "far.npy", z)
    grid = open_terrain(tmp_path / "far.npy", nodata="fill")
    assert 0 < grid.filled_count < z.size - 9
    assert np.isnan(grid.heights[-1, -1]) and grid.heights[10, 10] == 5.0


def _write_tif(path: Path, z: np.ndarray, nodata=None, crs="EPSG:32119") -> None:
    """A one-band GeoTIFF with 10 m cells whose top-left corner is (1000, 2000)."""
    profile = dict(driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype=z.dtype)
    transform = Affine(10, 0, 1000, 0, -10, 2000)
    with rasterio.open(path, "w", crs=crs, transform=transform, nodata=nodata, **profile) as ds:
        ds.write(z, 1)


def test_netcdf_through_gdal(tmp_path):
    """A netCDF grid reads with its transform, CRS and nodata mask."""
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    z[1, 1] = -9999.0
    _write_tif(tmp_path / "a.tif", z, nodata=-9999.0)
    rasterio.shutil.copy(tmp_path / "a.tif", tmp_path / "a.nc", driver="netCDF")
    grid = open_terrain(tmp_path / "a.nc")
    assert grid.transform == Affine(10, 0, 1000, 0, -10, 2000)
    assert grid.crs == "EPSG:32119"
    assert grid.nodata_count == 1 and np.isnan(grid.heights[1, 1])
    assert grid.heights[2, 3] == 11.0


def test_nan_and_nodata_value_both_masked(tmp_path):
    """A float raster's nodata value and stray NaN cells both become nodata."""
    z = np.ones((3, 3), dtype=np.float32)
    z[0, 0] = -9999.0
    z[2, 2] = np.nan
    _write_tif(tmp_path / "m.tif", z, nodata=-9999.0)
    grid = open_terrain(tmp_path / "m.tif")
    assert grid.nodata_count == 2 and grid.point_count == 7


def test_wide_integers_stay_exact(tmp_path):
    """int32 heights beyond float32's exact range are kept as exact float64 values."""
    z = np.array([[2**24 + 1, 2**24 + 3], [7, -(2**25) - 1]], dtype=np.int32)
    _write_tif(tmp_path / "wide.tif", z)
    grid = open_terrain(tmp_path / "wide.tif")
    assert grid.heights.dtype == np.float64
    assert np.array_equal(grid.heights, z.astype(np.float64))


def test_raster_band_option(tmp_path):
    """band= chooses the band; a band the file lacks is an InvalidParameterError."""
    z = np.stack([np.zeros((3, 3)), np.full((3, 3), 7.0)]).astype(np.float32)
    with rasterio.open(
        tmp_path / "two.tif", "w", driver="GTiff", width=3, height=3, count=2, dtype="float32",
        transform=Affine(1, 0, 0, 0, -1, 3),
    ) as ds:  # fmt: skip
        ds.write(z)
    assert open_terrain(tmp_path / "two.tif", band=2).z_range == (7.0, 7.0)
    with pytest.raises(InvalidParameterError, match="band 3"):
        open_terrain(tmp_path / "two.tif", band=3)


def test_all_nodata_raster_is_empty(tmp_path):
    """A raster whose every cell is nodata raises EmptyTerrainError."""
    _write_tif(tmp_path / "void.tif", np.full((4, 4), -9999.0, dtype=np.float32), nodata=-9999.0)
    with pytest.raises(EmptyTerrainError, match="no valid elevation"):
        open_terrain(tmp_path / "void.tif")


# -- encoded PNGs ------------------------------------------------------------------------------


def _terrain_rgb(h: np.ndarray) -> np.ndarray:
    """Mapbox Terrain-RGB pixels (rows, cols, 3) uint8 of heights rounded to 0.1 m."""
    v = np.rint((h + 10000.0) * 10.0).astype(np.int64)
    return np.stack([v // 65536, (v // 256) % 256, v % 256], axis=-1).astype(np.uint8)


def _terrarium(h: np.ndarray) -> np.ndarray:
    """Mapzen Terrarium pixels (rows, cols, 3) uint8; the fraction is truncated to 1/256 m."""
    v = h + 32768.0
    whole = np.floor(v).astype(np.int64)
    frac = np.floor((v - whole) * 256.0).astype(np.int64)
    return np.stack([whole // 256, whole % 256, frac], axis=-1).astype(np.uint8)


HEIGHTS = np.random.default_rng(7).uniform(-400.0, 8800.0, size=(6, 9))


def test_terrain_rgb_round_trip(tmp_path):
    """Terrain-RGB heights come back within the encoding's 0.1 m step (rounded: ≤ 0.05 m)."""
    Image.fromarray(_terrain_rgb(HEIGHTS), "RGB").save(tmp_path / "t.png")
    grid = open_terrain(tmp_path / "t.png", encoding="terrain-rgb")
    assert grid.shape == HEIGHTS.shape
    assert np.abs(grid.heights - HEIGHTS).max() <= 0.05 + 1e-3


def test_terrarium_round_trip(tmp_path):
    """Terrarium heights come back within the encoding's 1/256 m step."""
    Image.fromarray(_terrarium(HEIGHTS), "RGB").save(tmp_path / "t.png")
    grid = open_terrain(tmp_path / "t.png", encoding="terrarium")
    assert np.abs(grid.heights - HEIGHTS).max() < 1.0 / 256.0


def test_alpha_zero_pixels_are_nodata(tmp_path):
    """In an RGBA Terrain-RGB image, pixels with alpha 0 are nodata, the others decode."""
    rgba = np.dstack([_terrain_rgb(HEIGHTS), np.full(HEIGHTS.shape, 255, np.uint8)])
    rgba[0, 0, 3] = rgba[5, 8, 3] = 0
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    grid = open_terrain(tmp_path / "a.png", encoding="terrain-rgb")
    assert grid.nodata_count == 2 and np.isnan(grid.heights[0, 0]) and np.isnan(grid.heights[5, 8])
    assert abs(grid.heights[3, 3] - HEIGHTS[3, 3]) <= 0.05 + 1e-3


def test_png_without_world_file_has_unit_cells_top_down(tmp_path):
    """A PNG without georeference gets cell size 1 with row 0 at the top (y of row 0 is largest)."""
    Image.fromarray(_terrarium(HEIGHTS), "RGB").save(tmp_path / "t.png")
    grid = open_terrain(tmp_path / "t.png", encoding="terrarium")
    assert grid.transform == Affine(1, 0, 0, 0, -1, 6)
    assert grid.y_coords[0] == 5.5 and grid.y_coords[-1] == 0.5


def test_png_world_file_georeferences(tmp_path):
    """A .pgw world file beside the PNG sets the grid's transform."""
    Image.fromarray(_terrarium(HEIGHTS), "RGB").save(tmp_path / "t.png")
    # World file: x size, 2 rotations, y size, then the centre of the top-left pixel.
    (tmp_path / "t.pgw").write_text("2\n0\n0\n-2\n101\n199\n")
    grid = open_terrain(tmp_path / "t.png", encoding="terrarium")
    assert grid.transform == Affine(2, 0, 100, 0, -2, 200)
    with pytest.raises(InvalidParameterError, match="own georeference"):
        open_terrain(tmp_path / "t.png", encoding="terrarium", cell_size=5)


def test_gray16_png_with_height_scale(tmp_path):
    """A 16-bit grayscale PNG gives z = raw * height_scale + height_offset."""
    raw = np.array([[0, 1, 2], [1000, 40000, 65535]], dtype=np.uint16)
    Image.fromarray(raw).save(tmp_path / "g.png")
    grid = open_terrain(tmp_path / "g.png", height_scale=0.1, height_offset=-100.0)
    expected = (raw.astype(np.float64) * 0.1 - 100.0).astype(np.float32)
    assert np.array_equal(grid.heights, expected)


def test_png_cell_size_and_origin(tmp_path):
    """cell_size and origin place a PNG that has no georeference."""
    Image.fromarray(np.zeros((4, 5), np.uint8)).save(tmp_path / "g.png")
    grid = open_terrain(tmp_path / "g.png", cell_size=(2.0, 3.0), origin=(10.0, 50.0))
    assert grid.transform == Affine(2, 0, 10, 0, -3, 50)


def test_rgb_png_without_encoding_asks_for_one(tmp_path):
    """An RGB PNG without encoding raises TerrainFormatError naming the encoding option."""
    Image.fromarray(_terrain_rgb(HEIGHTS), "RGB").save(tmp_path / "t.png")
    with pytest.raises(TerrainFormatError, match="encoding='terrain-rgb'"):
        open_terrain(tmp_path / "t.png")


def test_unknown_encoding_rejected(tmp_path):
    """An unknown encoding name is an InvalidParameterError listing the known ones."""
    Image.fromarray(_terrain_rgb(HEIGHTS), "RGB").save(tmp_path / "t.png")
    with pytest.raises(InvalidParameterError, match="terrarium"):
        open_terrain(tmp_path / "t.png", encoding="mapbox")


# -- numpy arrays ------------------------------------------------------------------------------


def test_npy_with_cell_size_and_origin(tmp_path):
    """A .npy is placed by cell_size and origin (left edge, top edge); int16 values stay exact."""
    z = np.arange(-6, 6, dtype=np.int16).reshape(3, 4) * 1000
    np.save(tmp_path / "z.npy", z)
    grid = open_terrain(tmp_path / "z.npy", cell_size=25.0, origin=(500.0, 900.0))
    assert np.array_equal(grid.heights, z.astype(np.float32))
    assert grid.x_coords[0] == 512.5 and grid.y_coords[0] == 887.5
    assert grid.y_coords[-1] == 837.5


def test_npy_default_georeference(tmp_path):
    """Without options a .npy has cell size 1, row 0 at the top and its bottom edge at y = 0."""
    np.save(tmp_path / "z.npy", np.zeros((3, 4)))
    grid = open_terrain(tmp_path / "z.npy")
    assert grid.transform == Affine(1, 0, 0, 0, -1, 3)
    assert grid.heights.dtype == np.float64


def test_jacksboro_npz_swapped_extent():
    """matplotlib's jacksboro npz (ymin/ymax swapped) gives a north-up grid with 3″ cells."""
    import matplotlib

    path = Path(matplotlib.get_data_path()) / "sample_data" / "jacksboro_fault_dem.npz"
    if not path.exists():
        pytest.skip(f"matplotlib sample data {path} is absent")
    with np.load(path) as npz:
        stored = npz["elevation"]
        ymin, ymax = float(npz["ymin"]), float(npz["ymax"])
    assert ymin > ymax  # the file's quirk this test is about
    # Degree cells without a CRS: the reader warns (tests/test_degrees_without_crs.py).
    with pytest.warns(TerrainDataWarning, match="--crs EPSG:4326"):
        grid = open_terrain(path)
    assert (grid.width, grid.height) == (403, 344) and grid.crs is None
    assert np.array_equal(grid.heights, stored.astype(np.float32))
    assert grid.cell_size == pytest.approx((ARCSEC_3, ARCSEC_3), rel=1e-6)
    assert grid.y_coords[0] > grid.y_coords[-1]
    assert grid.domain.ymax == pytest.approx(ymin - ARCSEC_3 / 2)
    assert grid.domain.ymin == pytest.approx(ymax + ARCSEC_3 / 2)
    assert open_terrain(path, crs="EPSG:4326").crs == "EPSG:4326"


def test_npz_entry_choice(tmp_path):
    """A .npz without 'elevation' and several 2-D arrays needs key=; key= picks the entry."""
    np.savez(tmp_path / "two.npz", a=np.zeros((3, 3)), b=np.ones((3, 3)))
    with pytest.raises(TerrainFormatError, match="key="):
        open_terrain(tmp_path / "two.npz")
    assert open_terrain(tmp_path / "two.npz", key="b").z_range == (1.0, 1.0)


def test_npz_centre_extent_with_step(tmp_path):
    """An extent spanning cell centres (dx = span / (n - 1)) is widened by half a cell."""
    z = np.zeros((3, 5))
    extent = dict(xmin=0.0, xmax=8.0, ymin=0.0, ymax=4.0, dx=2.0, dy=2.0)
    np.savez(tmp_path / "c.npz", elevation=z, **extent)
    grid = open_terrain(tmp_path / "c.npz")
    d = grid.domain
    assert (d.xmin, d.xmax, d.ymin, d.ymax) == (0.0, 8.0, 0.0, 4.0)


# -- SCAPE terrains ----------------------------------------------------------------------------

STMS = [
    ("scape/crater.stm", 336, 459, 1533, 2478),
    ("scape/ashby.stm", 346, 452, 113, 587),
    ("scape/ozark.stm", 369, 462, 328, 437),
    ("scape/ntc.stm", 1024, 1024, 487, 1610),
]


@pytest.mark.parametrize(("rel", "width", "height", "zmin", "zmax"), STMS, ids=[s[0] for s in STMS])
def test_stm_facts(data_dir, rel, width, height, zmin, zmax):
    """Each .stm reads with the README's size and z range, cell size 1 and no CRS."""
    grid = open_terrain(data_file(data_dir, rel))
    assert (grid.width, grid.height) == (width, height)
    assert grid.z_range == (zmin, zmax)
    assert grid.cell_size == (1.0, 1.0) and grid.crs is None and grid.nodata_count == 0


def test_crater_stm_equals_pgm(data_dir):
    """crater.stm (numpy) and crater.pgm (Pillow, rescaled back by maxval) hold equal heights."""
    stm = open_terrain(data_file(data_dir, "scape/crater.stm"))
    pgm = open_terrain(data_file(data_dir, "scape/crater.pgm"))
    assert np.array_equal(stm.heights, pgm.heights)
    assert stm.transform == pgm.transform


def _stm_bytes(z: np.ndarray, order: bytes, dtype: str) -> bytes:
    """An STM file: header line with the order bytes, then the heights."""
    rows, cols = z.shape
    return f"STM {cols} {rows} ".encode() + order + b"\n" + z.astype(dtype).tobytes()


def test_stm_little_endian(tmp_path):
    """Order bytes 01 02 03 04 read the heights as little-endian, row 0 at the top."""
    z = np.array([[1, 2, 3], [300, 40000, 65535]], dtype=np.uint16)
    (tmp_path / "le.stm").write_bytes(_stm_bytes(z, b"\x01\x02\x03\x04", "<u2"))
    (tmp_path / "be.stm").write_bytes(_stm_bytes(z, b"\x04\x03\x02\x01", ">u2"))
    for name in ("le.stm", "be.stm"):
        assert np.array_equal(open_terrain(tmp_path / name).heights, z.astype(np.float32))


def test_truncated_stm(tmp_path):
    """A truncated .stm raises TerrainFormatError with expected and actual byte counts."""
    z = np.ones((4, 5), dtype=np.uint16)
    (tmp_path / "cut.stm").write_bytes(_stm_bytes(z, b"\x04\x03\x02\x01", ">u2")[:-7])
    with pytest.raises(TerrainFormatError, match=r"truncated.*needs 40 bytes.*has 33"):
        open_terrain(tmp_path / "cut.stm")


def test_stm_bad_order_bytes(tmp_path):
    """Unknown order bytes raise TerrainFormatError naming the valid ones."""
    z = np.ones((2, 2), dtype=np.uint16)
    (tmp_path / "odd.stm").write_bytes(_stm_bytes(z, b"\x01\x01\x01\x01", ">u2"))
    with pytest.raises(TerrainFormatError, match="04 03 02 01"):
        open_terrain(tmp_path / "odd.stm")


def test_pgm_8bit_with_small_maxval(tmp_path):
    """An 8-bit P2 PGM with maxval 100 reads its raw values (Pillow's stretch undone)."""
    (tmp_path / "s.pgm").write_text("P2\n# comment\n3 2\n100\n0 50 100\n1 2 99\n")
    grid = open_terrain(tmp_path / "s.pgm")
    assert np.array_equal(grid.heights, [[0, 50, 100], [1, 2, 99]])


# -- point clouds ------------------------------------------------------------------------------


def test_autzen_laz(data_dir):
    """autzen: 110,000 points; 7 share an (x, y) with another and merge → 109,993 data points."""
    cloud = open_terrain(data_file(data_dir, "lidar/autzen_trim.laz"))
    assert isinstance(cloud, TINPointSet)
    assert cloud.point_count + cloud.duplicates_merged == 110_000
    assert cloud.duplicates_merged == 7
    assert tuple(round(z, 2) for z in cloud.z_range) == (406.26, 520.51)
    assert "Lambert_Conformal_Conic" in cloud.crs and '"foot"' in cloud.crs


def test_autzen_ground_only(data_dir):
    """ground_only keeps the 26,107 class-2 points (no two share an (x, y), so none merge)."""
    cloud = open_terrain(data_file(data_dir, "lidar/autzen_trim.laz"), ground_only=True)
    assert cloud.point_count == 26_107 and cloud.duplicates_merged == 0
    assert round(cloud.z_range[0], 2) == 406.26


def test_no_ground_points_is_empty(data_dir, tmp_path):
    """A cloud with no class-2 points and ground_only=True raises EmptyTerrainError."""
    import laspy

    las = laspy.read(data_file(data_dir, "lidar/autzen_trim.laz"))
    las.points = las.points[np.asarray(las.classification) == 1][:100]
    las.write(tmp_path / "noground.las")
    with pytest.raises(EmptyTerrainError, match="ground"):
        open_terrain(tmp_path / "noground.las", ground_only=True)


# -- quantized mesh ----------------------------------------------------------------------------

TILE_9_533_383 = (7.3828125, 44.6484375, 7.734375, 45.0)


def test_quantized_mesh_tile(data_dir):
    """Tile 9/533/383: 103 vertices, 127 triangles, heights 206..788, lon/lat from its name."""
    tin = open_terrain(data_file(data_dir, "tin/9_533_383.terrain"))
    assert isinstance(tin, TIN) and tin.crs == "EPSG:4326"
    assert (len(tin.vertices), len(tin.triangles)) == (103, 127)
    assert tuple(round(z) for z in tin.z_range) == (206, 788)
    d = tin.domain
    assert (d.xmin, d.ymin, d.xmax, d.ymax) == TILE_9_533_383


def test_tile_bounds_scheme():
    """Cesium's geographic tiling: 2 × 1 tiles at level 0, y counted from the south."""
    assert tile_bounds(0, 0, 0) == (-180.0, -90.0, 0.0, 90.0)
    assert tile_bounds(0, 1, 0) == (0.0, -90.0, 180.0, 90.0)
    assert tile_bounds(9, 533, 383) == TILE_9_533_383
    with pytest.raises(TerrainFormatError, match="does not exist"):
        tile_bounds(0, 2, 0)


def test_quantized_mesh_gzip_and_layouts(data_dir, tmp_path):
    """A gzipped tile in a Z/X/Y folder layout decodes to the same TIN as the plain file."""
    src = data_file(data_dir, "tin/9_533_383.terrain")
    plain = open_terrain(src)
    folder = tmp_path / "9" / "533"
    folder.mkdir(parents=True)
    (folder / "383.terrain").write_bytes(gzip.compress(src.read_bytes()))
    zipped = open_terrain(folder / "383.terrain")
    assert np.array_equal(zipped.vertices, plain.vertices)


def test_quantized_mesh_bounds(data_dir, tmp_path):
    """Without an address in its name a tile needs bounds=; given, they set the domain."""
    tile = tmp_path / "tile.terrain"
    shutil.copy(data_file(data_dir, "tin/9_533_383.terrain"), tile)
    with pytest.raises(TerrainFormatError, match="bounds="):
        open_terrain(tile)
    tin = open_terrain(tile, bounds=(0.0, 10.0, 1.0, 11.0))
    d = tin.domain
    assert (d.xmin, d.ymin, d.xmax, d.ymax) == (0.0, 10.0, 1.0, 11.0)


def test_quantized_mesh_name_against_header(data_dir, tmp_path):
    """A name whose address disagrees with the tile's header centre (north-counted y) is refused."""
    tile = tmp_path / "9_533_128.terrain"
    shutil.copy(data_file(data_dir, "tin/9_533_383.terrain"), tile)
    with pytest.raises(TerrainFormatError, match="centre"):
        open_terrain(tile)


# -- bad input ---------------------------------------------------------------------------------


def test_missing_file(tmp_path):
    """A missing file raises TerrainFormatError saying it does not exist."""
    with pytest.raises(TerrainFormatError, match="does not exist"):
        open_terrain(tmp_path / "nope.tif")


def test_text_file_with_tif_extension(tmp_path):
    """A text file named .tif raises TerrainFormatError with the path and GDAL's reason."""
    bad = tmp_path / "bad.tif"
    bad.write_text("this is not a GeoTIFF\n")
    with pytest.raises(TerrainFormatError, match=r"Cannot read .*bad\.tif") as info:
        open_terrain(bad)
    assert "not recognized" in str(info.value)


def test_unknown_extension_garbage(tmp_path):
    """Garbage with an unknown extension raises TerrainFormatError listing supported formats."""
    bad = tmp_path / "thing.xyz123"
    bad.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(TerrainFormatError, match="Supported formats: GDAL raster"):
        open_terrain(bad)


def test_unknown_extension_detected_by_content(data_dir, tmp_path):
    """A known format under an unknown extension is recognised by its first bytes."""
    copy = tmp_path / "crater.bin"
    shutil.copy(data_file(data_dir, "scape/crater.stm"), copy)
    assert open_terrain(copy).shape == (459, 336)


@pytest.mark.parametrize(
    "name",
    ["x.tif", "x.asc", "N00E000.hgt", "x.hgt.zip", "x.dem", "x.nc", "x.png", "x.npy", "x.npz",
     "x.stm", "x.pgm", "x.las", "x.laz", "0_0_0.terrain"],
)  # fmt: skip
def test_corrupt_files_raise_terrain_format_error(tmp_path, name):
    """Every reader turns a corrupt file into TerrainFormatError naming the path."""
    bad = tmp_path / name
    bad.write_bytes(b"\x00garbage\xff" * 8)
    with pytest.raises(TerrainFormatError, match=name.replace(".", r"\.")):
        open_terrain(bad)


def test_empty_and_thin_arrays(tmp_path):
    """An empty array, a 1 × N array and an all-NaN array each raise EmptyTerrainError."""
    np.save(tmp_path / "empty.npy", np.zeros((0,)))
    np.save(tmp_path / "thin.npy", np.zeros((1, 50)))
    np.save(tmp_path / "nan.npy", np.full((4, 4), np.nan))
    with pytest.raises(EmptyTerrainError, match="empty"):
        open_terrain(tmp_path / "empty.npy")
    with pytest.raises(EmptyTerrainError, match="2 × 2"):
        open_terrain(tmp_path / "thin.npy")
    with pytest.raises(EmptyTerrainError, match="no valid elevation"):
        open_terrain(tmp_path / "nan.npy")


def test_array_of_wrong_rank(tmp_path):
    """A 3-D array raises TerrainFormatError asking for a 2-D array."""
    np.save(tmp_path / "cube.npy", np.zeros((2, 3, 4)))
    with pytest.raises(TerrainFormatError, match="2-D"):
        open_terrain(tmp_path / "cube.npy")


def test_unknown_nodata_policy(tmp_path):
    """An unknown nodata policy raises InvalidParameterError naming mask and fill."""
    np.save(tmp_path / "z.npy", np.zeros((3, 3)))
    with pytest.raises(InvalidParameterError, match=r"'mask'.*'fill'"):
        open_terrain(tmp_path / "z.npy", nodata="interpolate")


@pytest.mark.parametrize(
    ("options", "word"),
    [
        ({"colour": "red"}, "Unknown option"),
        ({"ground_only": True}, "does not apply"),
        ({"cell_size": -1.0}, "positive"),
        ({"cell_size": (1.0, 2.0, 3.0)}, "pair"),
        ({"origin": "top"}, "pair"),
        ({"crs": 4326}, "string"),
        ({"band": 0}, "band"),
    ],
)
def test_bad_options(tmp_path, options, word):
    """Bad or misplaced options raise InvalidParameterError with a message that names them."""
    np.save(tmp_path / "z.npy", np.zeros((3, 3)))
    _write_tif(tmp_path / "z.tif", np.zeros((3, 3), np.float32))
    target = tmp_path / ("z.tif" if "band" in options else "z.npy")
    with pytest.raises(InvalidParameterError, match=word):
        open_terrain(target, **options)


def test_bad_bounds_and_flags(data_dir):
    """bounds must be four ordered numbers; ground_only must be a boolean."""
    with pytest.raises(InvalidParameterError, match="west < east"):
        open_terrain(data_file(data_dir, "tin/9_533_383.terrain"), bounds=(1, 0, 0, 1))
    with pytest.raises(InvalidParameterError, match="True or False"):
        open_terrain(data_file(data_dir, "lidar/autzen_trim.laz"), ground_only="yes")


def test_read_grid_refuses_tins(data_dir):
    """read_grid raises TerrainFormatError for a file that holds a TIN."""
    with pytest.raises(TerrainFormatError, match="not a regular grid"):
        read_grid(data_file(data_dir, "tin/9_533_383.terrain"))


def test_read_raster_holds_the_band_once(tmp_path):
    """A float32 band becomes the heights in the buffer GDAL read it into (NaN at nodata),
    not in a second full-size copy."""
    from approxtree.io._common import as_heights

    band = np.ma.masked_array(np.arange(12, dtype=np.float32).reshape(3, 4), mask=False)
    band.mask[1, 2] = True
    heights = as_heights(band, reuse=True)
    assert np.shares_memory(heights, band.data)
    assert np.isnan(heights[1, 2]) and np.isfinite(np.delete(heights.ravel(), 6)).all()
