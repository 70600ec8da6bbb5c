"""The renderer on headless EGL: pictures are checked for cracks, the α bound and content.

GL tests share one EGL context (fixture ``gl_context``). Where EGL is missing they fail with
the ContextUnavailableError message naming the packages to install; they never skip.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import binary_erosion

from approxtree import ApproximationTree, ContextUnavailableError, InvalidParameterError
from approxtree.datasets import fractal_terrain, sample_terrain
from approxtree.glsl import ShaderError, create_program, load_source, shader_dir
from approxtree.render import Camera, Cut, Engine, Style, overview_camera
from approxtree.render.context import create_context
from approxtree.render.frame import STAT_KEYS
from approxtree.render.gpu_cache import GpuCache


@pytest.fixture(scope="session")
def gl_context():
    """One headless EGL context for every GL test (released at the end of the session)."""
    ctx = create_context()  # raises ContextUnavailableError with the install hint
    yield ctx
    ctx.release()


@pytest.fixture(scope="module")
def fractal_tree() -> ApproximationTree:
    """A 257² fractal with exact leaves (ε = 0), so drawn leaves never add error."""
    terrain = fractal_terrain(257, seed=5, relief=300.0)
    return ApproximationTree.build(terrain, epsilon=0.0, max_points=17 * 17, progress=False)


@pytest.fixture(scope="module")
def sample_tree() -> ApproximationTree:
    """The sample terrain (EPSG:4326) with the default build."""
    return ApproximationTree.build(sample_terrain(), epsilon=1.0, progress=False)


@pytest.fixture()
def engine(gl_context, fractal_tree):
    """An offscreen engine on the shared context."""
    eng = Engine(fractal_tree, context=gl_context, offscreen=True)
    yield eng
    eng.release()


def oblique_view(tree) -> Camera:
    c = tree.terrain.domain.center
    return Camera.look_at((c[0] - 300, c[1] - 1400, 1600), (c[0], c[1], 0), fov=60)


def holes_in_footprint(gl_context, tree, skirts: bool) -> tuple[int, int, int]:
    """(background pixels inside the footprint, footprint pixels, resolution levels drawn)."""
    eng = Engine(tree, context=gl_context, offscreen=True, skirts=skirts)
    try:
        cam = oblique_view(tree)
        # The unsimplified terrain shares every border vertex: its coverage is the footprint.
        full = eng.render(cam, (400, 400), Cut(full_resolution=True))
        lod = eng.render(cam, (400, 400), Cut(alpha=1.0, gamma=math.inf))
        levels = len(set(tree.levels[lod.selection.nodes].tolist()))
    finally:
        eng.release()
    inner = binary_erosion(full.image[..., 3] > 0, iterations=2)
    holes = inner & (lod.image[..., 3] == 0)
    return int(holes.sum()), int(inner.sum()), levels


def test_no_cracks_between_patches_of_mixed_resolution(gl_context, fractal_tree):
    """Seen from above with patches of several levels, no background pixel shows inside the
    terrain's footprint — and without skirts the same view does show cracks."""
    holes, footprint, levels = holes_in_footprint(gl_context, fractal_tree, skirts=True)
    assert levels >= 2 and footprint > 50_000
    assert holes == 0
    holes_without, _, _ = holes_in_footprint(gl_context, fractal_tree, skirts=False)
    assert holes_without > 0


@pytest.mark.parametrize(
    ("view", "alpha"),
    [("oblique", 1.0), ("oblique", 2.0), ("oblique", 4.0), ("overhead", 1.0), ("overhead", 2.0)],
)
def test_screen_error_within_alpha(engine, fractal_tree, view, alpha):
    """For every covered surface pixel, (x, y, z) and (x, y, h_T(x, y)) project at most
    alpha + 1 px apart (1 px of rasterization slack); prints the largest distance.

    overhead: the eye straight above the terrain, where the vertical segment at the nearest
    point of a box is seen end-on (the nadir bound of visual_error.py must refine there)."""
    terrain = fractal_tree.terrain
    c = terrain.domain.center
    if view == "oblique":
        cam = Camera.look_at((c[0] - 800, c[1] - 2500, 900), (c[0], c[1], 100), fov=60)
    else:
        top = fractal_tree.bboxes[0][5]
        cam = Camera.look_at((c[0], c[1] - 300, top + 2000), (c[0], c[1] + 600, 0.0), fov=60)
    frame = engine.render(cam, (480, 320), Cut(alpha=alpha, gamma=math.inf))
    engine.world_positions(frame)
    # The cut must hold simplified patches, or the test proves nothing.
    assert (fractal_tree.errors[frame.selection.nodes] > 0).sum() >= 5
    pos = frame.positions
    surface = pos[..., 3] > 0.5  # skirt fragments (0) and background (−1) left out
    assert surface.sum() > 10_000
    p = pos[surface][:, :3]
    q = p.copy()
    q[:, 2] = terrain.height_at(p[:, 0], p[:, 1])
    a, _ = frame.frame_state.world_to_pixels(p)
    b, _ = frame.frame_state.world_to_pixels(q)
    dist = np.hypot(*(a - b).T)
    finite = np.isfinite(dist)
    assert finite.mean() > 0.999
    largest = float(dist[finite].max())
    print(f"{view} alpha = {alpha}: largest screen error {largest:.3f} px over {finite.sum()} px")
    assert largest <= alpha + 1.0
    assert frame.stats["max_alpha"] <= alpha


