"""Baking without GL: lattices, layer order, shading models and the NC land-use case."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from affine import Affine
from conftest import data_file

import approxtree as at
from approxtree import InvalidParameterError
from approxtree.datasets import fractal_terrain
from approxtree.textures import GouraudShading, PhongShading, TexturePyramid, TopographicShading
from approxtree.textures.bake import OVERLAY_COLOUR, bake, texture_lattice
from approxtree.textures.thematic import ClassTable


def test_nc_bake_puts_land_use_classes_at_their_map_positions(data_dir, tmp_path):
    """Baked NC texture: 10 m lattice, land-use hue at sampled map points, shading varies."""
    dem = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    landuse = data_file(data_dir, "nc/landuse_r.tif")
    result = bake(dem, tmp_path, thematic=landuse, max_texture_size=1024)
    figures = result.figures()
    assert figures["sizes"][0] == [1500, 1350]
    assert figures["levels"] == 2
    level0 = result.pyramid.level(0)
    with rasterio.open(landuse) as ds:
        classes = ds.read(1)
        table = ds.colormap(1)
        assert result.pyramid.levels[0].transform.almost_equals(ds.transform)
    rng = np.random.default_rng(0)
    # Away from the outer half-cell border (no shading there), each texel is its class colour
    # (softened by default, issue 17) times the shade factor of the "shade" blend (at most
    # 1.25 on sunny slopes): the hue ratios are kept up to rounding where nothing clips.
    table = ClassTable(table).softened().colours
    for _ in range(200):
        r, c = rng.integers(3, 1347), rng.integers(3, 1497)
        k = classes[r, c]
        if k == 255:
            assert level0[r, c, 3] == 0 or level0[r, c, 3] == 255
            continue
        colour = np.array(table[k][:3], dtype=float)
        texel = level0[r, c, :3].astype(float)
        shade = texel.max() / colour.max()
        assert 0 < shade <= 1.25 + 1e-9
        if texel.max() < 255:
            np.testing.assert_allclose(texel, colour * shade, atol=2.5)
    assert level0[..., 0].std() > 10


def test_overlays_are_drawn_on_top(data_dir, tmp_path):
    """Stream pixels of a shading + streams bake carry the overlay colour."""
    dem = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    streams = data_file(data_dir, "nc/streams.shp")
    result = bake(dem, tmp_path, overlays=[streams], max_texture_size=512)
    level0 = result.pyramid.level(0)
    r, g, b, _ = OVERLAY_COLOUR
    blue = (level0[..., 0] == r) & (level0[..., 1] == g) & (level0[..., 2] == b)
    assert 0.01 < blue.mean() < 0.5
    assert result.figures()["layers"] == ["shading:topographic", "overlay:streams.shp"]


def test_shading_only_bake_is_the_hillshade(tmp_path):
    """A pure topographic bake at DEM resolution has R = G = B = the hillshade value."""
    g = fractal_terrain(100, 120, seed=4, relief=200.0)
    result = bake(g, tmp_path, max_texture_size=128, gl=False)
    level0 = np.asarray(result.pyramid.level(0))
    shade = TopographicShading(g).shade()
    np.testing.assert_array_equal(level0[..., 0], shade)
    np.testing.assert_array_equal(level0[..., 1], shade)
    np.testing.assert_array_equal(level0[..., 2], shade)


def test_texture_lattice_covers_the_grid_cells():
    """The lattice at a finer texel size spans exactly the DEM's cell extent."""
    g = fractal_terrain(50, 80, seed=1)
    t, (rows, cols) = texture_lattice(g, 10.0 / 3)
    assert (rows, cols) == (150, 240)
    assert t @ (0, 0) == g.transform @ (0, 0)
    assert np.allclose(t @ (cols, rows), g.transform @ (80, 50))


def test_phong_and_gouraud_agree_at_vertices_and_differ_between():
    """Phong and Gouraud are equal at the data points and differ inside oversampled cells."""
    g = fractal_terrain(33, seed=5, relief=300.0)
    p = PhongShading(g, oversample=4).shade()
    q = GouraudShading(g, oversample=4).shade()
    np.testing.assert_array_equal(p[::4, ::4], q[::4, ::4])
    assert (p != q).mean() > 0.1
    flat = at.Grid(np.zeros((5, 5)))
    lit = PhongShading(flat, altitude=90.0, ambient=0.0, diffuse=1.0).shade()
    assert (lit == 255).all()


def test_bad_bake_requests(tmp_path):
    """Unknown shading or blend, nothing to bake, or a missing raster are clear errors."""
    g = fractal_terrain(9)
    with pytest.raises(InvalidParameterError, match="shading"):
        bake(g, tmp_path, shading="toon")
    with pytest.raises(InvalidParameterError, match="blend"):
        bake(g, tmp_path, blend="screen")
    with pytest.raises(InvalidParameterError, match="Nothing to bake"):
        bake(g, tmp_path, shading=None)
    with pytest.raises(at.TerrainFormatError, match="does not exist"):
        bake(g, tmp_path, thematic=tmp_path / "none.tif")


