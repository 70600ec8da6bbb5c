"""Image textures: RGB(A), grey and paletted rasters in any CRS draped on a terrain (issue 30).

The test image is the NC land use rendered to RGBA through its colour table (nodata
transparent) and warped to EPSG:4326: another CRS than the DEM's (EPSG:32119).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner
from conftest import data_file
from rasterio.warp import Resampling, calculate_default_transform, reproject
from scipy.ndimage import maximum_filter, minimum_filter

import approxtree as at
from approxtree import ApproximationTree
from approxtree.cli import main as cli_main
from approxtree.errors import InvalidParameterError, TerrainFormatError
from approxtree.textures import ImageTexture, MultiTexture, TexturePyramid, TopographicShading
from approxtree.textures.bake import bake

#: The texel of the comparisons: the land use's own 10 m cell, over the DEM's grid.
TEXEL = 10.0


def _landuse_rgba(landuse: Path) -> tuple[np.ndarray, Affine, object, np.ndarray]:
    """(4, rows, cols) RGBA of the land use through its colour table (nodata transparent),
    its transform, CRS and (rows, cols) classes."""
    with rasterio.open(landuse) as ds:
        classes = ds.read(1)
        table = ds.colormap(1)
        transform, crs = ds.transform, ds.crs
    lut = np.zeros((256, 4), dtype=np.uint8)
    for k, c in table.items():
        lut[k] = c
    rgba = np.ascontiguousarray(np.moveaxis(lut[classes], -1, 0))
    rgba[3] = np.where(classes == 255, 0, 255)
    rgba[:3, classes == 255] = 0
    return rgba, transform, crs, classes


def _write(path: Path, planes: np.ndarray, transform, crs, **extra) -> Path:
    """Write (bands, rows, cols) uint8 planes as a GeoTIFF; the rest as rasterio profile keys."""
    profile = {
        "driver": "GTiff",
        "width": planes.shape[2],
        "height": planes.shape[1],
        "count": planes.shape[0],
        "dtype": "uint8",
        "transform": transform,
        "crs": crs,
        **extra,
    }
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(planes)
    return path


@pytest.fixture(scope="module")
def nc(data_dir) -> dict:
    """The NC DEM, land use, and the land use as an RGBA image in EPSG:4326."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    landuse = data_file(data_dir, "nc/landuse_r.tif")
    return {"dem": dem, "landuse": landuse}


@pytest.fixture(scope="module")
def rgba_4326(nc, tmp_path_factory) -> Path:
    """The NC land use in its legend's colours, RGBA, warped (nearest) to EPSG:4326."""
    rgba, transform, crs, classes = _landuse_rgba(nc["landuse"])
    with rasterio.open(nc["landuse"]) as ds:
        bounds = ds.bounds
    dst, w, h = calculate_default_transform(
        crs, "EPSG:4326", classes.shape[1], classes.shape[0], *bounds
    )
    out = np.zeros((4, h, w), dtype=np.uint8)
    reproject(
        rgba,
        out,
        src_transform=transform,
        src_crs=crs,
        dst_transform=dst,
        dst_crs="EPSG:4326",
        resampling=Resampling.nearest,
    )
    path = tmp_path_factory.mktemp("image") / "landuse_4326.tif"
    return _write(path, out, dst, "EPSG:4326", photometric="RGB", alpha="YES")


def _dem_lattice(dem: Path) -> tuple[Affine, tuple[int, int], str]:
    """The DEM's extent at TEXEL: transform, (rows, cols), CRS."""
    with rasterio.open(dem) as ds:
        t, crs = ds.transform, ds.crs.to_string()
        rows = round(ds.height * abs(t.e) / TEXEL)
        cols = round(ds.width * t.a / TEXEL)
    return Affine(TEXEL, 0, t.c, 0, -TEXEL, t.f), (rows, cols), crs


