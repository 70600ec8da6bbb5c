"""Textures without GL: hillshade and colour relief against gdaldem, class tables, blending."""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest
import rasterio
from affine import Affine
from conftest import data_file

import approxtree as at
from approxtree import InvalidParameterError, TerrainFormatError
from approxtree.datasets import fractal_terrain
from approxtree.textures import (
    ClassTable,
    ColourRamp,
    ColourReliefFile,
    MultiTexture,
    ThematicTexture,
    TopographicShading,
    blend,
    rasterize_lines,
)


def gdaldem(*args: str) -> None:
    """Run gdaldem (Debian package gdal-bin, installed by .ci/run); fail clearly without it."""
    if shutil.which("gdaldem") is None:
        pytest.fail("gdaldem is missing: install the Debian package gdal-bin")
    # PAM off: color-relief with percentages computes the source's statistics, which GDAL
    # would save as X.aux.xml beside the shared data.
    env = {**os.environ, "GDAL_PAM_ENABLED": "NO"}
    subprocess.run(["gdaldem", *args, "-q"], check=True, env=env)


def read_bands(path) -> np.ndarray:
    with rasterio.open(path) as ds:
        return np.moveaxis(ds.read(), 0, -1).astype(np.int64)


# (data file, gdaldem options, TopographicShading options)
HILLSHADE_CASES = [
    ("edge/SainteHelens.dem", [], {}),
    ("edge/SainteHelens.dem", ["-alg", "ZevenbergenThorne"], {"algorithm": "zevenbergen-thorne"}),
    ("edge/SainteHelens.dem", ["-combined"], {"combined": True}),
    ("edge/SainteHelens.dem", ["-multidirectional"], {"multidirectional": True}),
    (
        "nc/elev_ned_30m.tif",
        ["-z", "3", "-az", "100", "-alt", "30"],
        {"z_factor": 3.0, "azimuth": 100.0, "altitude": 30.0},
    ),
    (
        "edge/dtm.tif",
        ["-multidirectional", "-alg", "ZevenbergenThorne"],
        {"multidirectional": True, "algorithm": "zevenbergen-thorne"},
    ),
    ("srtm/N22W160v2.3a.hgt.zip", ["-s", "111120", "-combined"], {"combined": True}),
]


@pytest.mark.parametrize(("relative", "gdal_args", "options"), HILLSHADE_CASES)
def test_hillshade_equals_gdaldem(data_dir, tmp_path, relative, gdal_args, options):
    """Horn, ZT, combined and multidirectional shading equal gdaldem within ±1, nodata alike."""
    path = data_file(data_dir, relative)
    src = f"/vsizip/{path}/N22W160.hgt" if str(path).endswith(".zip") else str(path)
    out = tmp_path / "hs.tif"
    gdaldem("hillshade", *gdal_args, src, str(out))
    ref = read_bands(out)[..., 0]
    # Kauai is in degrees: scale=None must pick gdaldem's -s 111120 by itself.
    mine = TopographicShading(at.open_terrain(path), **options).shade().astype(np.int64)
    assert mine.shape == ref.shape
    np.testing.assert_array_equal(mine == 0, ref == 0)
    assert np.abs(mine - ref).max() <= 1


def test_colour_relief_equals_gdaldem(data_dir, tmp_path):
    """A colour file with nv, percentages, names and mixed separators equals gdaldem exactly."""
    path = data_file(data_dir, "edge/SainteHelens.dem")
    colours = tmp_path / "colours.txt"
    colours.write_text(
        "# elevation colours\n"
        "nv 0 0 0 0\n"
        "700,20,40,200\n"
        "10% 50 160 60\n"
        "1500 white\n"
        "1800:brown\n"
        "2000 150 100 50 200\n"
        "75% 200 200 200\n"
        "2543 255 0 0\n"
    )
    out = tmp_path / "relief.tif"
    gdaldem("color-relief", "-alpha", str(path), str(colours), str(out))
    grid = at.open_terrain(path)
    mine = ThematicTexture(grid.heights, grid.transform, ColourReliefFile(colours)).rgba()
    np.testing.assert_array_equal(mine.astype(np.int64), read_bands(out))


def test_nodata_without_nv_stays_transparent(tmp_path):
    """Without an nv line, nodata is transparent, never coloured as an elevation."""
    colours = tmp_path / "c.txt"
    colours.write_text("0 0 0 0\n10 255 255 255\n")
    z = np.array([[0.0, 5.0], [np.nan, 10.0]])
    rgba = ThematicTexture(z, Affine.identity(), ColourReliefFile(colours)).rgba()
    assert rgba[1, 0].tolist() == [0, 0, 0, 0]
    assert rgba[0, 1].tolist() == [127, 127, 127, 255]