# (data file, TopographicShading options) for the GL bake against numpy.
GL_CASES = [
    ("edge/SainteHelens.dem", {}),
    ("edge/SainteHelens.dem", {"algorithm": "zevenbergen-thorne"}),
    ("edge/SainteHelens.dem", {"combined": True}),
    ("edge/SainteHelens.dem", {"multidirectional": True}),
    ("edge/dtm.tif", {"multidirectional": True, "algorithm": "zevenbergen-thorne"}),
    ("nc/elev_ned_30m.tif", {"z_factor": 3.0, "azimuth": 100.0, "altitude": 30.0}),
]


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the GL bake tests."""
    from approxtree.render.context import create_context

    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.mark.parametrize(("relative", "options"), GL_CASES)
def test_gl_bake_equals_numpy_and_tiles_join_exactly(data_dir, gl_context, relative, options):
    """GL hillshade of a real DEM (with nodata) equals the numpy kernel within ±1, nodata
    alike; drawn in forced 37 × 37 tiles it equals the one-pass result exactly."""
    from approxtree.textures.gl_bake import GLTopographicShading

    grid = at.open_terrain(data_file(data_dir, relative))
    # A crop keeps the test quick and puts the crop edge inside valid data.
    rows, cols = grid.shape
    crop = at.Grid(
        grid.heights[: min(rows, 300), : min(cols, 300)], transform=grid.transform, crs=grid.crs
    )
    numpy_shade = TopographicShading(crop, **options).shade().astype(np.int64)
    one_pass = GLTopographicShading(crop, context=gl_context, **options).shade()
    tiled = GLTopographicShading(crop, context=gl_context, tile_size=37, **options).shade()
    np.testing.assert_array_equal(one_pass == 0, numpy_shade == 0)
    assert np.abs(one_pass.astype(np.int64) - numpy_shade).max() <= 1
    np.testing.assert_array_equal(tiled, one_pass)
    if relative.startswith("edge/"):
        assert (numpy_shade == 0).sum() > 2 * (crop.shape[0] + crop.shape[1])


def test_gl_bake_equals_gdaldem(data_dir, tmp_path, gl_context):
    """The GL bake of SainteHelens (nodata inside) equals gdaldem hillshade within ±1."""
    import shutil
    import subprocess

    from approxtree.textures.gl_bake import GLTopographicShading

    if shutil.which("gdaldem") is None:
        pytest.fail("gdaldem is missing: install the Debian package gdal-bin")
    path = data_file(data_dir, "edge/SainteHelens.dem")
    out = tmp_path / "hs.tif"
    subprocess.run(["gdaldem", "hillshade", "-q", str(path), str(out)], check=True)
    with rasterio.open(out) as ds:
        ref = ds.read(1).astype(np.int64)
    mine = GLTopographicShading(at.open_terrain(path), context=gl_context).shade()
    np.testing.assert_array_equal(mine == 0, ref == 0)
    assert np.abs(mine.astype(np.int64) - ref).max() <= 1


def test_bake_uses_gl_and_falls_back_to_numpy(tmp_path, gl_context):
    """bake() shades with GL (tiled here) on the context it is given; without one it falls
    back to numpy and the pyramids agree within ±1."""
    g = fractal_terrain(130, 150, seed=8, relief=250.0)
    on_gpu = bake(g, tmp_path / "gl", context=gl_context, tile_size=50, max_texture_size=64)
    assert on_gpu.gl and on_gpu.figures()["gl"] is True
    fallback = bake(g, tmp_path / "np", max_texture_size=64, context=None)
    assert fallback.gl is False
    a = np.asarray(on_gpu.pyramid.level(0)).astype(np.int64)
    b = np.asarray(fallback.pyramid.level(0)).astype(np.int64)
    assert np.abs(a - b).max() <= 1
    np.testing.assert_array_equal(b[..., 0], TopographicShading(g).shade())
    assert len(on_gpu.pyramid) == len(fallback.pyramid) == 3


def test_the_bake_command_does_not_import_the_tree_builder(tmp_path):
    """``approxtree bake`` of a DEM imports neither the tree builder nor the patch strategies
    (their numba kernels are a third of the import time of every bake)."""
    import subprocess
    import sys

    code = (
        "import sys, approxtree, approxtree.cli, approxtree.io, approxtree.textures.bake\n"
        "approxtree.cli._is_tree('dem.tif')\n"
        "print(sorted(m for m in sys.modules if m.startswith(('approxtree.tree.', "
        "'approxtree.patches', 'approxtree.render'))))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=tmp_path
    )
    assert out.stdout.strip() == "['approxtree.tree.zarr_store']"
    # The names stay where they were, imported on first use.
    from approxtree import ApproximationTree
    from approxtree.tree import ApproximationTree as same

    assert ApproximationTree is same


def test_the_program_ends_a_bake_without_the_teardown(tmp_path):
    """``python -m approxtree bake`` ends its process as soon as the pyramid is written and
    its summary printed (no atexit handlers: the interpreter's teardown is skipped), while a
    failing bake and other commands end as usual (handlers run, exit code kept)."""
    import subprocess
    import sys

    dem = tmp_path / "dem.tif"
    z = np.linspace(0.0, 50.0, 64 * 48, dtype=np.float32).reshape(64, 48)
    profile = {"driver": "GTiff", "width": 48, "height": 64, "count": 1, "dtype": "float32"}
    with rasterio.open(dem, "w", **profile, transform=Affine(10, 0, 0, 0, -10, 640)) as ds:
        ds.write(z, 1)
    code = (
        "import atexit, sys\n"
        "atexit.register(lambda: print('TEARDOWN'))\n"
        "from approxtree.cli import run\n"
        "sys.argv = ['approxtree', *sys.argv[1:]]\n"
        "run()\n"
    )

    def program(*args: str) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-c", code, *args]
        return subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path)

    done = program("bake", str(dem), "--out", "p", "--no-gl", "--quiet", "--json")
    assert done.returncode == 0, done.stderr
    assert "TEARDOWN" not in done.stdout
    # The summary was flushed before the end, and the pyramid is whole.
    assert '"levels"' in done.stdout and (tmp_path / "p" / "pyramid.json").is_file()
    pyramid = TexturePyramid(tmp_path / "p")
    assert pyramid.level(0).shape == (64, 48, 4)
    failed = program("bake", str(dem), "--out", "p", "--no-gl", "--palette", "nlcd")
    assert failed.returncode == 2 and "Error:" in failed.stderr
    assert "TEARDOWN" in failed.stdout
    info = program("info", str(dem))
    assert info.returncode == 0 and "TEARDOWN" in info.stdout


@pytest.mark.parametrize("windowed", [False, True])
@pytest.mark.parametrize(
    "options",
    [{}, {"algorithm": "zevenbergen-thorne"}, {"multidirectional": True}, {"combined": True}],
)
def test_hillshade_strips_are_the_whole_hillshade(windowed, options):
    """The pyramid's strips of a plain hillshade, shaded strip by strip from the heights (read
    by windows with a one-row halo when the grid is windowed), are texel for texel the grey
    levels and alpha of the whole grid's hillshade: strip edges, the grid's border and holes
    included; a windowed grid's band is never read whole."""
    from approxtree.geometry.grid import Grid
    from approxtree.geometry.windowed import ArraySource, WindowedHeights
    from approxtree.textures.base import grey_alpha_strips

    rng = np.random.default_rng(7)
    z = np.cumsum(rng.normal(0, 3, (53, 41)), axis=0).astype(np.float32)
    z[20:23, 10:14] = np.nan
    z[6, :] = np.nan  # a hole across a strip edge (rows 0..5 | 6..11)
    whole = Grid(z, transform=Affine(10, 0, 0, 0, -10, 530))
    heights = WindowedHeights(ArraySource(z), cache_bytes=1 << 14, block_shape=(8, 8))
    grid = Grid(heights, transform=whole.transform) if windowed else whole
    shading = TopographicShading(grid, **options)
    shade = TopographicShading(whole, **options).shade()
    expected = [s.copy() for s in grey_alpha_strips(shade, 6)]  # a reused buffer
    strips = [s.copy() for s in shading.level_strips(6)]
    assert [s.shape for s in strips] == [e.shape for e in expected]
    for got, want in zip(strips, expected, strict=True):
        np.testing.assert_array_equal(got, want)
    assert sum(int((s[1] == 0).sum()) for s in strips) > 2 * (53 + 41)  # holes and border
    # A windowed grid is read strip by strip, never whole.
    assert "_whole_heights" not in grid.__dict__