def test_level0_matches_gdalwarp(nc, rgba_4326, tmp_path):
    """bake --image of an EPSG:4326 RGBA image over the EPSG:32119 DEM writes a level 0 equal
    to `gdalwarp -r bilinear` of the image onto the same grid: alpha exactly, colour within 1
    (the CLI's GDAL and rasterio's may differ in the last bit of a bilinear weight)."""
    gdalwarp = shutil.which("gdalwarp")
    if gdalwarp is None:
        pytest.skip("gdalwarp is not installed")
    out = tmp_path / "tex"
    res = CliRunner().invoke(
        cli_main,
        [
            *("bake", str(nc["dem"]), "--image", str(rgba_4326), "--shading", "none"),
            *("--texel", str(TEXEL), "--out", str(out), "--quiet"),
        ],
    )
    assert res.exit_code == 0, res.output
    transform, (rows, cols), crs = _dem_lattice(nc["dem"])
    ref = tmp_path / "gdalwarp.tif"
    x0, y1 = transform.c, transform.f
    x1, y0 = x0 + cols * TEXEL, y1 - rows * TEXEL
    subprocess.run(
        [
            *(gdalwarp, "-q", "-r", "bilinear", "-t_srs", crs),
            *("-te", str(x0), str(y0), str(x1), str(y1), "-ts", str(cols), str(rows)),
            *(str(rgba_4326), str(ref)),
        ],
        check=True,
    )
    with rasterio.open(ref) as ds:
        want = np.moveaxis(ds.read(), 0, -1).astype(np.int64)
    got = TexturePyramid(out).level(0).astype(np.int64)
    assert got.shape == want.shape
    assert np.array_equal(got[..., 3], want[..., 3])
    opaque = want[..., 3] > 0
    assert opaque.mean() > 0.9
    diff = np.abs(got - want)[opaque][:, :3]
    print(f"max colour difference vs gdalwarp: {diff.max()} ({(diff > 0).mean():.4%} of texels)")
    assert diff.max() <= 1


def test_paletted_image_takes_its_colour_table(nc, tmp_path):
    """A paletted image on its own grid (the land use at its 10 m cells) is sampled nearest
    and looked up in its colour table: level 0 is exactly the table's colours, nodata
    transparent."""
    rgba, _, _, _ = _landuse_rgba(nc["landuse"])
    result = bake(
        at.open_terrain(nc["dem"]), tmp_path / "tex", shading=None, images=[nc["landuse"]]
    )
    assert result.layers == ["image:landuse_r.tif"]
    got = result.pyramid.level(0)
    assert np.array_equal(np.moveaxis(got, -1, 0), rgba)


def test_rgb_nodata_and_grey_images(nc, tmp_path):
    """An RGB image's nodata value and a grey image's mask band make those texels
    transparent; a grey image drapes with R = G = B."""
    rgba, transform, crs, classes = _landuse_rgba(nc["landuse"])
    rgb = _write(tmp_path / "rgb.tif", rgba[:3], transform, crs, nodata=0, photometric="RGB")
    grey = tmp_path / "grey.tif"
    with rasterio.open(
        grey, "w", driver="GTiff", width=rgba.shape[2], height=rgba.shape[1], count=1,
        dtype="uint8", transform=transform, crs=crs,
    ) as ds:  # fmt: skip
        ds.write(rgba[1], 1)
        ds.write_mask(rgba[3])
    terrain = at.open_terrain(nc["dem"])
    for path, colour in ((rgb, rgba[:3]), (grey, np.broadcast_to(rgba[1], rgba[:3].shape))):
        level = bake(terrain, tmp_path / path.stem, shading=None, images=[path]).pyramid.level(0)
        level = np.moveaxis(level, -1, 0)
        # Nodata (class 255, written as black / masked) is transparent; the rest as given.
        assert np.array_equal(level[3] == 0, classes == 255)
        assert np.array_equal(level[:3, classes != 255], colour[:, classes != 255])


def test_layers_stack_in_order(nc, rgba_4326, tmp_path):
    """Images, thematic layer and shading stack in that order (the layers bake reports): the
    thematic layer covers the image where it is valid, the shading blends with both, and the
    streamed blend of an image and a shading equals the whole-array one."""
    terrain = at.open_terrain(nc["dem"])
    transform, shape, crs = _dem_lattice(nc["dem"])
    image = ImageTexture(rgba_4326, transform, shape, crs)
    result = bake(
        terrain,
        tmp_path / "tex",
        shading="topographic",
        images=[rgba_4326],
        thematic=nc["landuse"],
        texel_size=TEXEL,
        gl=False,
        max_texture_size=4096,
    )
    assert result.layers == [
        "image:landuse_4326.tif",
        "thematic:landuse_r.tif",
        "shading:topographic",
    ]
    level = result.pyramid.level(0)
    # The softened land use over the image, then shaded: not the image's raw colours.
    raw = image.rgba()
    opaque = (raw[..., 3] == 255) & (level[..., 3] == 255)
    assert np.abs(level[opaque, :3].astype(int) - raw[opaque, :3]).mean() > 10
    shading = TopographicShading(terrain)
    blended = MultiTexture([image, _on(shading, transform, shape, terrain)], ["multiply"])
    streamed = np.concatenate([np.moveaxis(s, 0, -1) for s in blended.band_strips(100)])
    assert np.array_equal(streamed, blended.rgba())


