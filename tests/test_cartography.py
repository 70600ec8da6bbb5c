"""Cartographic pictures (issue 17): tests compute what a picture must show.

- the default camera frames the terrain: its surface covers >= 60 % of a 1280 × 720 image
  (the demo terrain, NC, a SRTM tile);
- the demo image is coloured (hypsometric palette under the baked hillshade), not grey;
- vertical exaggeration raises the silhouette, and the α bound holds on the exaggerated
  terrain (error segments measured on screen);
- the sun's azimuth decides which slopes are lit: the rendered brightness correlates best with
  a hillshade of the same azimuth computed independently with numpy;
- the walls along the terrain's border have the wall colour; the background modes;
- the fixed relief palette ties colours to elevations: no top-of-ramp colour on 150 m hills;
  the default tint spans the terrain's own range;
- a classified lidar cloud's default picture is its ground surface, filling the frame.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file
from PIL import Image

import approxtree as at
from approxtree import ApproximationTree
from approxtree.cli import main as cli_main
from approxtree.datasets import fractal_terrain, sample_terrain
from approxtree.render import Camera, Cut, Engine, FrameState, Style, select
from approxtree.render.context import create_context
from approxtree.render.frame_state import framing_camera
from approxtree.render.style import WALL_COLOUR, Sun
from approxtree.textures.palettes import DEFAULT_PALETTE, PALETTES

SIZE = (1280, 720)


def surface_coverage(engine: Engine, tree) -> float:
    """Fraction of a SIZE image covered by the terrain surface (walls left out) in the
    default framing of the tree."""
    cam = framing_camera(tree.bboxes[0], engine.scale, SIZE)
    frame = engine.render(cam, SIZE, style=Style(background="transparent"))
    engine.world_positions(frame)
    return float((frame.positions[..., 3] == 1).mean())


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for the GL tests of this module."""
    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="module")
def nc_tree(data_dir) -> ApproximationTree:
    terrain = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    return ApproximationTree.build(terrain, epsilon=1.0, progress=False)


@pytest.fixture(scope="module")
def hills_tree() -> ApproximationTree:
    """A fractal terrain of rolling hills (about 50 m to 250 m), 30 m cells."""
    terrain = fractal_terrain(257, seed=3, relief=50.0, cell_size=30.0)
    z = terrain.heights
    heights = 50.0 + 200.0 * (z - np.nanmin(z)) / (np.nanmax(z) - np.nanmin(z))
    return ApproximationTree.build(
        at.Grid(heights, terrain.transform, terrain.crs), epsilon=0.5, progress=False
    )


def test_default_framing_covers_most_of_the_image(gl_context, nc_tree, data_dir):
    """The terrain's surface fills >= 60 % of 1280 × 720 in the default framing, for the
    demo terrain, NC and a whole SRTM tile (1° × 1°, taller than wide); the old overview
    (bounding sphere in the vertical field of view) covered 16 %."""
    srtm = at.open_terrain(data_file(data_dir, "srtm/N44W072.hgt"))
    trees = {
        "demo": ApproximationTree.build(sample_terrain(), epsilon=2.0, progress=False),
        "nc": nc_tree,
        "srtm": ApproximationTree.build(srtm, epsilon=10.0, progress=False),
    }
    for name, tree in trees.items():
        with Engine(tree, context=gl_context, offscreen=True) as eng:
            cover = surface_coverage(eng, tree)
        print(f"{name}: surface covers {cover:.1%} of the frame")
        assert cover >= 0.60, (name, cover)


