"""Windowed terrain: a Grid over a WindowedHeights answers exactly as the in-memory Grid.

Real DEMs with nodata (../shared/data) and generated tiled GeoTIFFs are opened both ways and
compared on every question a strategy or the renderer asks; pickling ships no data; peak
memory of the windowed questions stays far below the band; whole-band operations on a large
windowed grid fail with a WholeBandError that says what to do.
"""

from __future__ import annotations

import pickle
import threading
import tracemalloc
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from atree_writer import write_atree
from conftest import data_file

from approxtree.errors import InvalidParameterError, WholeBandError
from approxtree.geometry import Grid, Rect
from approxtree.geometry import windowed as windowed_module
from approxtree.geometry.windowed import ArraySource, WindowedHeights, band_statistics
from approxtree.io import open_terrain, read_raster
from approxtree.io.raster import RasterSource

# -- helpers -----------------------------------------------------------------------------------


def _write_tif(path: Path, z: np.ndarray, nodata: float | None = -9999.0, tile: int = 256) -> Path:
    """A tiled GeoTIFF of z (NaN → nodata), written window by window."""
    import rasterio
    from rasterio.windows import Window

    rows, cols = z.shape
    profile = dict(
        driver="GTiff",
        width=cols,
        height=rows,
        count=1,
        dtype=z.dtype,
        nodata=nodata,
        tiled=True,
        blockxsize=tile,
        blockysize=tile,
        transform=Affine(2.0, 0, 500000.0, 0, -2.0, 4200000.0),
        crs="EPSG:32610",
    )
    with rasterio.open(path, "w", **profile) as ds:
        out = np.where(np.isnan(z), nodata, z).astype(z.dtype) if nodata is not None else z
        ds.write(out, 1, window=Window(0, 0, cols, rows))
    return path