def _on(shading, transform, shape, terrain):
    """The topographic shading of ``terrain`` resampled onto a lattice (as bake does)."""
    from approxtree.textures.bake import _resample_heights

    return TopographicShading(_resample_heights(terrain, transform, shape))


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the render test of this module."""
    from approxtree.render.context import create_context

    ctx = create_context()
    yield ctx
    ctx.release()


def test_rendered_frame_shows_the_image_where_it_belongs(gl_context, nc, rgba_4326, tmp_path):
    """A decal render of the EPSG:4326 image baked over the DEM shows, at pixels inside
    uniform land-use patches, the colour of the land-use class at that pixel's map x, y."""
    from approxtree.render import Camera, Cut, Engine, Style

    tree = ApproximationTree.build(at.open_terrain(nc["dem"]), epsilon=1.0, progress=False)
    result = bake(tree.terrain, tmp_path, shading=None, images=[rgba_4326], max_texture_size=1024)
    _, _, _, classes = _landuse_rgba(nc["landuse"])
    with rasterio.open(nc["landuse"]) as ds:
        inv = ~ds.transform
        table = ds.colormap(1)
    lut = np.zeros((256, 3), dtype=np.int64)
    for k, c in table.items():
        lut[k] = c[:3]
    # Texels whose 17 × 17 neighbourhood holds one class: far from every class border.
    uniform = maximum_filter(classes, 17) == minimum_filter(classes, 17)
    c = tree.terrain.domain.center
    cam = Camera.look_at((c[0] + 1000, c[1] - 500, 4000), (c[0] + 1000, c[1] - 499, 0), fov=45)
    with Engine(tree, textures=result.pyramid, context=gl_context, offscreen=True) as eng:
        frame = eng.render(cam, (400, 300), Cut(alpha=1.0, gamma=1.0), style=Style(lighting=False))
        eng.world_positions(frame)
    surface = frame.positions[..., 3] == 1
    xy = frame.positions[surface][:, :2]
    cols = np.floor(inv.a * xy[:, 0] + inv.b * xy[:, 1] + inv.c).astype(int)
    rows = np.floor(inv.d * xy[:, 0] + inv.e * xy[:, 1] + inv.f).astype(int)
    inside = (rows >= 0) & (rows < classes.shape[0]) & (cols >= 0) & (cols < classes.shape[1])
    rows, cols = rows[inside], cols[inside]
    keep = uniform[rows, cols] & (classes[rows, cols] != 255)
    assert keep.sum() > 10_000
    k = classes[rows[keep], cols[keep]]
    drawn = frame.image[surface][inside][keep, :3].astype(np.int64)
    close = np.abs(drawn - lut[k]).max(axis=1) <= 3
    print(f"image colours: {close.mean():.4f} of {keep.sum()} pixels within ±3")
    assert close.mean() > 0.98
    assert len(np.unique(k)) >= 4


def _bake_error(nc, image: Path, tmp_path: Path) -> str:
    """The output of a bake --image that must fail with exit 2."""
    args = ["bake", str(nc["dem"]), "--image", str(image), "--out", str(tmp_path / "tex")]
    res = CliRunner().invoke(cli_main, [*args, "--quiet"])
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), res.output
    return lines[0]


def test_odd_images_give_one_error_line(nc, rgba_4326, tmp_path):
    """An image without a CRS, one that misses the DEM, a 2-band image without alpha and a
    file that is no image each give one clear Error: line and exit 2."""
    rgba, transform, crs, _ = _landuse_rgba(nc["landuse"])
    no_crs = _write(tmp_path / "no_crs.tif", rgba[:3], transform, None)
    assert "has no CRS" in _bake_error(nc, no_crs, tmp_path)
    far = _write(tmp_path / "far.tif", rgba[:3], transform @ Affine.translation(1e5, 0), crs)
    assert "does not overlap" in _bake_error(nc, far, tmp_path)
    two = _write(tmp_path / "two.tif", rgba[:2], transform, crs)
    assert "2 bands" in _bake_error(nc, two, tmp_path)
    text = tmp_path / "notes.tif"
    text.write_text("not an image")
    assert "Cannot read" in _bake_error(nc, text, tmp_path)