def test_a_lidar_cloud_default_picture_is_its_ground_filling_the_frame(data_dir, tmp_path):
    """render of a classified LAZ: its ground points (class 2), said in one Note line (none
    with -q), gaps filled, the surface covering >= 60 % of the frame (34 % before: every
    point, trees as needles, sky through its gaps); --all-points keeps every point."""
    laz = str(data_file(data_dir, "lidar/autzen_trim.laz"))
    runner = CliRunner()
    png = tmp_path / "autzen.png"
    base = ["render", laz, "--background", "transparent", "--json"]
    res = runner.invoke(cli_main, [*base, "--out", str(png)])
    assert res.exit_code == 0, res.output
    assert res.stderr == (
        "Note: autzen_trim.laz: drawing its 26,107 ground points (classification 2) of "
        "110,000, gaps filled; --all-points draws every point.\n"
    )
    cover = float((np.asarray(Image.open(png))[..., 3] > 0).mean())
    print(f"autzen: terrain covers {cover:.1%} of the frame")
    assert cover >= 0.60
    quiet = runner.invoke(cli_main, [*base, "--out", str(tmp_path / "q.png"), "-q"])
    assert quiet.exit_code == 0 and quiet.stderr == ""
    res = runner.invoke(cli_main, [*base, "--out", str(tmp_path / "all.png"), "--all-points"])
    assert res.exit_code == 0 and res.stderr == ""
    # Every point: the trees' needles take far more triangles than the ground surface.
    assert json.loads(res.stdout)["triangles"] > 10 * json.loads(quiet.stdout)["triangles"]


def test_cli_demo_is_coloured_and_framed(tmp_path):
    """`approxtree demo` writes a coloured plate (the palette under the baked shading: mean
    chroma of the terrain's pixels well above a grey image's 0) that fills the frame; the
    default background is the sky (opaque, blue above the terrain)."""
    runner = CliRunner()
    out = tmp_path / "demo.zarr"
    res = runner.invoke(cli_main, ["demo", "--out", str(out), "--json"])
    assert res.exit_code == 0, res.output
    img = np.asarray(Image.open(tmp_path / "demo.png")).astype(int)
    assert (img[..., 3] == 255).all()
    top = img[:8, :, :3].reshape(-1, 3).mean(axis=0)
    assert top[2] > top[0] + 40  # sky blue at the top of the image
    png = tmp_path / "t.png"
    textures = str(tmp_path / "demo_textures")
    args = ["render", str(out), "--textures", textures, "--out", str(png)]
    res = runner.invoke(cli_main, [*args, "--background", "transparent"])
    assert res.exit_code == 0, res.output
    img = np.asarray(Image.open(png)).astype(int)
    terrain = img[..., 3] == 255
    assert terrain.mean() >= 0.60
    rgb = img[terrain][:, :3]
    chroma = (rgb.max(axis=1) - rgb.min(axis=1)).mean()
    print(f"demo: coverage {terrain.mean():.1%}, mean chroma {chroma:.1f}")
    assert chroma > 15.0


def silhouette_rows(image: np.ndarray) -> np.ndarray:
    """(w,) the topmost terrain row of every column of an RGBA image (h where none)."""
    drawn = image[..., 3] > 0
    h = image.shape[0]
    return np.where(drawn.any(axis=0), drawn.argmax(axis=0), h)


def test_exaggeration_raises_the_silhouette(gl_context, hills_tree):
    """Seen from ground level (the eye at the local origin's height, which the exaggeration
    leaves in place), exaggerating z by 4 lifts the skyline of the hills by many pixels in
    almost every column; the engine reports the factor."""
    tree = hills_tree
    c = tree.terrain.domain.center
    w = tree.terrain.domain.width
    z0 = float(tree.origin[2])
    cam = Camera.look_at((c[0], c[1] - 1.5 * w, z0), (c[0], c[1], z0), fov=40)
    images = {}
    for k in (1.0, 4.0):
        with Engine(tree, context=gl_context, offscreen=True, exaggeration=k) as eng:
            assert eng.exaggeration == pytest.approx(k)
            images[k] = eng.render(cam, (480, 320), style=Style(background="transparent")).image
    flat, tall = silhouette_rows(images[1.0]), silhouette_rows(images[4.0])
    both = (flat < 320) & (tall < 320)
    assert both.mean() > 0.5
    lift = flat[both] - tall[both]
    print(f"skyline lifted by {np.median(lift):.0f} px (median)")
    assert np.median(lift) >= 10 and (lift >= 0).mean() > 0.95