def _synthetic(rows: int, cols: int, seed: int = 0) -> np.ndarray:
    """Smooth heights with a few nodata holes, float32."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float64)
    z = 100 + 20 * np.sin(xx / 37.0) * np.cos(yy / 23.0) + rng.normal(0, 0.5, (rows, cols))
    z = z.astype(np.float32)
    z[rows // 3 : rows // 3 + 17, cols // 4 : cols // 4 + 41] = np.nan
    z[-5:, :9] = np.nan
    z[rng.integers(0, rows, 50), rng.integers(0, cols, 50)] = np.nan
    return z


def _rects(g: Grid) -> list[Rect]:
    """Rectangles across the grid: whole, quadrants, a thin strip and a small one off-block."""
    rows, cols = g.shape
    return [
        g.domain,
        g.rect_of(0, rows // 2, 0, cols // 2),
        g.rect_of(rows // 2, rows - 1, cols // 3, cols - 1),
        g.rect_of(rows // 5, rows // 5 + 1, 0, cols - 1),
        g.rect_of(rows // 2 - 3, rows // 2 + 9, cols // 2 - 11, cols // 2 + 2),
        Rect(g.domain.xmin - 50, g.domain.ymin - 50, g.domain.xmin + 7.3, g.domain.ymin + 9.1),
    ]


def assert_same_grid(w: Grid, g: Grid) -> None:
    """Every question of the GeometryData interface, windowed vs in memory."""
    assert w.is_windowed and not g.is_windowed
    assert w.shape == g.shape and w.domain == g.domain and w.crs == g.crs
    assert w.transform == g.transform
    assert w.z_range == g.z_range
    assert w.point_count == g.point_count and w.nodata_count == g.nodata_count
    rng = np.random.default_rng(1)
    d = g.domain
    for rect in _rects(g):
        assert w.index_range(rect) == g.index_range(rect)
        np.testing.assert_array_equal(w.points(rect), g.points(rect))
        for axis in (0, 1):
            assert w.split_position(rect, axis) == g.split_position(rect, axis)
    # h_T at random points (some outside), at data points and on the last row and column.
    x = rng.uniform(d.xmin - 5, d.xmax + 5, 3000)
    y = rng.uniform(d.ymin - 5, d.ymax + 5, 3000)
    np.testing.assert_array_equal(w.height_at(x, y), g.height_at(x, y))
    xs, ys = g.x_coords, g.y_coords
    grid_xy = (xs[None, ::7], ys[::5, None])
    np.testing.assert_array_equal(w.height_at(*grid_xy), g.height_at(*grid_xy))
    edge = (xs[None, [0, -1]], ys[:, None])
    np.testing.assert_array_equal(w.height_at(*edge), g.height_at(*edge))
    rows, cols = g.shape
    for r0, r1, c0, c1 in [(0, rows - 1, 0, cols - 1), (1, rows // 2, 3, cols - 2)]:
        ww, gw = w.window(r0, r1, c0, c1), g.window(r0, r1, c0, c1)
        assert not ww.is_windowed and ww.index_offset == gw.index_offset
        np.testing.assert_array_equal(ww.heights, gw.heights)
        np.testing.assert_array_equal(ww.points(), gw.points())


# -- WindowedHeights over an in-memory source ----------------------------------------------------


def _array_heights(cache_bytes: int = 64 * 1024) -> tuple[np.ndarray, WindowedHeights]:
    z = _synthetic(301, 257)
    return z, WindowedHeights(ArraySource(z), cache_bytes=cache_bytes, block_shape=(32, 48))


@pytest.mark.parametrize(
    "key",
    [
        (slice(None), slice(None)),
        (slice(5, 290), slice(40, 41)),
        (slice(3, 300, 7), slice(None, None, -3)),
        (slice(None, None, -1), slice(250, 3, -11)),
        (17, slice(2, 200)),
        (slice(2, 200), -1),
        (-3, 44),
        (slice(0, 0), slice(None)),
    ],
)
def test_slices_equal_numpy(key):
    z, h = _array_heights()
    got = h[key]
    assert got.shape == z[key].shape
    np.testing.assert_array_equal(got, z[key])


def test_index_arrays_broadcast_like_numpy():
    z, h = _array_heights()
    rng = np.random.default_rng(2)
    rr = rng.integers(-301, 301, (23, 1))
    cc = rng.integers(-257, 257, (1, 19))
    for key in [
        (rr, cc),
        (rr[:19, 0], cc[0]),
        (rr, 5),
        (7, cc),
        (rr[:, 0], slice(3, 9)),
        (slice(3, 9), cc),
    ]:
        np.testing.assert_array_equal(h[key], z[key])
        assert h[key].shape == z[key].shape
    with pytest.raises(IndexError):
        h[np.array([301]), np.array([0])]
    with pytest.raises(IndexError):
        h[z > 0]


def test_points_read_only_their_blocks_and_cache_stays_bounded():
    z, h = _array_heights(cache_bytes=4 * 32 * 48 * 4)
    source = h.source
    # Two far-apart points: two blocks read, not the box between them.
    np.testing.assert_array_equal(h[np.array([0, 300]), np.array([0, 256])], z[[0, 300], [0, 256]])
    assert source.cells_read <= 2 * 32 * 48
    for r in range(0, 301, 9):
        h[r : r + 40, :]
        assert h.cached_bytes <= h.cache_bytes


def test_threads_read_the_same_values():
    z, h = _array_heights(cache_bytes=3 * 32 * 48 * 4)
    rng = np.random.default_rng(3)
    keys = [(rng.integers(0, 301, 500), rng.integers(0, 257, 500)) for _ in range(64)]
    with ThreadPoolExecutor(8) as pool:
        results = list(pool.map(lambda k: h[k], keys))
    for k, got in zip(keys, results, strict=True):
        np.testing.assert_array_equal(got, z[k])
    assert h.cached_bytes <= h.cache_bytes


def test_band_statistics_match_numpy():
    z, h = _array_heights()
    assert band_statistics(h) == (
        int(np.isfinite(z).sum()),
        float(np.nanmin(z)),
        float(np.nanmax(z)),
    )


def test_windowed_array_grid_equals_in_memory():
    z, h = _array_heights()
    t = Affine(0.1 + 1e-9, 0, 612345.67, 0, -0.3, 4123456.89)
    assert_same_grid(Grid(h, t, "EPSG:32610"), Grid(z, t, "EPSG:32610"))


def test_opening_does_not_scan():
    z, h = _array_heights()
    g = Grid(h)
    repr(g)
    _ = g.domain
    g.index_range(g.domain)
    assert h.source.cells_read == 0
    assert g.z_range == (float(np.nanmin(z)), float(np.nanmax(z)))
    assert h.source.cells_read == z.size


def test_empty_windowed_grid_fails_when_first_counted():
    from approxtree.errors import EmptyTerrainError

    g = Grid(WindowedHeights(ArraySource(np.full((40, 30), np.nan, dtype=np.float32))))
    with pytest.raises(EmptyTerrainError):
        _ = g.point_count


# -- rasters -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "relative",
    [
        "edge/dtm.tif",
        "edge/hugo_site.asc",
        "edge/SainteHelens.dem",
        "edge/nz_elev.tif",
        "roads/lux_elev.tif",
        "srtm/N22W160v2.3a.hgt.zip",
    ],
)
def test_real_dems_windowed_equal_in_memory(data_dir, relative):
    path = data_file(data_dir, relative)
    g = read_raster(path, windowed=False)
    w = read_raster(path, windowed=True)
    assert w.nodata_count > 0
    assert_same_grid(w, g)
    # Small odd blocks, so that every question crosses block borders of the real data.
    small = WindowedHeights(w.heights.source, cache_bytes=256 * 1024, block_shape=(37, 53))
    assert_same_grid(Grid(small, w.transform, w.crs), g)


def test_generated_tiled_geotiff_and_vrt(tmp_path):
    z = _synthetic(700, 613)
    tif = _write_tif(tmp_path / "dem.tif", z)
    g = read_raster(tif, windowed=False)
    w = read_raster(tif, windowed=True)
    assert w.heights.block_shape == (512, 512)
    assert_same_grid(w, g)
    # A VRT over the GeoTIFF reads the same windows through GDAL.
    vrt = tmp_path / "dem.vrt"
    vrt.write_text(
        """<VRTDataset rasterXSize="613" rasterYSize="700">
  <SRS>EPSG:32610</SRS>
  <GeoTransform>500000.0, 2.0, 0.0, 4200000.0, 0.0, -2.0</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">
    <NoDataValue>-9999</NoDataValue>
    <SimpleSource>
      <SourceFilename relativeToVRT="1">dem.tif</SourceFilename><SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="613" ySize="700"/>
      <DstRect xOff="0" yOff="0" xSize="613" ySize="700"/>
    </SimpleSource>
  </VRTRasterBand>