def test_image_texture_api_errors(nc, rgba_4326):
    """ImageTexture refuses an unknown resampling and a missing file with ApproxTreeErrors."""
    transform, shape, crs = _dem_lattice(nc["dem"])
    with pytest.raises(InvalidParameterError, match="resampling"):
        ImageTexture(rgba_4326, transform, shape, crs, resampling="sharpest")
    with pytest.raises(TerrainFormatError, match="does not exist"):
        ImageTexture(rgba_4326.with_name("none.tif"), transform, shape, crs)


def _verify(pyramid: Path, image: Path, *extra: str) -> tuple[int, dict]:
    """Exit code and JSON report of ``approxtree verify PYRAMID --image IMAGE``."""
    import json

    res = CliRunner().invoke(
        cli_main, ["verify", str(pyramid), "--image", str(image), *extra, "--json"]
    )
    assert res.exit_code in (0, 1), res.output
    return res.exit_code, json.loads(res.output)


def test_verify_checks_every_level_against_the_image(nc, rgba_4326, tmp_path):
    """verify --image passes a 4-level image pyramid (reprojected RGBA and paletted) with
    every level within 1 of the box-filtered reprojection, and fails one baked from an image
    with a patch repainted, naming the levels."""
    terrain = at.open_terrain(nc["dem"])
    bake(terrain, tmp_path / "rgba", shading=None, images=[rgba_4326], texel_size=5.0,
         max_texture_size=512)  # fmt: skip
    code, report = _verify(tmp_path / "rgba", rgba_4326)
    checks = {c["name"]: c for c in report["checks"]}
    assert code == 0 and checks["image"]["ok"], report
    assert len(report["figures"]["image_max_difference"]) == 4
    assert max(report["figures"]["image_max_difference"]) <= 1
    bake(terrain, tmp_path / "palette", shading=None, images=[nc["landuse"]],
         max_texture_size=512)  # fmt: skip
    code, report = _verify(tmp_path / "palette", nc["landuse"])
    assert code == 0, report
    # The same pyramid against an image with a 100 × 100 pixel patch repainted magenta.
    with rasterio.open(rgba_4326) as ds:
        planes, profile = ds.read(), ds.profile
    planes[:3, 500:600, 500:600] = np.array([255, 0, 255], dtype=np.uint8)[:, None, None]
    other = tmp_path / "repainted.tif"
    with rasterio.open(other, "w", **profile) as ds:
        ds.write(planes)
    code, report = _verify(tmp_path / "rgba", other)
    checks = {c["name"]: c for c in report["checks"]}
    assert code == 1 and not checks["image"]["ok"]
    failed = {o["address"].split(" texel")[0] for o in checks["image"]["offenders"]}
    assert {"level 0", "level 3"} <= failed, failed


#: The quadrant image's colours, by quadrant (east of the DEM's centre, north of it).
QUADRANTS = {
    (0, 0): (220, 30, 30),
    (1, 0): (30, 200, 60),
    (0, 1): (40, 60, 220),
    (1, 1): (230, 210, 40),
}
#: Points this near (degrees, ~300 m) to a quadrant border are left out of the comparisons.
BORDER = 0.003