def test_alpha_bound_holds_on_the_exaggerated_terrain():
    """With z × 3 in the display scale, every on-screen error segment (3 × ε long in display
    units) of a cut at α stays within α and its node's α_N pixels (measured as in
    test_alpha_bound); the largest one shows real error (>= α / 4)."""
    from test_alpha_bound import Dem, screen_errors

    dem = Dem(fractal_terrain(129, seed=5, relief=300.0))
    tree = dem.tree
    box = tree.bboxes[0]
    # Far enough that the cut at α = 1 px is coarser than the leaves.
    target = 0.5 * (box[:3] + box[3:])
    camera = Camera.look_at(target + 4.0 * (dem.frame("oblique").eye - target), target, 45.0)
    for k in (1.0, 3.0):
        scale = dem.scale * np.array([1.0, 1.0, k])
        fs = FrameState.from_camera(camera, (480, 320), box, tree.origin, scale)
        sel = select(tree, fs, alpha=1.0, gamma=math.inf, texels=dem.texels)
        lengths = screen_errors(dem, fs, sel.nodes)
        for a_node, d in zip(sel.alphas, lengths, strict=True):
            assert float(d.max(initial=0.0)) <= a_node + 1e-6
        largest = max(float(d.max(initial=0.0)) for d in lengths)
        print(f"exaggeration {k}: {len(sel.nodes)} nodes, largest error {largest:.3f} px")
        assert 0.25 <= largest <= 1.0 + 1e-6