def test_landuse_uses_its_embedded_colour_table(data_dir):
    """The land-use raster's embedded table colours each class; nodata (255) is transparent."""
    path = data_file(data_dir, "nc/landuse_r.tif")
    tex = ThematicTexture.from_raster(path)
    rgba = tex.rgba()
    with rasterio.open(path) as ds:
        classes = ds.read(1)
        table = ds.colormap(1)
    for k in range(1, 8):
        r, c = np.argwhere(classes == k)[0]
        assert tuple(rgba[r, c]) == table[k]
    assert (rgba[classes == 255, 3] == 0).all()
    assert (rgba[classes != 255, 3] == 255).all()


def test_colour_ramp_maps_the_range_ends():
    """A matplotlib ramp maps vmin and vmax to the colormap's ends; NaN is transparent."""
    import matplotlib

    z = np.array([[0.0, 50.0, 100.0, np.nan]])
    rgba = ColourRamp("viridis", 0.0, 100.0)(z, np.isfinite(z))
    cmap = matplotlib.colormaps["viridis"]
    assert tuple(rgba[0, 0]) == tuple(cmap(0.0, bytes=True))
    assert tuple(rgba[0, 2]) == tuple(cmap(1.0, bytes=True))
    assert rgba[0, 3, 3] == 0


def _pixel(rgb, a=255):
    return np.array([[[*rgb, a]]], dtype=np.uint8)


@pytest.mark.parametrize("mode", ["multiply", "overlay", "soft-light", "over"])
def test_blend_modes_follow_the_w3c_formulas(mode):
    """Each blend mode gives the W3C compositing result on one opaque pixel."""
    backdrop = _pixel((102, 204, 255))
    source = _pixel((128, 128, 0))
    b = backdrop[0, 0, :3] / 255.0
    s = source[0, 0, :3] / 255.0
    formulas = {
        "multiply": b * s,
        "overlay": np.where(b <= 0.5, 2 * b * s, 1 - 2 * (1 - b) * (1 - s)),
        "soft-light": np.where(
            s <= 0.5,
            b - (1 - 2 * s) * b * (1 - b),
            b + (2 * s - 1) * (np.where(b <= 0.25, ((16 * b - 12) * b + 4) * b, np.sqrt(b)) - b),
        ),
        "over": s,
    }
    want = np.round(formulas[mode] * 255).astype(int)
    got = blend(backdrop, source, mode)[0, 0]
    np.testing.assert_array_equal(got[:3], want)
    assert got[3] == 255


def test_blend_respects_source_alpha():
    """A transparent source pixel leaves the backdrop unchanged; half alpha mixes halfway."""
    backdrop = _pixel((200, 100, 50))
    assert blend(backdrop, _pixel((0, 0, 0), 0), "multiply")[0, 0].tolist() == [200, 100, 50, 255]
    half = blend(backdrop, _pixel((0, 0, 0), 128), "over")[0, 0]
    assert abs(int(half[0]) - 100) <= 1