def test_image_covers_terrain_with_varied_shading(gl_context, sample_tree):
    """The overview of the sample terrain covers the image centre, is shaded (not flat) and
    leaves alpha 0 (transparent black) wherever no terrain is drawn."""
    with Engine(sample_tree, context=gl_context, offscreen=True) as eng:
        cam = overview_camera(sample_tree.bboxes[0], eng.scale)
        frame = eng.render(cam, (320, 240), Cut(alpha=1.0, gamma=2.0))
    img = frame.image
    assert img.shape == (240, 320, 4) and img.dtype == np.uint8
    covered = img[..., 3] > 0
    assert 0.05 < covered.mean() < 0.9
    assert covered[120, 160]
    ys, xs = np.nonzero(covered)
    assert abs(xs.mean() - 160) < 40 and abs(ys.mean() - 120) < 40
    assert set(np.unique(img[..., 3]).tolist()) == {0, 255}
    assert not img[~covered].any()
    lum = img[covered][:, :3].astype(float).mean(axis=1)
    assert lum.std() > 10.0
    assert set(frame.stats) == set(STAT_KEYS)
    assert frame.stats["patches"] == len(frame.selection.nodes) > 0


def test_wireframe_differs(engine, fractal_tree):
    """The wireframe picture differs from the filled one over a large part of the terrain."""
    cam = oblique_view(fractal_tree)
    filled = engine.render(cam, (200, 200), Cut(alpha=2.0))
    wire = engine.render(cam, (200, 200), Cut(alpha=2.0), style=Style(wireframe=True))
    differ = np.any(filled.image != wire.image, axis=-1)
    assert differ.mean() > 0.2
    assert wire.stats["triangles"] == filled.stats["triangles"]


def test_full_resolution_draws_more_triangles(engine, fractal_tree):
    """--full-resolution draws every data cell (2 triangles each); the cut draws fewer."""
    cam = overview_camera(fractal_tree.bboxes[0], engine.scale)
    full = engine.render(cam, (200, 150), Cut(full_resolution=True))
    lod = engine.render(cam, (200, 150), Cut(alpha=1.0, gamma=math.inf))
    assert full.stats["triangles"] == 2 * 256 * 256
    assert lod.stats["triangles"] < full.stats["triangles"] / 4


def test_embedded_engine_draws_into_host_framebuffer(gl_context, fractal_tree):
    """An engine given the host's context draws into the framebuffer the host has bound;
    the host's pixels equal the offscreen picture of the same view."""
    size = (160, 120)
    cam = oblique_view(fractal_tree)
    color = gl_context.renderbuffer(size, 4)
    depth = gl_context.depth_renderbuffer(size)
    host_fbo = gl_context.framebuffer(color_attachments=[color], depth_attachment=depth)
    try:
        with Engine(fractal_tree, context=gl_context) as eng:
            host_fbo.use()
            host_fbo.clear(0.0, 0.0, 1.0, 1.0)
            frame = eng.render(cam, size, Cut(alpha=2.0))
            assert frame.image is None
            host = np.frombuffer(host_fbo.read(components=4), np.uint8).reshape(120, 160, 4)
            eng.render(cam, size, Cut(alpha=2.0))
            reference = eng.renderer.read_image(gl_context.fbo, size)
        with Engine(fractal_tree, context=gl_context, offscreen=True) as off:
            offscreen = off.render(cam, size, Cut(alpha=2.0)).image
        assert (host[..., 3] > 0).mean() > 0.3
        assert np.array_equal(host[::-1], offscreen)
        assert np.array_equal(reference, offscreen)
    finally:
        for obj in (host_fbo, color, depth):
            obj.release()