class _Info:
    def __init__(self, renderer: str) -> None:
        self.info = {"GL_RENDERER": renderer}


def test_software_renderers_are_recognised():
    """Mesa's and Google's CPU rasterizers count as software, a GPU's driver does not."""
    from approxtree.render.context import is_software

    assert is_software(_Info("llvmpipe (LLVM 15.0.6, 256 bits)"))
    assert is_software(_Info("Google SwiftShader"))
    assert is_software(_Info("softpipe"))
    assert not is_software(_Info("NVIDIA H100 80GB HBM3/PCIe/SSE2"))
    assert not is_software(_Info("AMD Radeon RX 7900 XTX (radeonsi, navi31, LLVM 17.0.6)"))


def test_cli_bake_uses_opengl_only_on_a_gpu(tmp_path):
    """The CLI bakes with OpenGL where a GPU draws, with numpy on a CPU-only OpenGL."""
    import json

    from click.testing import CliRunner

    from approxtree.cli import main
    from approxtree.render.context import hardware_gl

    dem = tmp_path / "dem.npy"
    np.save(dem, fractal_terrain(65, seed=3).heights)
    done = CliRunner().invoke(main, ["bake", str(dem), "--out", str(tmp_path / "p"), "--json"])
    assert done.exit_code == 0, done.output
    assert json.loads(done.output)["gl"] is hardware_gl()