def test_multitexture_blends_shading_over_land_use(data_dir):
    """Land use multiplied by hillshade keeps class hues and darkens shaded slopes."""
    grid = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    shade = TopographicShading(grid)
    classes = np.where(np.arange(grid.width)[None, :] < grid.width // 2, 1, 2)
    classes = np.broadcast_to(classes, grid.shape)
    land = ThematicTexture(classes, grid.transform, ClassTable({1: (255, 0, 0), 2: (0, 0, 255)}))
    out = MultiTexture([land, shade], ["multiply"]).rgba()
    inner = out[1:-1, 1:-1]
    assert (inner[:, : grid.width // 2 - 2, 2] == 0).all()  # red half has no blue
    assert (inner[:, grid.width // 2 :, 0] == 0).all()  # blue half has no red
    assert inner[..., 0].std() > 0  # the shading modulates the colour


def test_multitexture_rejects_mismatched_lattices():
    """Layers on different lattices must be resampled first: a clear error says so."""
    a = ThematicTexture(np.zeros((4, 4)), Affine.identity(), ClassTable({0: (1, 2, 3)}))
    b = ThematicTexture(np.zeros((5, 4)), Affine.identity(), ClassTable({0: (1, 2, 3)}))
    with pytest.raises(InvalidParameterError, match="lattice"):
        MultiTexture([a, b], ["over"])


def test_streams_rasterize_onto_the_dem_lattice(data_dir):
    """NC streams (EPSG:3358) burn into the DEM lattice (EPSG:32119) along their lines."""
    import pyogrio
    import shapely

    grid = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    streams = data_file(data_dir, "nc/streams.shp")
    tex = rasterize_lines(streams, grid.transform, grid.shape, grid.crs, width=30.0)
    burnt = tex.values > 0
    assert 0.01 < burnt.mean() < 0.5
    _, _, wkb, _ = pyogrio.raw.read(streams, columns=[])
    lines = shapely.union_all(shapely.from_wkb(wkb))
    rr, cc = np.nonzero(burnt)
    pick = np.random.default_rng(0).choice(len(rr), 200, replace=False)
    pts = shapely.points(grid.x_coords[cc[pick]], grid.y_coords[rr[pick]])
    # A burnt cell centre is within half the width plus half a cell diagonal of a stream.
    assert shapely.distance(pts, lines).max() <= 15.0 + 15.0 * np.sqrt(2)


def test_cast_shadows_fall_behind_a_wall():
    """Light from the west: cells east of a tall wall are shadowed, cells west are lit."""
    z = np.zeros((20, 40))
    z[:, 20] = 100.0
    g = at.Grid(z, Affine(1, 0, 0, 0, -1, 20))
    mask = TopographicShading(g, azimuth=270.0, altitude=30.0).shadow_mask()
    assert mask[10, 21:30].all()
    assert not mask[10, :20].any()


def test_curvature_marks_ridges_and_hollows():
    """Curvature is negative on a ridge and positive in a valley."""
    x = np.linspace(-1, 1, 41)
    ridge = at.Grid(np.broadcast_to(-(x**2) * 100, (41, 41)).copy())
    valley = at.Grid(np.broadcast_to(x**2 * 100, (41, 41)).copy())
    assert TopographicShading(ridge).curvature()[20, 20] < 0
    assert TopographicShading(valley).curvature()[20, 20] > 0


def test_morphology_and_shadows_darken():
    """Slope weighting and cast shadows only ever darken the plain hillshade."""
    g = fractal_terrain(65, seed=3, relief=300.0)
    plain = TopographicShading(g).shade().astype(int)
    moody = TopographicShading(g, slope_weight=1.0, shadows=True, altitude=20.0)
    low = TopographicShading(g, altitude=20.0).shade().astype(int)
    assert (moody.shade().astype(int) <= low).all()
    assert plain.std() > 0


def test_bad_shading_and_colour_inputs(tmp_path):
    """Unknown algorithm, altitude out of range, malformed or missing colour files are errors."""
    g = fractal_terrain(9)
    with pytest.raises(InvalidParameterError, match="algorithm"):
        TopographicShading(g, algorithm="sobel")
    with pytest.raises(InvalidParameterError, match="altitude"):
        TopographicShading(g, altitude=95.0)
    with pytest.raises(InvalidParameterError, match="exclude"):
        TopographicShading(g, combined=True, multidirectional=True)
    bad = tmp_path / "bad.txt"
    bad.write_text("100 12 13\n")
    with pytest.raises(TerrainFormatError, match=r"bad\.txt:1"):
        ColourReliefFile(bad)
    with pytest.raises(TerrainFormatError, match="does not exist"):
        ColourReliefFile(tmp_path / "missing.txt")
    with pytest.raises(InvalidParameterError, match="colormap"):
        ColourRamp("no-such-map")


@pytest.mark.parametrize("algorithm", [0, 1])
@pytest.mark.parametrize("mode", [0, 1, 2])
def test_grey_hillshade_kernel_rounds_like_numpy(algorithm, mode):
    """hillshade_grey (the bake's kernel, no float grid) is np.rint of the float kernel on
    every cell, nodata holes and borders included."""
    from approxtree.kernels import hillshade as hs

    z = fractal_terrain(90, 70, seed=4, relief=300.0).heights.copy()
    z[20:25, 30:41] = np.nan
    args = (z, 2.0, -2.0, 1.5, 40.0, 300.0, algorithm, mode)
    want = np.rint(hs.hillshade(*args)).astype(np.uint8)
    np.testing.assert_array_equal(hs.hillshade_grey(*args), want)


def test_texture_names_load_with_their_modules_only():
    """``approxtree.textures`` imports a public name's module on first use: a bake's imports
    (shading, pyramid) leave out the OpenGL bake, patches and palettes; every name of
    ``__all__`` still resolves, ``blend`` to the function."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import approxtree.textures.bake\n"
        "print(sorted(m for m in sys.modules if m.startswith('approxtree.textures.')))\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = run.stdout.strip().splitlines()[-1]
    for module in ("gl_bake", "patch", "palettes"):
        assert f"approxtree.textures.{module}'" not in loaded
    import approxtree.textures as textures
    from approxtree.textures.blend import blend

    assert all(getattr(textures, name) is not None for name in textures.__all__)
    assert textures.blend is blend and set(textures.__all__) <= set(dir(textures))