def test_gpu_cache_evicts_least_recently_used(gl_context):
    """Under a byte budget of about two entries the least recently used entry goes first."""
    tri = np.array([[0, 1, 2]], dtype=np.uint32)

    def mesh():
        return np.zeros((3, 4), np.float32), tri

    cache = GpuCache(gl_context, budget_bytes=2 * (48 + 12) + 10)
    try:
        cache.get("a", mesh)
        cache.get("b", mesh)
        cache.get("a", mesh)  # touch a: b is now the least recently used
        cache.get("c", mesh)
        assert cache.keys() == ["a", "c"]
        assert cache.evictions == 1 and cache.nbytes == 2 * 60
    finally:
        cache.release()
    assert len(cache) == 0 and cache.nbytes == 0


def test_small_cache_budget_still_draws_the_whole_frame(gl_context, fractal_tree):
    """With a budget far below one frame's meshes the frame is complete and memory bounded."""
    cam = oblique_view(fractal_tree)
    with Engine(fractal_tree, context=gl_context, offscreen=True) as big:
        expected = big.render(cam, (400, 400), Cut(alpha=1.0, gamma=math.inf))
    with Engine(fractal_tree, context=gl_context, offscreen=True, cache_bytes=200_000) as small:
        frame = small.render(cam, (400, 400), Cut(alpha=1.0, gamma=math.inf))
        assert small.cache.evictions > 0
        assert frame.stats["gpu_bytes"] <= 200_000 + 100_000
    assert expected.stats["gpu_bytes"] > 1_000_000
    assert np.array_equal(frame.image, expected.image)


def test_release_frees_everything(gl_context, fractal_tree):
    """release() empties the cache, frees programs and buffers, keeps the host's context
    usable, and a released engine refuses to render."""
    eng = Engine(fractal_tree, context=gl_context, offscreen=True)
    eng.render(oblique_view(fractal_tree), (64, 64), Cut(alpha=2.0))
    assert len(eng.cache) > 0
    eng.release()
    assert eng.released and len(eng.cache) == 0 and eng.cache.nbytes == 0
    eng.release()  # twice is harmless
    with pytest.raises(InvalidParameterError, match="released"):
        eng.render(oblique_view(fractal_tree), (64, 64))
    buf = gl_context.buffer(reserve=16)  # the shared context still works
    buf.release()


def test_empty_frames_for_cameras_that_see_no_terrain(engine, fractal_tree):
    """Looking away or from inside the ground gives a fully transparent frame, not an error."""
    c = fractal_tree.terrain.domain.center
    away = Camera.look_at((c[0], c[1], 2000), (c[0], c[1], 5000), fov=60)
    under = Camera.look_at((c[0], c[1], -50), (c[0] + 100, c[1], 0), fov=60)
    for cam in (away, under):
        frame = engine.render(cam, (64, 48))
        assert frame.stats["patches"] == 0 and frame.stats["triangles"] == 0
        assert not frame.image.any()


def test_bad_inputs_raise_clear_errors(engine, fractal_tree):
    """Zero or huge viewports, alpha <= 0 and non-finite cameras raise InvalidParameterError."""
    cam = oblique_view(fractal_tree)
    for size in ((0, 10), (10, 0), (10**6, 10)):
        with pytest.raises(InvalidParameterError, match="size"):
            engine.render(cam, size)
    for alpha in (0.0, -2.0, math.nan):
        with pytest.raises(InvalidParameterError, match="alpha"):
            engine.render(cam, (32, 32), Cut(alpha=alpha))
    with pytest.raises(InvalidParameterError, match="finite"):
        Camera.look_at((math.inf, 0, 0), (0, 0, 0))
    with pytest.raises(InvalidParameterError, match="TexturePyramid"):
        Engine(fractal_tree, textures=object(), context=engine.ctx)


def test_missing_egl_names_the_packages(monkeypatch):
    """Without EGL the error is a ContextUnavailableError naming the packages to install."""
    import moderngl

    def fail(**kwargs):
        raise RuntimeError("libEGL.so.1: cannot open shared object file")

    monkeypatch.setattr(moderngl, "create_standalone_context", fail)
    with pytest.raises(ContextUnavailableError, match="libegl1 libgl1-mesa-dri"):
        create_context()


