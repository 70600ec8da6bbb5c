"""Map tiles (``approxtree tiles --format imagery|terrarium|terrain-rgb``): tilings, heights,
imagery, PMTiles archives and their verification.

Tiles are decoded here with Pillow and the encodings' published formulas (Terrarium:
R·256 + G + B/256 − 32768; Terrain-RGB: −10000 + (R·65536 + G·256 + B)·0.1); pixel centres
come from the tilings' formulas written here; tile bounds are compared with morecantile's
WebMercatorQuad and WorldCRS84Quad; archives are read with the ``pmtiles`` package.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from click.testing import CliRunner
from conftest import data_file
from PIL import Image

from approxtree.cli import main
from approxtree.datasets import fractal_heights
from approxtree.errors import InvalidParameterError, StoreError
from approxtree.io import open_terrain
from approxtree.textures.pyramid import TexturePyramid
from approxtree.tiles.imagery import ImageryTiles
from approxtree.tiles.map_tiles import tile_plan, write_map_tiles
from approxtree.tiles.raster_dem import DemTiles
from approxtree.tiles.schemes import SCHEMES
from approxtree.verify import verify

DECODE = {"terrarium": (256.0, 32768.0, 1 / 256), "terrain-rgb": (10.0, 10000.0, 0.1)}


def decode_heights(data: bytes, encoding: str) -> np.ndarray:
    """(h, w) heights of a raster-dem tile, by the encoding's formula."""
    scale, offset, _ = DECODE[encoding]
    rgb = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), dtype=np.float64)
    return (rgb[..., 0] * 65536 + rgb[..., 1] * 256 + rgb[..., 2]) / scale - offset


def mercator_centres(z: int, x: int, y: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(lon, lat) of a Web Mercator tile's pixel centres, row 0 north."""
    t = (np.arange(size) + 0.5) / size
    n = 2.0**z
    lon = -180.0 + 360.0 * (x + t) / n
    lat = np.degrees(np.arctan(np.sinh(np.pi * (1.0 - 2.0 * (y + t) / n))))
    return np.meshgrid(lon, lat)


@pytest.fixture(scope="module")
def nc(data_dir: Path):
    return open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))


