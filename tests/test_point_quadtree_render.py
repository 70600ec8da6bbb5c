"""The point quadtree (seed 003) drawn by the Engine: its per-view LOD mesh leaves no crack in
all-terrain views, keeps every data point within α pixels on screen, reports the usual frame
stats, and is saved, loaded, built, rendered and viewed like any tree."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from atree_writer import write_atree
from click.testing import CliRunner
from conftest import data_file
from matplotlib.tri import LinearTriInterpolator, Triangulation
from test_point_quadtree import areas
from test_render import gl_context  # noqa: F401 (shared GL fixture)

import approxtree as at
from approxtree.cli import main
from approxtree.datasets import fractal_terrain
from approxtree.render import Camera, Cut, Engine
from approxtree.render import point_quadtree_source as source_module
from approxtree.render.frame import STAT_KEYS
from approxtree.render.frustum import boxes_in_frustum
from approxtree.render.lod_cut import LodSelector, node_mesh, pixels_per_radian
from approxtree.render.point_quadtree_source import PointQuadtreeSource
from approxtree.render.selector import SelectionResult
from approxtree.tree.atree import TreeFile
from approxtree.tree.point_quadtree import PointQuadtree

SIZE = (400, 300)
ALPHAS = (1.0, 4.0)


def scattered_cloud() -> at.TINPointSet:
    """30,000 generated points, a third crowded into the middle (leaves of many levels)."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 1000, (30_000, 2))
    xy[:10_000] = 400 + 0.2 * xy[:10_000]
    z = 40 * np.sin(xy[:, 0] / 70) + 30 * np.cos(xy[:, 1] / 50) + rng.normal(0, 1, len(xy))
    return at.TINPointSet(np.column_stack([xy, z]))


@pytest.fixture(scope="module", params=["autzen-ground", "autzen-all", "scattered"])
def quadtree(request, data_dir) -> PointQuadtree:
    """Point quadtrees (δ = 50) of the Autzen ground points, all Autzen points (buildings and
    trees included), and a generated scattered cloud."""
    if request.param == "scattered":
        return PointQuadtree(scattered_cloud(), 50)
    laz = data_file(data_dir, "lidar/autzen_trim.laz")
    return PointQuadtree(at.open_terrain(laz, ground_only=request.param == "autzen-ground"), 50)


def all_terrain_views(q: PointQuadtree) -> dict[str, Camera]:
    """Views that see nothing but terrain: top-down, top-down low, oblique, close-up."""
    d = q.terrain.domain
    (cx, cy), (z0, z1) = d.center, q.terrain.z_range
    w, h = d.width, d.height
    return {
        "top": Camera.look_at((cx, cy, z1 + 0.4 * h), (cx, cy + 1e-3, z0), fov=45),
        "top-low": Camera.look_at(
            (cx + 0.2 * w, cy, z1 + 0.08 * h), (cx + 0.2 * w, cy + 1e-3, z0), fov=60
        ),
        "oblique": Camera.look_at((cx, cy - 0.25 * h, z1 + 0.2 * h), (cx, cy, z0), fov=45),
        "close": Camera.look_at(
            (cx, cy, z1 + 0.02 * h), (cx + 0.03 * w, cy + 0.03 * h, z0), fov=60
        ),
    }


def background_pixels(eng: Engine, q: PointQuadtree) -> tuple[dict[tuple[str, float], int], int]:
    """(background pixels of the LOD frame per (view, α), most node levels in one frame);
    each view is checked to be all terrain at full resolution first."""
    out, levels = {}, 0
    for name, cam in all_terrain_views(q).items():
        full = eng.render(cam, SIZE, Cut(full_resolution=True))
        assert (full.image[..., 3] == 0).sum() == 0, f"view {name} is not all terrain"
        for alpha in ALPHAS:
            lod = eng.render(cam, SIZE, Cut(alpha=alpha))
            assert lod.stats["triangles"] < full.stats["triangles"]
            out[name, alpha] = int((lod.image[..., 3] == 0).sum())
            levels = max(levels, len(set(q.levels[lod.selection.nodes].tolist())))
    return out, levels


def test_engine_draws_the_lod_mesh_without_cracks(gl_context, quadtree):  # noqa: F811
    """Top-down, low, oblique and close-up views, α = 1 and 4: 0 background pixels in every
    all-terrain view, with nodes of several levels on screen."""
    eng = Engine(quadtree, context=gl_context, offscreen=True)
    try:
        assert isinstance(eng.source, PointQuadtreeSource)
        holes, levels = background_pixels(eng, quadtree)
    finally:
        eng.release()
    assert holes == {key: 0 for key in holes}
    assert levels >= 3