</VRTDataset>"""
    )
    v = open_terrain(vrt, windowed=True)
    assert v.is_windowed
    np.testing.assert_array_equal(v.heights[:, :], g.heights)
    np.testing.assert_array_equal(v.points(_rects(g)[2]), g.points(_rects(g)[2]))


def test_netcdf_windowed(tmp_path):
    from rasterio.shutil import copy

    tif = _write_tif(tmp_path / "dem.tif", _synthetic(120, 90), tile=16)
    nc = tmp_path / "dem.nc"
    # GDAL writes netCDF only by copying (CreateCopy).
    copy(tif, nc, driver="netCDF")
    assert_same_grid(read_raster(nc, windowed=True), read_raster(nc, windowed=False))


def test_windowed_default_follows_threshold(tmp_path, monkeypatch):
    tif = _write_tif(tmp_path / "dem.tif", _synthetic(64, 80))
    monkeypatch.setenv("APPROXTREE_WINDOWED_BYTES", str(64 * 80 * 4 - 1))
    assert read_raster(tif).is_windowed
    monkeypatch.setenv("APPROXTREE_WINDOWED_BYTES", str(64 * 80 * 4))
    assert not read_raster(tif).is_windowed
    monkeypatch.delenv("APPROXTREE_WINDOWED_BYTES")
    assert not read_raster(tif).is_windowed
    with pytest.raises(InvalidParameterError, match="windowed"):
        read_raster(tif, windowed="yes")  # type: ignore[arg-type]


def test_pickle_ships_no_data(tmp_path):
    tif = _write_tif(tmp_path / "dem.tif", _synthetic(600, 500))
    w = read_raster(tif, windowed=True)
    x, y = w.x_coords[::3][None, :], w.y_coords[::4][:, None]
    before = w.height_at(x, y)
    _ = w.z_range
    data = pickle.dumps(w)
    assert len(data) < 4096 < 600 * 500 * 4
    back = pickle.loads(data)
    assert back.is_windowed and back.heights.cached_bytes == 0
    np.testing.assert_array_equal(back.height_at(x, y), before)
    # The source opens its own dataset in a new thread.
    out = {}
    thread = threading.Thread(target=lambda: out.update(z=back.heights[10:20, 30:40]))
    thread.start()
    thread.join()
    np.testing.assert_array_equal(out["z"], w.heights[10:20, 30:40])


def test_peak_memory_bounded_by_blocks(tmp_path):
    import rasterio
    from rasterio.windows import Window

    n = 4096
    path = tmp_path / "big.tif"
    profile = dict(
        driver="GTiff",
        width=n,
        height=n,
        count=1,
        dtype="float32",
        nodata=-9999.0,
        tiled=True,
        blockxsize=256,
        blockysize=256,
        transform=Affine(1.0, 0, 0.0, 0, -1.0, float(n)),
    )
    # Written strip by strip so that the test itself never holds the band.
    with rasterio.open(path, "w", **profile) as ds:
        for r0 in range(0, n, 256):
            yy, xx = np.mgrid[r0 : r0 + 256, 0:n].astype(np.float32)
            ds.write(np.sin(xx / 50) * np.cos(yy / 70) * 100, 1, window=Window(0, r0, n, 256))
    band = n * n * 4
    source = RasterSource(str(path))
    g = Grid(
        WindowedHeights(source, cache_bytes=4 * 256 * 256 * 4), Affine(1.0, 0, 0.0, 0, -1.0, n)
    )
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0.5, n - 0.5, 5000), rng.uniform(0.5, n - 0.5, 5000)
    # Load the numba kernels first: compiling or loading them allocates Python objects.
    g.height_at(x[:2], y[:2])
    tracemalloc.start()
    try:
        zr = g.z_range
        pts = g.points(g.rect_of(1000, 1100, 2000, 2150))
        h = g.height_at(x, y)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < band / 8
    assert -100.5 < zr[0] < zr[1] < 100.5 and len(pts) == 101 * 151 and np.isfinite(h).all()


def test_whole_band_operations_fail_clearly(tmp_path, monkeypatch):
    from approxtree.patches import STRATEGIES
    from approxtree.rd.bintree import lattice_heights
    from approxtree.textures.shading import TopographicShading

    tif = _write_tif(tmp_path / "dem.tif", _synthetic(200, 180))
    g = read_raster(tif, windowed=True)
    monkeypatch.setattr(windowed_module, "WHOLE_BAND_LIMIT_BYTES", 10_000)
    with pytest.raises(WholeBandError, match=r"Grid\.valid"):
        _ = g.valid
    with pytest.raises(WholeBandError, match="window"):
        np.asarray(g.heights)
    # A patch over the whole band is refused (trees build block by block instead).
    for policy in ("grid", "rtin", "tin", "nonregular"):
        with pytest.raises(WholeBandError, match="building"):
            STRATEGIES[policy].build_many(g, [g.domain], 16, 1.0)
    with pytest.raises(WholeBandError, match="shading"):
        TopographicShading(g).hillshade()
    with pytest.raises(WholeBandError, match="binary tree"):
        lattice_heights(g)
    # Questions that read only their windows still work.
    assert g.point_count == read_raster(tif).point_count


def test_small_windowed_grid_builds_the_same_tree(tmp_path):
    from approxtree import ApproximationTree, load_tree

    tif = _write_tif(tmp_path / "dem.tif", _synthetic(150, 130))
    g, w = read_raster(tif, windowed=False), read_raster(tif, windowed=True)
    for policy in ("grid", "nonregular"):
        a = ApproximationTree.build(g, epsilon=0.5, max_points=17 * 17, policy=policy)
        b = ApproximationTree.build(w, epsilon=0.5, max_points=17 * 17, policy=policy)
        np.testing.assert_array_equal(a.errors, b.errors)
        np.testing.assert_array_equal(a.rects, b.rects)
        for i in range(len(a)):
            np.testing.assert_array_equal(a.patch(i).vertices, b.patch(i).vertices)
            np.testing.assert_array_equal(a.patch(i).triangles, b.patch(i).triangles)
    # A small windowed terrain written to a legacy .atree (the tests' writer) holds it whole
    # (np.asarray of its heights), and the reader loads it in memory.
    write_atree(b, tmp_path / "t.atree")
    back = load_tree(tmp_path / "t.atree")
    assert not back.terrain.is_windowed
    np.testing.assert_array_equal(back.terrain.heights, g.heights)


def test_grid_patch_mesh_reads_only_its_lattice(tmp_path, monkeypatch):
    from approxtree.patches.grid import GridPatch

    tif = _write_tif(tmp_path / "dem.tif", _synthetic(300, 260))
    g, w = read_raster(tif, windowed=False), read_raster(tif, windowed=True)
    # No whole-band read is allowed: the mesh must come from the lattice alone.
    monkeypatch.setattr(windowed_module, "WHOLE_BAND_LIMIT_BYTES", 0)
    index = (3, 290, 5, 250, 13, 9)
    a = GridPatch(g, g.rect_of(3, 290, 5, 250), index, 0.0, (0.0, 0.0), 0)
    b = GridPatch(w, w.rect_of(3, 290, 5, 250), index, 0.0, (0.0, 0.0), 0)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.triangles, b.triangles)


def test_cli_info_on_a_windowed_raster(tmp_path):
    import json

    from click.testing import CliRunner

    from approxtree.cli import main

    tif = _write_tif(tmp_path / "dem.tif", _synthetic(90, 70))
    result = CliRunner().invoke(main, ["info", str(tif), "--windowed", "on", "--json"])
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    g = read_raster(tif)
    assert figures["windowed"] is True
    assert figures["points"] == g.point_count and figures["z_min"] == g.z_range[0]


def test_raster_source_read_from_many_threads(tmp_path):
    z = _synthetic(530, 470)
    tif = _write_tif(tmp_path / "dem.tif", z)
    h = WindowedHeights(RasterSource(str(tif)), cache_bytes=2 * 256 * 256 * 4)
    rng = np.random.default_rng(4)
    keys = [(rng.integers(0, 530, 300), rng.integers(0, 470, 300)) for _ in range(48)]
    # Each thread opens its own dataset handle; values equal the array's.
    with ThreadPoolExecutor(6) as pool:
        results = list(pool.map(lambda k: h[k], keys))
    for k, got in zip(keys, results, strict=True):
        np.testing.assert_array_equal(got, z[k])


@pytest.mark.parametrize("policy", ["grid", "rtin", "tin", "nonregular"])
def test_windowed_build_reads_blocks_not_the_band(monkeypatch, policy):
    """Above the whole-band limit a build goes block by block (tree/blocks.py): it never asks
    for the band whole, reads each cell about once, and equals the in-memory build."""
    from approxtree import ApproximationTree

    z = _synthetic(200, 180)
    source = ArraySource(z)
    g = Grid(WindowedHeights(source, cache_bytes=64 * 1024, block_shape=(64, 64)))
    monkeypatch.setattr(windowed_module, "WHOLE_BAND_LIMIT_BYTES", 10_000)
    with pytest.raises(WholeBandError):
        g.heights_array("reading it whole")
    tree = ApproximationTree.build(g, epsilon=1.0, policy=policy)
    # The blockwise z range scan and the one block's window: each cell read about twice.
    assert source.cells_read <= 2 * z.size + 4 * (z.shape[0] + z.shape[1])
    ref = ApproximationTree.build(Grid(z), epsilon=1.0, policy=policy)
    np.testing.assert_array_equal(tree.rects, ref.rects)
    np.testing.assert_array_equal(tree.errors, ref.errors)


def test_header_claiming_more_cells_fails_at_open(tmp_path):
    import struct

    from approxtree.errors import TerrainFormatError

    path = _write_tif(tmp_path / "dem.tif", _synthetic(64, 64), tile=16)
    data = bytearray(path.read_bytes())
    ifd = struct.unpack_from("<I", data, 4)[0]
    for i in range(struct.unpack_from("<H", data, ifd)[0]):
        entry = ifd + 2 + 12 * i
        if struct.unpack_from("<H", data, entry)[0] in (256, 257):  # ImageWidth, ImageLength
            struct.pack_into("<HIHH", data, entry + 2, 3, 1, 60000, 0)
    path.write_bytes(bytes(data))
    # Windowed, nothing of the band is read but one block: that block already fails.
    with pytest.raises(TerrainFormatError, match="60000 × 60000"):
        read_raster(path, windowed=True)


def test_cli_build_on_a_too_large_windowed_raster_is_one_error_line(tmp_path, monkeypatch):
    """A build that needs the whole band of a windowed raster over the limit prints one Error
    line and writes nothing (here the microstructures' resampling; a store is written block by
    block, where the legacy .atree writer read the band whole)."""
    import json

    from click.testing import CliRunner

    from approxtree.cli import main

    tif = _write_tif(tmp_path / "dem.tif", _synthetic(90, 70))
    monkeypatch.setattr(windowed_module, "WHOLE_BAND_LIMIT_BYTES", 1000)
    crs = {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32610"}}
    line = {"type": "LineString", "coordinates": [[500010, 4199830], [500130, 4199990]]}
    layer = {
        "type": "FeatureCollection",
        "crs": crs,
        "features": [{"type": "Feature", "properties": {}, "geometry": line}],
    }
    (tmp_path / "river.geojson").write_text(json.dumps(layer))
    out = tmp_path / "t.zarr"
    args = ["build", str(tif), "--out", str(out), "--windowed", "on"]
    args += ["--microstructures", str(tmp_path / "river.geojson")]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2
    assert result.output.startswith("Error: ") and "windowed=False" in result.output
    assert "Traceback" not in result.output and not out.exists()


def test_render_of_a_windowed_tree_equals_in_memory(monkeypatch):
    """Full resolution, the LOD cut and a strided normal map draw the same pixels."""
    from approxtree import ApproximationTree
    from approxtree.datasets import fractal_terrain
    from approxtree.render import Cut, Engine, overview_camera
    from approxtree.render import normal_map as normal_map_module
    from approxtree.render.context import create_context

    base = fractal_terrain(129, seed=7, relief=200.0)
    z = np.array(base.heights, dtype=np.float32)
    z[40:52, 60:75] = np.nan
    t = base.transform
    g = Grid(z, t, base.crs)
    w = Grid(WindowedHeights(ArraySource(z), cache_bytes=64 * 1024, block_shape=(32, 32)), t)
    # A normal map smaller than the grid: rows and columns are read with a stride.
    monkeypatch.setattr(normal_map_module, "NORMAL_MAP_MAX", 50)
    ctx = create_context()
    images = []
    try:
        for terrain in (g, w):
            tree = ApproximationTree.build(terrain, epsilon=0.5, max_points=17 * 17, progress=False)
            eng = Engine(tree, context=ctx, offscreen=True)
            try:
                cam = overview_camera(tree.bboxes[0], eng.scale)
                full = eng.render(cam, (160, 120), Cut(full_resolution=True)).image
                lod = eng.render(cam, (160, 120), Cut(alpha=1.0)).image
            finally:
                eng.release()
            images.append((full, lod))
    finally:
        ctx.release()
    assert images[0][0][..., 3].any()
    np.testing.assert_array_equal(images[0][0], images[1][0])
    np.testing.assert_array_equal(images[0][1], images[1][1])


def _window_in_child(grid: Grid) -> tuple[tuple[float, float], np.ndarray]:
    """Run in another process: the z range and one window of a shipped windowed grid."""
    return grid.z_range, grid.window(10, 40, 20, 60).heights


def test_windowed_grid_ships_to_another_process(tmp_path):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    tif = _write_tif(tmp_path / "dem.tif", _synthetic(300, 280))
    g, w = read_raster(tif, windowed=False), read_raster(tif, windowed=True)
    # As dask ships it: by pickle, to a fresh interpreter that opens the file itself.
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        z_range, heights = pool.submit(_window_in_child, w).result(timeout=300)
    assert z_range == g.z_range
    np.testing.assert_array_equal(heights, g.window(10, 40, 20, 60).heights)


def test_a_65536_squared_vrt_opens_windowed_by_default(tmp_path):
    """A 17 GB (as float32) VRT mosaic opens at once and answers from the one tile it holds."""
    z = _synthetic(300, 260)
    _write_tif(tmp_path / "tile.tif", z)
    n, r_off, c_off = 65536, 40000, 51234
    (tmp_path / "big.vrt").write_text(
        f"""<VRTDataset rasterXSize="{n}" rasterYSize="{n}">
  <SRS>EPSG:32610</SRS>
  <GeoTransform>400000.0, 2.0, 0.0, 4300000.0, 0.0, -2.0</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">
    <NoDataValue>-9999</NoDataValue>
    <SimpleSource>
      <SourceFilename relativeToVRT="1">tile.tif</SourceFilename><SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="260" ySize="300"/>
      <DstRect xOff="{c_off}" yOff="{r_off}" xSize="260" ySize="300"/>
    </SimpleSource>
  </VRTRasterBand>