class Quadrants:
    """An RGB image in EPSG:4326 over the NC DEM, one colour per quadrant (split at the DEM's
    centre in longitude and latitude), baked with ``bake --image``; the NC tree as a store."""

    def __init__(self, dem: Path, work: Path) -> None:
        from pyproj import Transformer

        self.terrain = at.open_terrain(dem)
        d = self.terrain.domain
        self.to_lonlat = Transformer.from_crs("EPSG:32119", "EPSG:4326", always_xy=True)
        lon, lat = self.to_lonlat.transform(
            [d.xmin, d.xmax, d.xmin, d.xmax], [d.ymin, d.ymin, d.ymax, d.ymax]
        )
        self.centre = self.to_lonlat.transform(*d.center)
        west, east = min(lon) - 0.01, max(lon) + 0.01
        south, north = min(lat) - 0.01, max(lat) + 0.01
        n = 400
        transform = Affine((east - west) / n, 0, west, 0, -(north - south) / n, north)
        lons = west + (np.arange(n) + 0.5) * transform.a
        lats = north + (np.arange(n) + 0.5) * transform.e
        quadrant = (lons[None, :] >= self.centre[0]) + 2 * (lats[:, None] >= self.centre[1])
        rgb = np.array(list(QUADRANTS.values()), dtype=np.uint8)[quadrant]
        image = _write(
            work / "quadrants.tif", np.moveaxis(rgb, -1, 0), transform, "EPSG:4326",
            photometric="RGB",
        )  # fmt: skip
        self.pyramid = work / "tex"
        res = CliRunner().invoke(
            cli_main,
            [
                *("bake", str(dem), "--image", str(image), "--shading", "none"),
                *("--max-texture-size", "512", "--out", str(self.pyramid), "--quiet"),
            ],
        )
        assert res.exit_code == 0, res.output
        self.tree = ApproximationTree.build(self.terrain, epsilon=1.0, progress=False)
        self.store = work / "nc.zarr"
        self.tree.save(self.store)
        # A known point per quadrant: half-way between the domain's centre and its corner.
        cx, cy = d.center
        self.points = {
            q: ((d.xmin + cx) / 2 if q[0] == 0 else (cx + d.xmax) / 2,
                (d.ymin + cy) / 2 if q[1] == 0 else (cy + d.ymax) / 2)
            for q in QUADRANTS
        }  # fmt: skip

    def quadrant_of(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(n,) int index into QUADRANTS of world points (n,) x, y; −1 near a border."""
        lon, lat = self.to_lonlat.transform(np.asarray(x), np.asarray(y))
        lon, lat = np.asarray(lon) - self.centre[0], np.asarray(lat) - self.centre[1]
        index = (lon >= 0) + 2 * (lat >= 0)
        return np.where((np.abs(lon) > BORDER) & (np.abs(lat) > BORDER), index, -1)


@pytest.fixture(scope="module")
def quadrants(nc, tmp_path_factory) -> Quadrants:
    """The quadrant image baked over the NC DEM (``Quadrants``)."""
    return Quadrants(nc["dem"], tmp_path_factory.mktemp("quadrants"))


def _close(rgb: np.ndarray, quadrant) -> np.ndarray:
    """(...) bool: which of (..., 3+) pixels are within 3 of the quadrant's colour."""
    return np.abs(rgb[..., :3].astype(np.int64) - QUADRANTS[quadrant]).max(axis=-1) <= 3


def test_viewer_frames_show_the_image_at_known_points(quadrants, tmp_path):
    """view --textures of a bake --image pyramid (Xvfb, decal): looking straight down on each
    quadrant's known point, the frame's centre has that quadrant's colour."""
    from map_checks import view_keyframes

    script = [
        {"eye": [x, y - 1.0, 2000.0], "target": [x, y, 0.0], "frames": 3}
        for x, y in quadrants.points.values()
    ]
    args = ["view", str(quadrants.store), "--textures", str(quadrants.pyramid)]
    shots = view_keyframes(tmp_path, args, script)
    for shot, q in zip(shots, QUADRANTS, strict=True):
        assert _close(shot[50:70, 70:90], q).all(), (q, shot[60, 80])


def _hue_quadrant(rgb: np.ndarray) -> np.ndarray:
    """(n,) index into QUADRANTS of the colour nearest in hue (direction in RGB, so shading
    that scales a colour keeps it) to each of (n, 3) pixels."""
    colours = np.array(list(QUADRANTS.values()), dtype=np.float64)
    colours /= np.linalg.norm(colours, axis=1, keepdims=True)
    rgb = rgb.astype(np.float64)
    rgb /= np.maximum(np.linalg.norm(rgb, axis=1, keepdims=True), 1e-9)
    return np.argmax(rgb @ colours.T, axis=1)


def test_notebook_widget_frame_shows_the_image(quadrants):
    """TerrainWidget(textures=the bake --image pyramid) draws each pixel of terrain (lit) in
    the hue of the image's quadrant under it, all four quadrants seen."""
    pytest.importorskip("jupyter_rfb")
    from approxtree.notebook import TerrainWidget

    widget = TerrainWidget(quadrants.tree, size=(320, 180), textures=str(quadrants.pyramid))
    try:
        image = widget.get_frame()
        positions = widget.view.engine.world_positions(widget.view.last_frame)
    finally:
        widget.close()
    surface = positions[..., 3] == 1
    xy = positions[surface][:, :2]
    want = quadrants.quadrant_of(xy[:, 0], xy[:, 1])
    keep = want >= 0
    got = _hue_quadrant(image[surface][keep, :3])
    assert keep.sum() > 10_000 and set(want[keep]) == {0, 1, 2, 3}
    assert (got == want[keep]).mean() > 0.99


def test_3dtiles_textures_show_the_image(quadrants, tmp_path):
    """tiles --format 3dtiles --textures (a bake --image pyramid): the texture of every tile
    whose node lies in one quadrant (away from its borders) is that quadrant's colour."""
    import io

    from PIL import Image
    from tiles3d_checks import read_glb

    out = tmp_path / "tileset"
    args = ["tiles", str(quadrants.store), "--format", "3dtiles", "--out", str(out)]
    args += ["--compression", "none"]
    res = CliRunner().invoke(cli_main, [*args, "--textures", str(quadrants.pyramid)])
    assert res.exit_code == 0, res.output
    rects = np.asarray(quadrants.tree.rects, dtype=np.float64)
    checked = set()
    for path in out.rglob("*.glb"):
        glb = read_glb(path)
        r = rects[int(glb["extras"]["node"])]
        corners = quadrants.quadrant_of(r[[0, 2, 0, 2]], r[[1, 1, 3, 3]])
        if corners[0] < 0 or (corners != corners[0]).any():
            continue
        q = list(QUADRANTS)[corners[0]]
        image = np.asarray(Image.open(io.BytesIO(glb["image"])).convert("RGB"))
        assert _close(image, q).mean() > 0.95, (path.name, q)
        checked.add(q)
    assert checked == set(QUADRANTS)


def test_imagery_tiles_show_the_image_at_known_points(quadrants, tmp_path):
    """tiles --format imagery --textures (a bake --image pyramid): at every zoom the pixel at
    each quadrant's known point is opaque and that quadrant's colour."""
    import json

    from map_checks import pixel_at

    out = tmp_path / "imagery"
    args = ["tiles", str(quadrants.store), "--format", "imagery", "--out", str(out)]
    res = CliRunner().invoke(
        cli_main, [*args, "--textures", str(quadrants.pyramid), "--minzoom", "8"]
    )
    assert res.exit_code == 0, res.output
    maxzoom = json.loads((out / "tilejson.json").read_text())["maxzoom"]
    assert maxzoom >= 11
    for q, (x, y) in quadrants.points.items():
        lon, lat = quadrants.to_lonlat.transform(x, y)
        for z in range(8, maxzoom + 1):
            pixel = pixel_at(out, lon, lat, z)
            assert pixel is not None and pixel[3] == 255 and _close(pixel, q), (q, z, pixel)


def test_bake_and_verify_offer_the_same_resamplings():
    """bake --resampling and verify --resampling offer exactly io.warp.RESAMPLINGS (one list)."""
    from approxtree.cli.bake import bake_command
    from approxtree.cli.verify import verify as verify_command
    from approxtree.io.warp import RESAMPLINGS

    for command in (bake_command, verify_command):
        (option,) = [p for p in command.params if p.name == "resampling"]
        assert list(option.type.choices) == list(RESAMPLINGS)


def test_windows_of_any_size_write_the_same_pyramid_files(nc, rgba_4326, tmp_path, monkeypatch):
    """An image baked in the smallest windows (strips of 2 rows, one tile wide), in windows of
    3 tiles and in the default ones writes byte-identical level files and pyramid.json (one
    build id for all)."""
    import uuid

    import approxtree.textures.pyramid as pyramid_module

    fixed = uuid.UUID(int=30)
    monkeypatch.setattr(pyramid_module.uuid, "uuid4", lambda: fixed)
    with rasterio.open(nc["dem"]) as ds:
        t = ds.transform
        shape = (round(ds.height * 3), round(ds.width * 3))
        lattice = Affine(t.a / 3, 0, t.c, 0, t.e / 3, t.f)
        crs = ds.crs.to_string()
    image = ImageTexture(rgba_4326, lattice, shape, crs)
    small = TexturePyramid.build(image, tmp_path / "small", 256, window_bytes=1)
    TexturePyramid.build(image, tmp_path / "three", 256, window_bytes=3 * 512 * 512 * 4)
    default = TexturePyramid.build(image, tmp_path / "default", 256)
    assert len(small) == 4 and small.levels[0].width > 1024
    names = sorted(p.name for p in (tmp_path / "default").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "small").iterdir())
    assert "level3.tif" in names and not any(n.endswith(".raw") for n in names)
    for name in names:
        a, b, c = ((tmp_path / d / name).read_bytes() for d in ("small", "three", "default"))
        assert a == b == c, name
    assert default.level(0)[..., 3].any()