def test_an_unrestricted_cut_shows_cracks(gl_context, data_dir, monkeypatch):  # noqa: F811
    """The crack test can fail: without the restriction of the cut (leaves two levels apart
    meet) the same views of all Autzen points show background pixels."""
    laz = data_file(data_dir, "lidar/autzen_trim.laz")
    q = PointQuadtree(at.open_terrain(laz), 50)
    monkeypatch.setattr(LodSelector, "_restrict_rows", lambda self, *args: None)
    eng = Engine(q, context=gl_context, offscreen=True)
    try:
        holes, _ = background_pixels(eng, q)
    finally:
        eng.release()
    assert sum(holes.values()) > 0


def mesh_heights(v: np.ndarray, t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Heights of the mesh (v, t) at xy (k, 2) by matplotlib's interpolator (independent of
    our kernels); zero-area triangles (T-junction fillers, vertical slivers) left out."""
    uxy, first, inverse = np.unique(v[:, :2], axis=0, return_index=True, return_inverse=True)
    tt = inverse.ravel()[t]
    tt = tt[np.abs(areas(uxy, tt)) > 1e-12]
    tri = Triangulation(uxy[:, 0], uxy[:, 1], tt)
    h = LinearTriInterpolator(tri, v[first, 2])(xy[:, 0], xy[:, 1])
    return np.ma.filled(h, np.nan)


@pytest.mark.parametrize("alpha", ALPHAS)
def test_every_data_point_is_drawn_within_alpha_pixels(gl_context, quadtree, alpha):  # noqa: F811
    """For every drawn node and every one of its data points in the image, the projections of
    (x, y, z) and (x, y, h_mesh) are at most α pixels apart; stats say the same."""
    eng = Engine(quadtree, context=gl_context, offscreen=True)
    try:
        frames = [
            eng.render(cam, SIZE, Cut(alpha=alpha)) for cam in all_terrain_views(quadtree).values()
        ]
        cuts_rows = [f.selection.nodes for f in frames]
    finally:
        eng.release()
    worst = 0.0
    for frame, rows in zip(frames, cuts_rows, strict=True):
        assert set(frame.stats) == set(STAT_KEYS)
        assert 0 < frame.stats["max_alpha"] <= alpha
        fs = frame.frame_state
        cut = LodSelector(quadtree).cut(
            fs.eye,
            pixels_per_radian(fs),
            alpha,
            fs.scale,
            boxes_in_frustum(quadtree.bboxes, fs.planes) & quadtree.in_domain,
        )
        np.testing.assert_array_equal(cut.rows[cut.visible], rows)
        for k in np.flatnonzero(cut.visible):
            node = quadtree.node_keys[cut.rows[k]]
            lo, hi = quadtree.point_range(node)
            if hi == lo:
                continue
            pts = quadtree.points[lo:hi]
            v, t = node_mesh(
                quadtree, node, tuple(cut.midpoints[k]), tuple(cut.keep[k]), int(cut.inserted[k])
            )
            h = mesh_heights(v, t, pts[:, :2])
            assert np.isfinite(h).all()
            # Matplotlib interpolates in global coordinates (~6e5 m here): float64 rounding.
            np.testing.assert_allclose(np.abs(pts[:, 2] - h).max(), cut.errors[k], atol=1e-5)
            a, wa = fs.world_to_pixels(pts)
            b, wb = fs.world_to_pixels(np.column_stack([pts[:, :2], h]))
            inside = (wa > 0) & (wb > 0) & (a >= 0).all(axis=1) & (a <= SIZE).all(axis=1)
            if inside.any():
                worst = max(worst, float(np.linalg.norm(a - b, axis=1)[inside].max()))
    assert 0 < worst <= alpha


def test_nothing_is_drawn_outside_the_data_domain(gl_context, data_dir):  # noqa: F811
    """The root square reaches past the Autzen tile on its short (north-south) side: the
    overview frame draws no node outside the domain, and its surface pixels lie within one
    drawn node of it (no extrapolated plateau north of the data)."""
    from approxtree.render import overview_camera

    laz = data_file(data_dir, "lidar/autzen_trim.laz")
    q = PointQuadtree(at.open_terrain(laz, ground_only=True), 50)
    assert not q.in_domain.all()
    eng = Engine(q, context=gl_context, offscreen=True)
    try:
        frame = eng.render(overview_camera(q.bboxes[0], eng.scale), SIZE, Cut(alpha=1.0))
        eng.world_positions(frame)
    finally:
        eng.release()
    nodes = frame.selection.nodes
    assert len(nodes) and q.in_domain[nodes].all()
    d = q.terrain.domain
    reach = q.squares[nodes, 2].max()
    y = frame.positions[..., 1][frame.positions[..., 3] > 0.5]
    assert len(y) > 1000 and y.max() <= d.ymax + reach < q.y0 + q.size


def test_meshes_stay_in_the_gpu_cache_between_frames(gl_context, quadtree):  # noqa: F811
    """The same view twice uploads nothing the second time; a closer eye changes the cut."""
    eng = Engine(quadtree, context=gl_context, offscreen=True)
    try:
        cam = all_terrain_views(quadtree)["oblique"]
        first = eng.render(cam, SIZE, Cut(alpha=2.0))
        # The selection reports the cut like an approximation tree's traversal.
        sel = first.selection
        assert sel.result_of(0) == SelectionResult.REFINED
        assert {sel.result_of(int(n)) for n in sel.nodes} == {SelectionResult.SELECTED}
        before = set(eng.cache.keys())
        again = eng.render(cam, SIZE, Cut(alpha=2.0))
        assert set(eng.cache.keys()) == before
        assert again.stats["triangles"] == first.stats["triangles"]
        close = eng.render(all_terrain_views(quadtree)["close"], SIZE, Cut(alpha=2.0))
        assert set(close.selection.nodes.tolist()) != set(first.selection.nodes.tolist())
    finally:
        eng.release()


def test_a_frame_builds_its_new_meshes_in_one_kernel_call(
    gl_context,  # noqa: F811
    quadtree,
    monkeypatch,
):
    """A frame builds the meshes the GPU cache lacks in one ``node_meshes`` call (not one
    per node), and the cache still holds one entry per drawn node: a second view builds
    only its new nodes' meshes, again in one call."""
    calls = []
    batch = source_module.node_meshes

    def counted(tree, rows, *args):
        calls.append(len(rows))
        return batch(tree, rows, *args)

    monkeypatch.setattr(source_module, "node_meshes", counted)
    eng = Engine(quadtree, context=gl_context, offscreen=True)
    try:
        views = all_terrain_views(quadtree)
        first = eng.render(views["oblique"], SIZE, Cut(alpha=2.0))
        assert calls == [first.stats["patches"]]
        assert len(eng.cache) == first.stats["patches"]
        before = set(eng.cache.keys())
        calls.clear()
        close = eng.render(views["close"], SIZE, Cut(alpha=2.0))
        new = set(eng.cache.keys()) - before
        assert len(new) > 0 and calls == [len(new)]
        assert close.stats["patches"] <= len(eng.cache)
    finally:
        eng.release()