</VRTDataset>"""
    )
    g = read_raster(tmp_path / "big.vrt")
    assert g.is_windowed and g.shape == (n, n)
    assert "_n_valid" not in g.__dict__
    assert g.heights.cached_bytes <= 512 * 512 * 4
    # The in-memory window holding the tile (same coordinates bit for bit) is the reference.
    tile = g.window(r_off, r_off + 299, c_off, c_off + 259)
    np.testing.assert_array_equal(tile.heights, z)
    rect = g.rect_of(r_off - 5, r_off + 120, c_off + 17, c_off + 300)
    pts = g.points(rect)
    assert len(pts) > 20000
    np.testing.assert_array_equal(pts, tile.points(rect))
    x, y = pts[:, 0] + 0.7, pts[:, 1] - 0.3
    np.testing.assert_array_equal(g.height_at(x, y), tile.height_at(x, y))


@pytest.mark.parametrize(
    "relative", ["edge/nz_elev.tif", "srtm/N22W160v2.3a.hgt.zip", "edge/SainteHelens.dem"]
)
def test_windowed_fill_equals_the_whole_band_fill(data_dir, relative):
    path = data_file(data_dir, relative)
    g = read_raster(path, nodata="fill", windowed=False)
    w = read_raster(path, nodata="fill", windowed=True)
    assert g.filled_count > 0 and w.nodata_policy == "fill"
    assert_same_grid(w, g)
    # Blocks far smaller than the fill's reach: each is filled from its halo alone.
    small = WindowedHeights(w.heights.source, cache_bytes=64 << 20, block_shape=(61, 89))
    rows, cols = g.shape
    assert rows * cols * 4 <= small.cache_bytes // 4  # read block by block, not in one go
    np.testing.assert_array_equal(small[:, :], g.heights)


@pytest.mark.parametrize("case", ["plain", "nodata", "mask"])
def test_read_into_fills_a_reused_buffer_like_read(tmp_path, case):
    """``RasterSource.read_into`` writes the window into the caller's buffer (returned as
    is) with ``read``'s values: nodata, masked cells and infinities of either sign as NaN,
    huge finite heights kept."""
    import rasterio

    z = _synthetic(300, 260, seed=3)
    z[10, 20], z[200, 5], z[150, 150] = np.inf, -np.inf, 3.0e38
    z[151, 150] = 3.0e38
    tif = _write_tif(tmp_path / "dem.tif", z, nodata=-9999.0 if case == "nodata" else None)
    if case == "mask":
        with rasterio.open(tif, "r+") as ds:
            ds.write_mask(np.where(np.isnan(z), 0, 255).astype(np.uint8))
    source = RasterSource(str(tif))
    want = z.copy()
    want[np.isinf(want)] = np.nan
    buffer = np.full((300, 260), 7.0, np.float32)
    for r0, r1 in ((0, 120), (100, 300), (5, 6)):
        out = source.read_into(r0, r1, 0, 260, buffer[: r1 - r0])
        assert np.shares_memory(out, buffer)
        np.testing.assert_array_equal(out, want[r0:r1])
        np.testing.assert_array_equal(source.read(r0, r1, 0, 260), want[r0:r1])