def numpy_hillshade(z: np.ndarray, cell: float, azimuth: float, altitude: float) -> np.ndarray:
    """gdaldem's Horn hillshade in [0, 1] of heights z (rows north first), cell size."""
    p = np.pad(z, 1, mode="edge")
    a, b, c = p[:-2, :-2], p[:-2, 1:-1], p[:-2, 2:]
    d, f = p[1:-1, :-2], p[1:-1, 2:]
    g, h, i = p[2:, :-2], p[2:, 1:-1], p[2:, 2:]
    dzdx = ((c + 2 * f + i) - (a + 2 * d + g)) / (8 * cell)
    dzdy = ((g + 2 * h + i) - (a + 2 * b + c)) / (8 * cell)  # towards the south
    az, alt = math.radians(azimuth), math.radians(altitude)
    sun = np.array([math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt)])
    n = np.stack([-dzdx, dzdy, np.ones_like(z)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return np.clip(n @ sun, 0.0, 1.0)


def test_sun_azimuth_decides_which_slopes_are_lit(gl_context, hills_tree):
    """Top-down renders lit from 315° and from 135°: each one's brightness correlates with
    the numpy hillshade of its own azimuth (sampled at each pixel's map position) more than
    with the opposite one, and the two renders differ."""
    tree = hills_tree
    grid = tree.terrain
    c = grid.domain.center
    cam = Camera.look_at((c[0], c[1], 15000.0), (c[0], c[1] + 1.0, 0.0), fov=30)
    shades = {az: numpy_hillshade(np.asarray(grid.heights), 30.0, az, 45.0) for az in (315, 135)}
    inv = ~grid.transform
    with Engine(tree, context=gl_context, offscreen=True, palette="grey") as eng:
        for az in (315, 135):
            frame = eng.render(cam, (400, 400), style=Style(sun=Sun(az, 45.0)))
            eng.world_positions(frame)
            surface = frame.positions[..., 3] == 1
            xy = frame.positions[surface][:, :2]
            cols = np.floor(inv.a * xy[:, 0] + inv.c).astype(int)
            rows = np.floor(inv.e * xy[:, 1] + inv.f).astype(int)
            ok = (rows > 0) & (cols > 0) & (rows < grid.shape[0] - 1) & (cols < grid.shape[1] - 1)
            bright = frame.image[surface][ok][:, :3].astype(float).mean(axis=1)
            corr = {
                other: np.corrcoef(bright, s[rows[ok], cols[ok]])[0, 1]
                for other, s in shades.items()
            }
            print(f"sun {az}°: correlation {corr}")
            assert corr[az] > 0.8
            assert corr[az] > corr[(az + 180) % 360] + 0.5


def test_border_walls_have_the_wall_colour(gl_context, nc_tree):
    """In the default overview of NC, the skirt pixels on the terrain's outer border are the
    wall colour lit by the sun (one hue: the RGB ratios of WALL_COLOUR), never the palette's
    green; textured terrain too."""
    tree = nc_tree
    d = tree.terrain.domain
    tol = 1e-4 * d.width
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        cam = framing_camera(tree.bboxes[0], eng.scale, SIZE)
        frame = eng.render(cam, SIZE)
        eng.world_positions(frame)
    pos = frame.positions
    skirt = pos[..., 3] == 0
    on_border = (
        (np.abs(pos[..., 0] - d.xmin) < tol)
        | (np.abs(pos[..., 0] - d.xmax) < tol)
        | (np.abs(pos[..., 1] - d.ymin) < tol)
        | (np.abs(pos[..., 1] - d.ymax) < tol)
    )
    walls = skirt & on_border
    assert walls.sum() > 500
    rgb = frame.image[walls][:, :3].astype(float)
    wall = np.array(WALL_COLOUR) * 255.0
    # Every wall pixel is the wall colour times one light factor in [0.6, 1].
    factor = rgb.sum(axis=1) / wall.sum()
    assert ((factor > 0.55) & (factor < 1.02)).all()
    assert np.abs(rgb - factor[:, None] * wall).max() <= 3.0


def test_background_modes(gl_context, hills_tree):
    """transparent: alpha 0 off the terrain; sky: opaque, bluer and darker at the top than
    at the bottom; a colour: exactly that colour off the terrain; the terrain is the same."""
    tree = hills_tree
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        cam = framing_camera(tree.bboxes[0], eng.scale, (320, 240))
        clear = eng.render(cam, (320, 240), style=Style(background="transparent")).image
        sky = eng.render(cam, (320, 240), style=Style(background="sky")).image
        red = eng.render(cam, (320, 240), style=Style(background="#ff0000")).image
    off = clear[..., 3] == 0
    assert off.any() and (~off).any()
    assert (sky[..., 3] == 255).all() and (red[..., 3] == 255).all()
    assert (red[off][:, :3] == (255, 0, 0)).all()
    assert np.array_equal(sky[~off], clear[~off]) and np.array_equal(red[~off], clear[~off])
    top, bottom = sky[0, :, :3].astype(int).mean(axis=0), sky[-1, :, :3].astype(int)
    assert off[0].all()
    assert top[2] > top[0] + 60 and top.sum() < sky[off][:, :3].astype(int).sum(axis=1).max()
    del bottom


def test_palette_follows_elevation_not_the_data_range(gl_context, hills_tree):
    """Unlit, seen from above, the 50–250 m hills are drawn in the fixed-elevation relief
    palette's colour at each pixel's elevation (within 4 grey levels); none of them gets the
    palette's top (snow) colour, nor anything near white, which the min/max-stretched ramp
    painted. (relief is asked for by name: the default tint follows the terrain's range.)"""
    tree = hills_tree
    c = tree.terrain.domain.center
    cam = Camera.look_at((c[0], c[1], 15000.0), (c[0], c[1] + 1.0, 0.0), fov=30)
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        eng.set_palette("relief")
        frame = eng.render(cam, (300, 300), style=Style(lighting=False))
        eng.world_positions(frame)
    surface = frame.positions[..., 3] == 1
    z = frame.positions[surface][:, 2]
    rgb = frame.image[surface][:, :3].astype(float)
    expected = PALETTES["relief"].colours(z) * 255.0
    assert np.median(np.abs(rgb - expected)) <= 4.0
    high = z > np.quantile(z, 0.95)
    snow = np.array(PALETTES["relief"].stops[-1][1], dtype=float)
    assert np.linalg.norm(rgb[high] - snow, axis=1).min() > 40.0
    assert (rgb[high].min(axis=1) < 215).all()


def test_default_tint_spans_the_terrain_own_range(gl_context, hills_tree):
    """Unlit, seen from above, the default palette lays its tint over the terrain's own
    min..max: the lowest pixels take its first colour, the highest its last (within 6 grey
    levels), where the fixed relief palette gives 200 m of hills nearly one green."""
    tree = hills_tree
    c = tree.terrain.domain.center
    cam = Camera.look_at((c[0], c[1], 15000.0), (c[0], c[1] + 1.0, 0.0), fov=30)
    # The unsimplified terrain: its lowest and highest points are drawn (a cut's coarser
    # patches need not reach them).
    whole = Cut(full_resolution=True)
    with Engine(tree, context=gl_context, offscreen=True) as eng:
        frame = eng.render(cam, (300, 300), whole, style=Style(lighting=False))
        eng.world_positions(frame)
        eng.set_palette("relief")
        fixed = eng.render(cam, (300, 300), whole, style=Style(lighting=False)).image
    surface = frame.positions[..., 3] == 1
    z = frame.positions[surface][:, 2]
    rgb = frame.image[surface][:, :3].astype(float)
    tint = PALETTES[DEFAULT_PALETTE]
    assert tint.relative
    expected = tint.colours(z, tree.terrain.z_range) * 255.0
    assert np.median(np.abs(rgb - expected)) <= 4.0
    low, high = z < np.quantile(z, 0.001), z > np.quantile(z, 0.999)
    first, last = (np.array(tint.stops[i][1], dtype=float) for i in (0, -1))
    assert np.abs(rgb[low].mean(axis=0) - first).max() <= 6.0
    assert np.abs(rgb[high].mean(axis=0) - last).max() <= 6.0
    # The spread of colours across the terrain: several times the fixed palette's.
    spread = np.ptp(rgb, axis=0).max()
    assert spread > 3 * np.ptp(fixed[surface][:, :3].astype(float), axis=0).max()


def test_land_use_is_softened_and_water_covers_the_streams(data_dir, tmp_path):
    """NC land use baked with its streams in the landclass96 legend: the legend colours are
    quieter than the raw embedded table (lower chroma), the shading stays visible, and no
    stream texel lies on open water (Jordan Lake is drawn over the streams); streams are at
    least two texels wide."""
    from approxtree.textures.bake import OVERLAY_COLOUR, bake

    dem = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    landuse = data_file(data_dir, "nc/landuse_r.tif")
    streams = data_file(data_dir, "nc/streams.shp")
    result = bake(dem, tmp_path / "lu", thematic=landuse, palette="landclass96", overlays=[streams])
    level0 = np.asarray(result.pyramid.level(0)).astype(int)
    import rasterio

    with rasterio.open(landuse) as ds:
        classes = ds.read(1)
        raw = ds.colormap(1)
    assert level0.shape[:2] == classes.shape
    r, g, b, _ = OVERLAY_COLOUR
    stream = (level0[..., 0] == r) & (level0[..., 1] == g) & (level0[..., 2] == b)
    water = classes == 6
    assert water.sum() > 10_000 and stream.sum() > 10_000
    assert not (stream & water).any()
    # Two texels wide: most stream texels have a stream neighbour across the line's width
    # in both x and y directions of the lattice (a one-texel line has it along its run only).
    horiz = stream[:, 1:] & stream[:, :-1]
    vert = stream[1:, :] & stream[:-1, :]
    assert horiz.sum() > 0.5 * stream.sum() and vert.sum() > 0.5 * stream.sum()
    land = ~stream & (classes != 255)
    rgb = level0[land][:, :3]
    chroma = (rgb.max(axis=1) - rgb.min(axis=1)).mean()
    raw_rgb = np.array([raw[int(k)][:3] for k in classes[land]])
    raw_chroma = (raw_rgb.max(axis=1) - raw_rgb.min(axis=1)).mean()
    print(f"chroma: baked {chroma:.0f}, raw table {raw_chroma:.0f}")
    assert chroma < 0.6 * raw_chroma
    assert level0[land][:, 1].std() > 10


def test_cli_refuses_bad_picture_options(tmp_path, hills_tree):
    """Bad palette, sun, background and exaggeration values: one Error line each, exit 2."""
    tree_file = tmp_path / "h.zarr"
    hills_tree.save(tree_file)
    runner = CliRunner()
    base = ["render", str(tree_file), "--out", str(tmp_path / "x.png"), "--size", "64x48"]
    cases = {
        ("--palette", "foo"): "Unknown palette 'foo'",
        ("--sun-altitude", "0"): "Sun altitude must be in (0, 90]",
        ("--background", "blurple"): "Unknown background 'blurple'",
        ("--exaggeration", "-1"): "vertical exaggeration must be a finite number > 0",
    }
    for option, message in cases.items():
        res = runner.invoke(cli_main, [*base, *option])
        assert res.exit_code == 2 and message in res.output, (option, res.output)
        assert res.output.count("Error:") == 1


def test_streams_keep_their_width_on_coarse_pyramid_levels(data_dir, tmp_path):
    """NC streams baked into a 3-level pyramid: every level shows them in the overlay colour
    itself (redrawn at that level's texel size, two texels wide), not faded into the
    averages of level 0, and on a similar share of the level's texels."""
    from approxtree.textures.bake import OVERLAY_COLOUR, bake

    dem = at.open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    streams = data_file(data_dir, "nc/streams.shp")
    result = bake(dem, tmp_path / "s", overlays=[streams], texel_size=10.0, max_texture_size=512)
    assert len(result.pyramid) == 3
    r, g, b, _ = OVERLAY_COLOUR
    shares = []
    for k in range(3):
        lv = np.asarray(result.pyramid.level(k))
        exact = (lv[..., 0] == r) & (lv[..., 1] == g) & (lv[..., 2] == b)
        shares.append(exact.mean())
    print("stream texel share per level:", [f"{s:.3f}" for s in shares])
    assert min(shares) > 0.03
    assert shares[2] >= 0.8 * shares[0]


@pytest.mark.parametrize("azimuth", [0, 45, 90, 135, 180, 225, 270, 315])
def test_framing_camera_from_every_azimuth_looks_from_outside_above(azimuth):
    """From any azimuth the fitted eye lies above the box and outside it, looking down at it
    (a corner behind the eye used to count as fitting: diagonal azimuths put the eye 2 km under
    the NC DEM)."""
    from approxtree.render.frame_state import framing_camera

    box = np.array([630015.0, 215015.0, 55.17, 644985.0, 228485.0, 156.39])
    cam = framing_camera(box, np.ones(3), (640, 360), 45.0, azimuth=azimuth)
    eye, target = np.asarray(cam.eye), np.asarray(cam.target)
    assert np.isfinite(eye).all() and np.isfinite(target).all()
    assert eye[2] > box[5]
    centre = box.reshape(2, 3).mean(axis=0)
    assert np.linalg.norm(eye - centre) > 0.5 * np.linalg.norm(box[3:] - box[:3])
    heading = np.degrees(np.arctan2(eye[0] - target[0], eye[1] - target[1])) % 360
    assert abs((heading - azimuth + 180) % 360 - 180) < 1e-6