def test_shader_loader_injects_stage_and_line(tmp_path, gl_context):
    """The loader checks #version, injects the stage define and #line so a compile error
    points at the real file line, resolves includes and stops include cycles."""
    src = load_source("terrain")
    vs = src.stages["VERTEX_SHADER"]
    assert vs.splitlines()[:3] == ["#version 330 core", "#define VERTEX_SHADER", "#line 2 0"]
    assert "hypsometric" in src.stages["FRAGMENT_SHADER"]
    assert (shader_dir() / "terrain.glsl").is_file()

    (tmp_path / "noversion.glsl").write_text("void main() {}\n")
    with pytest.raises(ShaderError, match="#version"):
        load_source("noversion", tmp_path)
    (tmp_path / "loop.glsl").write_text('#version 330 core\n#include "loop.glsl"\n')
    with pytest.raises(ShaderError, match="deeper"):
        load_source("loop", tmp_path)
    broken = (
        "#version 330 core\n#if defined VERTEX_SHADER\nvoid main() { gl_Position = vec4(0); }\n"
        "#elif defined FRAGMENT_SHADER\nout vec4 c;\nvoid main() { c = undefined_name; }\n#endif\n"
    )
    (tmp_path / "broken.glsl").write_text(broken)
    with pytest.raises(ShaderError, match=r"0:6"):
        create_program(gl_context, "broken", tmp_path)


def test_cli_render_writes_rgba_png_and_stats(tmp_path, fractal_tree):
    """`approxtree render --json` writes an RGBA PNG (with --background transparent, alpha 0
    off the terrain; opaque sky by default) and prints
    the frame's stats; --eye/--target, --wireframe and --full-resolution are honoured."""
    import json

    from click.testing import CliRunner
    from PIL import Image

    from approxtree.cli import main

    tree_file = tmp_path / "t.zarr"
    fractal_tree.save(tree_file)
    png = tmp_path / "r.png"
    runner = CliRunner()
    # The default background is the sky (opaque, issue 17); transparent stays available.
    base = ["render", str(tree_file), "--out", str(png), "--size", "160x120", "--json"]
    res = runner.invoke(main, [*base, "--background", "transparent"])
    assert res.exit_code == 0, res.output
    stats = json.loads(res.output)
    assert set(stats) == {*STAT_KEYS, "image"}
    img = np.asarray(Image.open(png))
    assert img.shape == (120, 160, 4)
    assert (img[..., 3] == 0).any() and (img[..., 3] == 255).any()
    assert runner.invoke(main, base).exit_code == 0
    assert (np.asarray(Image.open(png))[..., 3] == 255).all()
    c = fractal_tree.terrain.domain.center
    args = [
        "render",
        str(tree_file),
        "--out",
        str(png),
        "--size",
        "96x64",
        "--json",
        "--eye",
        f"{c[0]},{c[1] - 1500},{1500}",
        "--target",
        f"{c[0]},{c[1]},0",
    ]
    lod = json.loads(runner.invoke(main, args).output)
    full = json.loads(runner.invoke(main, [*args, "--full-resolution", "--wireframe"]).output)
    assert full["triangles"] > lod["triangles"] > 0
    bad = runner.invoke(main, ["render", str(tree_file), "--out", str(png), "--size", "0x10"])
    assert bad.exit_code == 2 and "size" in bad.output
    bad = runner.invoke(main, ["render", str(tree_file), "--out", str(png), "--alpha", "-1"])
    assert bad.exit_code == 2 and "alpha" in bad.output


def test_normal_map_in_strips_equals_the_whole_map():
    """The normal map is computed in row strips (bounded memory); each strip's halo rows make
    every texel the one the whole map gives, at strip seams, borders and holes alike."""
    from approxtree.render.normal_map import normal_texels, normals

    rng = np.random.default_rng(0)
    for ny, nx in [(1000, 70), (257, 3), (2, 5), (513, 40)]:
        z = np.cumsum(rng.normal(size=(ny, nx)), axis=0) * 3.0
        z[255:258, 1:3] = np.nan
        xs = np.sort(rng.uniform(0, 1000, nx))
        ys = np.sort(rng.uniform(0, 1000, ny))
        whole = normals(z, xs, ys)[..., :2]
        want = np.rint((whole * 0.5 + 0.5) * 255.0).astype(np.uint8)
        np.testing.assert_array_equal(normal_texels(z, xs, ys), want)