def test_engine_refuses_what_does_not_apply(gl_context):  # noqa: F811
    """Texture pyramids and a triangle budget are clear errors for a point quadtree."""
    q = PointQuadtree(scattered_cloud(), 200)
    with pytest.raises(at.InvalidParameterError, match="colour ramp"):
        Engine(q, context=gl_context, textures="somewhere")
    eng = Engine(q, context=gl_context, offscreen=True)
    try:
        cam = all_terrain_views(q)["top"]
        with pytest.raises(at.InvalidParameterError, match="triangle budget"):
            eng.render(cam, SIZE, Cut(max_triangles=1000))
        with pytest.raises(at.InvalidParameterError, match="alpha"):
            eng.render(cam, SIZE, Cut(alpha=0.0))
    finally:
        eng.release()


def test_tree_file_holds_either_kind(tmp_path):
    """load_tree opens a point quadtree and an approximation tree; ApproximationTree.load
    refuses a quadtree file with a clear error; a flipped byte in the quadtree section is a
    StoreError (checksummed like the rest)."""
    q = PointQuadtree(scattered_cloud(), 200)
    path = tmp_path / "q.atree"
    write_atree(q, path)
    back = at.load_tree(path)
    assert isinstance(back, PointQuadtree)
    np.testing.assert_array_equal(back.node_errors, q.node_errors)
    with pytest.raises(at.StoreError, match="load_tree"):
        at.ApproximationTree.load(path)
    grid = at.ApproximationTree.build(fractal_terrain(33, seed=1), epsilon=1.0, progress=False)
    write_atree(grid, tmp_path / "g.atree")
    assert isinstance(at.load_tree(tmp_path / "g.atree"), at.ApproximationTree)
    with pytest.raises(at.StoreError, match="approximation tree, not a point quadtree"):
        PointQuadtree.load(tmp_path / "g.atree")
    raw = bytearray(path.read_bytes())
    f = TreeFile(path)
    offset, length = f.section_span("quadtree")
    del f
    raw[offset + length // 2] ^= 0xFF
    (tmp_path / "bad.atree").write_bytes(bytes(raw))
    with pytest.raises(at.StoreError, match="checksum"):
        at.load_tree(tmp_path / "bad.atree")


def test_cli_builds_renders_and_refuses_grids(tmp_path, data_dir):
    """approxtree build cloud.laz --kind point-quadtree, then render --json: one PNG with
    terrain and the frame stats; a raster is refused with one Error line and exit 2."""
    laz = data_file(data_dir, "lidar/autzen_trim.laz")
    runner = CliRunner()
    out = tmp_path / "q.zarr.zip"
    res = runner.invoke(
        main, ["build", str(laz), "--out", str(out), "--kind", "point-quadtree", "--json"]
    )
    assert res.exit_code == 0, res.output
    figures = json.loads(res.output)
    assert figures["tree_kind"] == "point_quadtree" and figures["max_points"] == 50
    assert figures["max_leaf_points"] <= 50 and figures["bytes"] == out.stat().st_size
    png = tmp_path / "q.png"
    res = runner.invoke(
        main, ["render", str(out), "--out", str(png), "--size", "320x240", "--json"]
    )
    assert res.exit_code == 0, res.output
    stats = json.loads(res.output)
    assert set(STAT_KEYS) <= set(stats) and stats["triangles"] > 0
    from PIL import Image

    img = np.asarray(Image.open(png))
    assert img.shape == (240, 320, 4) and (img[..., 3] == 255).mean() > 0.1
    np.save(tmp_path / "grid.npy", np.random.default_rng(0).uniform(0, 9, (20, 20)))
    res = runner.invoke(
        main, ["build", str(tmp_path / "grid.npy"), "--out", str(tmp_path / "g.zarr"),
               "--kind", "point-quadtree"]
    )  # fmt: skip
    assert res.exit_code == 2
    assert res.output.count("Error:") == 1 and "scattered points" in res.output


def test_viewer_engine_path_draws_into_a_host_framebuffer(gl_context, tmp_path):  # noqa: F811
    """What `approxtree view q.atree` does without a window: load_tree, the embedded Engine
    drawing into the framebuffer bound by the host, the upload call the viewer makes first,
    and the lighting option the viewer passes."""
    q = PointQuadtree(scattered_cloud(), 100)
    q.save(tmp_path / "q.zarr")
    tree = at.load_tree(tmp_path / "q.zarr")
    w, h = SIZE
    color = gl_context.renderbuffer((w, h), 4)
    depth = gl_context.depth_renderbuffer((w, h))
    fbo = gl_context.framebuffer(color_attachments=[color], depth_attachment=depth)
    eng = Engine(tree, context=gl_context)
    try:
        assert eng.upload(0) is False
        fbo.use()
        frame = eng.render(all_terrain_views(tree)["top"], SIZE, Cut(alpha=1.0))
        assert frame.image is None and frame.stats["triangles"] > 0
        host = np.frombuffer(fbo.read(components=4), dtype=np.uint8).reshape(h, w, 4)
        assert (host[..., 3] > 0).mean() == 1.0
        eng.set_vertical_exaggeration(2.0)
        eng.set_skirts(False)
    finally:
        eng.release()
        for obj in (fbo, color, depth):
            obj.release()


def test_cli_view_loads_a_quadtree_file_before_the_window(tmp_path):
    """`approxtree view q.atree` opens the quadtree file and gets as far as the window: without
    a display the one Error line is about glfw, not about the tree file."""
    PointQuadtree(scattered_cloud(), 200).save(tmp_path / "q.zarr")
    res = CliRunner().invoke(
        main,
        ["view", str(tmp_path / "q.zarr"), "--frames", "1"],
        env={"DISPLAY": None, "WAYLAND_DISPLAY": None},
    )
    assert res.exit_code == 2
    assert res.output.count("Error:") == 1 and "glfw could not initialise" in res.output


def test_viewer_window_replays_a_quadtree(tmp_path):
    """In a real window under Xvfb: a scripted replay over a point quadtree draws terrain in
    every frame and exits 0."""
    import shutil
    import subprocess
    import sys

    from PIL import Image

    from approxtree.viewer.xvfb import virtual_display

    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian/Ubuntu: apt-get install -y xvfb)")
    q = PointQuadtree(scattered_cloud(), 100)
    q.save(tmp_path / "q.zarr")
    views = all_terrain_views(q)
    script = [
        {"eye": views[v].eye.tolist(), "target": views[v].target.tolist(), "frames": 3}
        for v in ("oblique", "top")
    ]
    (tmp_path / "path.json").write_text(json.dumps(script))
    with virtual_display("1280x1024x24") as display:
        result = subprocess.run(
            [sys.executable, "-m", "approxtree", "view", "q.zarr", "--script", "path.json",
             "--stats", "stats.jsonl", "--screenshots", "shots", "--size", "480x270"],
            cwd=tmp_path,
            env={**os.environ, "DISPLAY": display},
            capture_output=True,
            text=True,
            timeout=300,
        )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = [json.loads(s) for s in (tmp_path / "stats.jsonl").read_text().splitlines()]
    assert len(lines) == 6 and all(s["triangles"] > 0 for s in lines)
    for i in range(2):
        shot = np.asarray(Image.open(tmp_path / "shots" / f"keyframe_{i:03d}.png"))
        assert (shot.max(axis=2) > 0).mean() > 0.9