@pytest.fixture(scope="module")
def gradient_pyramid(tmp_path_factory) -> TexturePyramid:
    """A 400 × 300 RGBA texture in EPSG:32119 (NC's CRS), 30 m texels: R grows eastward
    (texel column), G southward (texel row), B = 7, opaque."""
    rows, cols = 300, 400
    rgba = np.zeros((rows, cols, 4), dtype=np.uint8)
    rgba[..., 0] = (np.arange(cols) * 255 // (cols - 1))[None, :]
    rgba[..., 1] = (np.arange(rows) * 255 // (rows - 1))[:, None]
    rgba[..., 2] = 7
    rgba[..., 3] = 255
    folder = tmp_path_factory.mktemp("pyr") / "gradient"
    transform = Affine(30.0, 0.0, 630000.0, 0.0, -30.0, 228500.0)
    return TexturePyramid.build(rgba, folder, 256, transform=transform, crs="EPSG:32119")


def test_tilings_match_morecantile():
    """Tile bounds of both tilings equal morecantile's (geographic: WorldCRS84Quad with TMS
    rows), pixel centres lie inside their tile, and tiles_touching finds a point's tile."""
    import morecantile
    from shapely import Point

    merc = morecantile.tms.get("WebMercatorQuad")
    crs84 = morecantile.tms.get("WorldCRS84Quad")
    for z, x, y in [(0, 0, 0), (3, 5, 2), (12, 1152, 1611), (17, 37000, 51000)]:
        b = merc.bounds(x, y, z)
        assert SCHEMES["webmercator"].bounds(z, x, y) == pytest.approx(
            (b.left, b.bottom, b.right, b.top), abs=1e-9
        )
    for z, x, y in [(0, 1, 0), (4, 7, 3), (13, 4586, 5820)]:
        b = crs84.bounds(x, 2**z - 1 - y, z)
        assert SCHEMES["geographic"].bounds(z, x, y) == pytest.approx(
            (b.left, b.bottom, b.right, b.top), abs=1e-9
        )
    for scheme in SCHEMES.values():
        w, s, e, n = scheme.bounds(9, 150, 200)
        lon, lat = scheme.pixel_centres(9, 150, 200, 256)
        assert w < lon.min() < lon.max() < e and s < lat.min() < lat.max() < n
        assert lat[0, 0] > lat[-1, 0]
        point = Point(-78.9, 35.8)
        for z in (0, 5, 13):
            tiles = scheme.tiles_touching(point.buffer(1e-9), z)
            assert any(
                scheme.bounds(z, *t)[0] <= -78.9 <= scheme.bounds(z, *t)[2]
                and scheme.bounds(z, *t)[1] <= 35.8 <= scheme.bounds(z, *t)[3]
                for t in tiles
            )


@pytest.mark.parametrize("encoding", ["terrarium", "terrain-rgb"])
def test_raster_dem_heights_are_within_the_step_of_h_t(nc, tmp_path, encoding):
    """Every pixel whose centre lies in the DEM decodes within the encoding's step of h_T
    there; the whole zoom range down to the DEM's cell is written, 512 px; verify agrees."""
    from pyproj import Transformer

    out = tmp_path / encoding
    figures = write_map_tiles(DemTiles(nc, encoding), out)
    doc = json.loads((out / "tilejson.json").read_text())
    assert doc["scheme"] == "xyz" and doc["minzoom"] == 0
    # NC's 30 m cells at 35.7° N: zoom 12 is the first with pixels (15.5 m) under a cell.
    assert doc["maxzoom"] == 12 and figures["tiles"] == doc["approxtree"]["tiles"]
    to_dem = Transformer.from_crs("EPSG:4326", nc.crs, always_xy=True)
    _, _, step = DECODE[encoding]
    measured = 0
    for path in sorted(out.rglob("*.png")):
        z, x, y = int(path.parent.parent.name), int(path.parent.name), int(path.stem)
        heights = decode_heights(path.read_bytes(), encoding)
        assert heights.shape == (512, 512)
        h = nc.height_at(*to_dem.transform(*mercator_centres(z, x, y, 512)))
        known = np.isfinite(h)
        measured += int(known.sum())
        assert np.abs(heights[known] - h[known]).max(initial=0.0) <= step / 2 + 1e-9
    assert measured > 500 * 450
    report = verify(out, nc)
    assert report.ok, report.offenders
    assert report.figures["worst_height_error"] <= step / 2 + 1e-9


def test_verify_finds_a_height_off_by_more_than_the_step(nc, tmp_path):
    """A tile whose pixel is changed by two codes fails verify's heights check, naming it."""
    out = tmp_path / "t"
    write_map_tiles(DemTiles(nc, "terrarium", maxzoom=11, minzoom=11), out)
    path = next(out.rglob("*.png"))
    rgb = np.asarray(Image.open(path).convert("RGB")).copy()
    # A pixel of the DEM (NC lies 55..156 m high; outside it the tile holds 0 m).
    data = np.argwhere(decode_heights(path.read_bytes(), "terrarium") > 50.0)
    r, c = data[len(data) // 2]
    rgb[r, c, 2] = (int(rgb[r, c, 2]) + 2) % 256
    Image.fromarray(rgb).save(path)
    report = verify(out, nc)
    assert not report.ok
    assert report.checks["heights"].failures == 1
    assert f"pixel ({r}, {c})" in report.offenders[0].address


def test_pmtiles_archive_holds_the_same_tiles(nc, tmp_path):
    """An .pmtiles --out is one archive (read by the pmtiles package) with every tile of the
    folder, byte for byte, WEBP lossless when asked, the TileJSON as metadata; verify reads it."""
    from pmtiles.reader import MmapSource, Reader, all_tiles
    from pmtiles.tile import TileType

    folder, archive = tmp_path / "dem", tmp_path / "dem.pmtiles"
    source = DemTiles(nc, "terrarium", tile_size=256, image_format="webp", minzoom=8)
    write_map_tiles(source, folder)
    write_map_tiles(source, archive)
    with open(archive, "rb") as f:
        reader = Reader(MmapSource(f))
        header, meta = reader.header(), reader.metadata()
        stored = {zxy: data for zxy, data in all_tiles(reader.get_bytes)}
    assert header["tile_type"] == TileType.WEBP and header["min_zoom"] == 8
    assert meta == json.loads((folder / "tilejson.json").read_text())
    files = {
        (int(p.parent.parent.name), int(p.parent.name), int(p.stem)): p.read_bytes()
        for p in folder.rglob("*.webp")
    }
    assert stored == files
    assert Image.open(io.BytesIO(next(iter(files.values())))).format == "WEBP"
    report = verify(archive, nc)
    assert report.ok and report.kind == "raster-dem"


def test_imagery_samples_the_pyramid_at_each_pixel_centre(gradient_pyramid, tmp_path):
    """Geographic (TMS) and Web Mercator imagery: each opaque pixel holds the texture at its
    centre (within 2 levels, bilinear); pixels off the texture are transparent."""
    from pyproj import Transformer

    to_crs = Transformer.from_crs("EPSG:4326", "EPSG:32119", always_xy=True)
    for name in ("geographic", "webmercator"):
        source = ImageryTiles(gradient_pyramid, SCHEMES[name])
        z = source.maxzoom
        for x, y in tile_plan(source)[z][:4]:
            rgba = np.asarray(Image.open(io.BytesIO(source.tile(z, x, y))))
            lon, lat = SCHEMES[name].pixel_centres(z, x, y, 256)
            px, py = to_crs.transform(lon, lat)
            col, row = (px - 630000.0) / 30.0 - 0.5, (228500.0 - py) / 30.0 - 0.5
            inside = (col >= 0.5) & (col <= 398.5) & (row >= 0.5) & (row <= 298.5)
            outside = (col < -1.5) | (col > 400.5) | (row < -1.5) | (row > 300.5)
            assert (rgba[inside, 3] == 255).all() and (rgba[outside, 3] == 0).all()
            want_r = col[inside] * 255 / 399
            want_g = row[inside] * 255 / 299
            assert np.abs(rgba[inside, 0] - want_r).max() <= 2.0
            assert np.abs(rgba[inside, 1] - want_g).max() <= 2.0
            assert (rgba[inside, 2] == 7).all()


def test_imagery_formats_and_coarse_zooms(gradient_pyramid, tmp_path):
    """PNG keeps alpha, WEBP decodes, JPEG is opaque RGB; a coarse tile averages the texture
    (its colour is the texture's mean, not one texel's); the folder verifies."""
    for fmt, mode in [("png", "RGBA"), ("webp", "RGBA"), ("jpeg", "RGB")]:
        source = ImageryTiles(gradient_pyramid, SCHEMES["webmercator"], image_format=fmt)
        out = tmp_path / fmt
        write_map_tiles(source, out)
        tiles = list(out.rglob(f"*.{'jpg' if fmt == 'jpeg' else fmt}"))
        assert len(tiles) == json.loads((out / "tilejson.json").read_text())["approxtree"]["tiles"]
        assert Image.open(tiles[0]).mode == mode
        assert verify(out).ok
    # Zoom 2: 20 km pixels over a 12 km texture, which falls in one averaged block.
    source = ImageryTiles(gradient_pyramid, SCHEMES["geographic"], maxzoom=2)
    rgba = source.pixels(2, *tile_plan(source)[2][0])
    opaque = rgba[..., 3] > 0
    assert 0 < opaque.sum() <= 4
    assert np.abs(rgba[opaque, 0].astype(int) - 127).max() <= 2


def test_verify_checks_imagery_colours_against_their_pyramid(gradient_pyramid, tmp_path):
    """Imagery PNG (geographic folder, every zoom down to the coarse ones that average
    blocks), WEBP and JPEG (Web Mercator PMTiles) verify against the pyramid they were cut
    from: every tile's pixels measured, within their format's tolerance; without the pyramid
    the colours are listed as not checked."""
    from approxtree.verify.map_tiles import COLOUR_TOLERANCE

    for fmt, scheme, name in [
        ("png", "geographic", "geo"),
        ("webp", "webmercator", "wm.pmtiles"),
        ("jpeg", "webmercator", "jpg.pmtiles"),
    ]:
        out = tmp_path / name
        write_map_tiles(ImageryTiles(gradient_pyramid, SCHEMES[scheme], image_format=fmt), out)
        report = verify(out, textures=gradient_pyramid.folder)
        assert report.ok, report.offenders[:3]
        tiles = report.figures["tiles"]
        assert report.checks["colours"].items == tiles > 4
        assert report.figures["pixels_measured"] == tiles * 256 * 256
        assert report.figures["worst_colour_difference"] <= COLOUR_TOLERANCE[fmt][1]
    assert report.figures["mean_colour_difference"] <= COLOUR_TOLERANCE["jpeg"][0]
    assert any("imagery colours" in n for n in verify(tmp_path / "geo").not_checked)


def test_verify_finds_an_imagery_pixel_off_its_pyramid(gradient_pyramid, tmp_path):
    """A PNG tile whose opaque pixel is made 8 levels redder fails verify's colours check,
    naming the tile and the pixel."""
    out = tmp_path / "t"
    source = ImageryTiles(gradient_pyramid, SCHEMES["webmercator"])
    z = source.maxzoom
    write_map_tiles(ImageryTiles(gradient_pyramid, SCHEMES["webmercator"], minzoom=z), out)
    path = max(out.rglob("*.png"), key=lambda p: np.asarray(Image.open(p))[..., 3].sum())
    rgba = np.asarray(Image.open(path)).copy()
    r, c = np.argwhere(rgba[..., 3] == 255)[0]
    rgba[r, c, 0] = (int(rgba[r, c, 0]) + 8) % 256
    Image.fromarray(rgba).save(path)
    report = verify(out, textures=gradient_pyramid.folder)
    assert not report.ok and report.checks["colours"].failures == 1
    assert f"pixel ({r}, {c}) channel R" in report.offenders[0].address


def test_map_outputs_refused_before_any_work(nc, gradient_pyramid, tmp_path):
    """A geographic tiling cannot go into PMTiles; a lossy raster-dem, heights the encoding
    cannot hold and a foreign folder are refused with what to do."""
    with pytest.raises(InvalidParameterError, match="webmercator"):
        write_map_tiles(
            ImageryTiles(gradient_pyramid, SCHEMES["geographic"]), tmp_path / "a.pmtiles"
        )
    with pytest.raises(InvalidParameterError, match="lossless"):
        DemTiles(nc, "terrarium", image_format="jpeg")
    # Heights beyond Terrarium's ±32768 m would be clipped: refused, the other one named.
    from approxtree.geometry import Grid

    tall = Grid(np.full((8, 8), 40000.0), Affine(0.001, 0, 10, 0, -0.001, 50), crs="EPSG:4326")
    with pytest.raises(InvalidParameterError, match="other encoding"):
        DemTiles(tall, "terrarium")
    assert DemTiles(tall, "terrain-rgb").maxzoom > 0
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(StoreError, match=r"notes\.txt"):
        write_map_tiles(DemTiles(nc, "terrarium", minzoom=3, maxzoom=3), foreign)
    assert (foreign / "notes.txt").read_text() == "mine"


def test_cli_writes_and_verifies_map_tiles(tmp_path):
    """tiles --format terrarium --out X.pmtiles and --format imagery --textures P from a tree
    store; approxtree verify exits 0 on both and the JSON figures name the format."""
    dem = small_dem(tmp_path / "dem.tif")
    runner = CliRunner()

    def run(*args: str) -> dict:
        result = runner.invoke(main, [*map(str, args), "--json"], catch_exceptions=False)
        assert result.exit_code == 0, result.output
        return json.loads(result.output.strip().splitlines()[-1])

    store = tmp_path / "s.zarr"
    run("build", dem, "--out", store)
    run("bake", store, "--out", tmp_path / "tex", "--no-gl", "--quiet")
    figures = run("tiles", store, "--format", "terrarium", "--out", tmp_path / "d.pmtiles")
    assert figures["format"] == "terrarium" and figures["tiles"] > 0
    figures = run(
        "tiles", store, "--format", "imagery", "--textures", tmp_path / "tex", "--out",
        tmp_path / "img", "--scheme", "webmercator", "--texture-format", "webp",
    )  # fmt: skip
    assert figures["tiling"] == "webmercator"
    for out in ("d.pmtiles", "img"):
        result = runner.invoke(main, ["verify", str(tmp_path / out), "--source", str(dem)])
        assert result.exit_code == 0, result.output
    result = runner.invoke(main, ["tiles", str(store), "--format", "imagery", "--out", "x"])
    assert result.exit_code == 2 and "--textures" in result.output
    assert math.isfinite(figures["bytes_per_tile"])


def small_dem(path: Path) -> Path:
    """A 129² fractal GeoTIFF in degrees (0.0005° cells, about 50 m), relief 300 m."""
    import rasterio

    heights = fractal_heights(129, seed=3, relief=300.0).astype(np.float32)
    profile = {"driver": "GTiff", "width": 129, "height": 129, "count": 1, "dtype": "float32"}
    transform = Affine(0.0005, 0, -72.0, 0, -0.0005, 45.0)
    with rasterio.open(path, "w", **profile, transform=transform, crs="EPSG:4326") as ds:
        ds.write(heights, 1)
    return path
