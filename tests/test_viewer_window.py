"""The viewer in a real window under Xvfb: scripted replay, keys through glfw's handler,
screenshots, stats lines and a clean exit."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file
from PIL import Image

from approxtree import ApproximationTree
from approxtree.datasets import sample_terrain
from approxtree.render.frame_state import display_scale, overview_camera
from approxtree.viewer.xvfb import virtual_display

SIZE = (480, 270)


@pytest.fixture(scope="module")
def display():
    """A private Xvfb display (":N"), stopped after the module's tests."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian/Ubuntu: apt-get install -y xvfb)")
    with virtual_display("1280x1024x24") as name:
        yield name


def run_viewer(display: str, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, DISPLAY=display)
    return subprocess.run(
        [sys.executable, "-m", "approxtree", "view", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def terrain_fraction(image: np.ndarray) -> float:
    """Share of pixels not left at the clear colour (black)."""
    return float((image.max(axis=2) > 0).mean())


@pytest.fixture(scope="module")
def sample_tree(tmp_path_factory):
    tree = ApproximationTree.build(sample_terrain(), epsilon=1.0, progress=False)
    path = tmp_path_factory.mktemp("tree") / "sample.zarr"
    tree.save(path)
    return tree, path


def test_replay_keys_screenshots_and_stats(display, sample_tree, tmp_path):
    """A replay opens the window, draws terrain, wireframe (L) changes the image, P writes a
    timestamped PNG, each frame logs positive triangles, the upload budget holds, exit 0."""
    tree, path = sample_tree
    cam = overview_camera(tree.bboxes[0], display_scale(tree.terrain))
    eye, target = cam.eye.tolist(), cam.target.tolist()
    near_eye = (0.6 * cam.eye + 0.4 * cam.target).tolist()
    script = [
        {"eye": eye, "target": target, "frames": 12},
        {"eye": eye, "target": target, "frames": 2, "keys": ["L"]},
        {"eye": near_eye, "target": target, "frames": 5, "keys": ["L", "P"]},
    ]
    (tmp_path / "path.json").write_text(json.dumps(script))
    result = run_viewer(
        display,
        tmp_path,
        str(path),
        "--script", "path.json",
        "--stats", "stats.jsonl",
        "--screenshots", "shots",
        "--size", f"{SIZE[0]}x{SIZE[1]}",
        "--keys", "1:F1,2:F1,3:2,4:1",
        "--max-uploads", "16", "--background", "transparent",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    shots = [np.asarray(Image.open(tmp_path / "shots" / f"keyframe_{i:03d}.png")) for i in range(3)]
    assert all(s.shape == (SIZE[1], SIZE[0], 3) for s in shots)
    plain, wire, near = shots
    assert terrain_fraction(plain) > 0.1
    assert terrain_fraction(near) > terrain_fraction(plain)
    # Wireframe draws dark edge lines instead of lit triangles: the image changes, darker.
    diff = np.abs(plain.astype(int) - wire.astype(int)).max(axis=2)
    assert (diff > 30).mean() > 0.05
    assert wire.astype(float).mean() < 0.8 * plain.astype(float).mean()
    # P wrote a timestamped screenshot into the working folder.
    stamped = list(tmp_path.glob("approxtree-*.png"))
    assert len(stamped) == 1
    lines = [json.loads(s) for s in (tmp_path / "stats.jsonl").read_text().splitlines()]
    assert len(lines) == 12 + 2 + 5
    assert all(s["triangles"] > 0 and s["patches"] > 0 for s in lines)
    assert all(s["paged_uploads"] <= 16 for s in lines)
    assert [s["keyframe"] for s in lines if s["keyframe"] is not None] == [0, 1, 2]
    # The queue drained while the first keyframe was held: its screenshot is the wanted cut.
    assert lines[11]["pending"] == 0 and lines[0]["pending"] > 0
    # "2" then "1" pressed α up and back down.
    assert lines[3]["alpha"] == pytest.approx(1.5) and lines[4]["alpha"] == pytest.approx(1.0)


def test_skirts_and_exaggeration_keys_change_the_image(display, sample_tree, tmp_path):
    """K (skirts off) and PAGE_UP (vertical exaggeration) each change the drawn terrain."""
    tree, path = sample_tree
    cam = overview_camera(tree.bboxes[0], display_scale(tree.terrain), elevation=15.0)
    eye, target = cam.eye.tolist(), cam.target.tolist()
    script = [
        {"eye": eye, "target": target, "frames": 1},
        {"eye": eye, "target": target, "frames": 1, "keys": ["PAGE_UP", "PAGE_UP"]},
        {"eye": eye, "target": target, "frames": 1, "keys": ["K"]},
    ]
    (tmp_path / "path.json").write_text(json.dumps(script))
    result = run_viewer(
        display, tmp_path, str(path), "--script", "path.json", "--screenshots", "shots",
        "--size", f"{SIZE[0]}x{SIZE[1]}", "--max-uploads", "0", "--background", "transparent",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    flat, tall = (
        np.asarray(Image.open(tmp_path / "shots" / f"keyframe_{i:03d}.png")) for i in (0, 1)
    )
    # Higher relief seen from a low angle covers more of the sky.
    assert terrain_fraction(tall) > terrain_fraction(flat)


def test_freeze_and_fly_keys(display, sample_tree, tmp_path):
    """C freezes the cut while the camera moves on; F then W/shift+W fly forward, shift 4x."""
    tree, path = sample_tree
    cam = overview_camera(tree.bboxes[0], display_scale(tree.terrain))
    eye, target = cam.eye.tolist(), cam.target.tolist()
    near_eye = (0.5 * cam.eye + 0.5 * cam.target).tolist()
    script = [
        {"eye": eye, "target": target, "frames": 2},
        {"eye": near_eye, "target": target, "frames": 3, "keys": ["C"]},
        {"eye": near_eye, "target": target, "frames": 1, "keys": ["C"]},
    ]
    (tmp_path / "path.json").write_text(json.dumps(script))
    result = run_viewer(
        display, tmp_path, str(path), "--script", "path.json", "--stats", "frozen.jsonl",
        "--size", f"{SIZE[0]}x{SIZE[1]}", "--max-uploads", "0",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = [json.loads(s) for s in (tmp_path / "frozen.jsonl").read_text().splitlines()]
    frozen = [s for s in lines if s["frozen"]]
    assert len(frozen) == 3
    # The frozen cut is the overview's, whatever the camera does; unfreezing refines.
    assert {s["patches"] for s in frozen} == {lines[1]["patches"]}
    assert frozen[0]["eye"] != frozen[-1]["eye"]
    assert lines[-1]["patches"] > lines[1]["patches"]

    result = run_viewer(
        display, tmp_path, str(path), "--frames", "6", "--stats", "fly.jsonl",
        "--size", f"{SIZE[0]}x{SIZE[1]}", "--keys", "0:F,2:W,3:W,4:shift+W",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = [json.loads(s) for s in (tmp_path / "fly.jsonl").read_text().splitlines()]
    assert len(lines) == 6 and lines[0]["mode"] == "fly"
    eyes = np.array([s["eye"] for s in lines])
    steps = np.linalg.norm(np.diff(eyes, axis=0) * display_scale(tree.terrain), axis=1)
    assert steps[0] == 0.0 and steps[1] > 0.0
    assert steps[2] == pytest.approx(steps[1]) and steps[3] == pytest.approx(4.0 * steps[1])
    assert steps[4] == 0.0


def test_thematic_toggle_changes_colours_by_land_use(display, data_dir, tmp_path):
    """T switches the NC land-use layer off: colours over forest and water stop differing as
    the land-use table says they should."""
    from approxtree.render.engine import Engine

    if not hasattr(Engine, "set_textures"):
        pytest.skip(
            "this Engine draws no texture pyramids yet (Engine.set_textures is missing); "
            "the thematic toggle runs once the textured renderer is merged"
        )
    from approxtree.io import open_terrain
    from approxtree.textures.bake import bake

    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    landuse = data_file(data_dir, "nc/landuse_r.tif")
    terrain = open_terrain(dem)
    tree = ApproximationTree.build(terrain, epsilon=1.0, progress=False)
    tree.save(tmp_path / "nc.zarr")
    bake(terrain, tmp_path / "landuse", shading=None, thematic=landuse, max_texture_size=1024)
    # Straight down over the domain centre, so every pixel shows one land-use cell.
    d = terrain.domain
    cx, cy = d.center
    script = [
        {"eye": [cx, cy - 1.0, 30000.0], "target": [cx, cy, 100.0], "frames": 3},
        {"eye": [cx, cy - 1.0, 30000.0], "target": [cx, cy, 100.0], "frames": 1, "keys": ["T"]},
    ]
    (tmp_path / "path.json").write_text(json.dumps(script))
    result = run_viewer(
        display, tmp_path, "nc.zarr", "--textures", "landuse", "--script", "path.json",
        "--screenshots", "shots", "--size", f"{SIZE[0]}x{SIZE[1]}", "--max-uploads", "0",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    on, off = (np.asarray(Image.open(tmp_path / "shots" / f"keyframe_{i:03d}.png")) for i in (0, 1))
    # Land use at each pixel centre, through the frame's own projection.
    import rasterio

    from approxtree.render import Camera, FrameState

    cam = Camera.look_at(tuple(script[0]["eye"]), tuple(script[0]["target"]), fov=45.0)
    fs = FrameState.from_camera(cam, SIZE, tree.bboxes[0], tree.origin, np.ones(3))
    with rasterio.open(landuse) as ds:
        classes = ds.read(1)
        rows, cols = np.mgrid[0 : ds.height : 5, 0 : ds.width : 5]
        xs, ys = ds.xy(rows.ravel(), cols.ravel())
        cls = classes[rows.ravel(), cols.ravel()]
    zs = terrain.height_at(np.asarray(xs), np.asarray(ys))
    px, _ = fs.world_to_pixels(np.column_stack([xs, ys, zs]))
    seen = np.isfinite(px).all(axis=1)
    px = np.where(seen[:, None], px, -1.0)
    c, r = px[:, 0].astype(int), SIZE[1] - 1 - px[:, 1].astype(int)
    inside = seen & (c >= 0) & (c < SIZE[0]) & (r >= 0) & (r < SIZE[1])

    def mean_colour(image, k):
        m = inside & (cls == k)
        return image[r[m], c[m]].astype(float).mean(axis=0)

    forest_water_on = np.abs(mean_colour(on, 5) - mean_colour(on, 6)).sum()
    forest_water_off = np.abs(mean_colour(off, 5) - mean_colour(off, 6)).sum()
    assert np.abs(on.astype(int) - off.astype(int)).max(axis=2).mean() > 5
    assert forest_water_on > forest_water_off + 30


def test_clear_errors_without_display_and_for_bad_scripts(sample_tree, tmp_path):
    """No display and a malformed script each end with one Error line and exit code 2."""
    _, path = sample_tree
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run(
        [sys.executable, "-m", "approxtree", "view", str(path), "--frames", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert "Error: glfw could not initialise" in result.stderr and "xvfb" in result.stderr
    (tmp_path / "bad.json").write_text('[{"eye": [0, 0, 1], "target": [0, 0, 1]}]')
    result = subprocess.run(
        [sys.executable, "-m", "approxtree", "view", str(path), "--script", "bad.json"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert "eye and target must differ" in result.stderr


def test_screenshots_keep_the_map_furniture_when_asked(display, sample_tree, tmp_path):
    """--screenshot-furniture: keyframe and P pictures keep the legend (bottom right) and the
    scale bar (bottom left) but not the Map panel (top left); --screenshot-name names P's
    files; without the flag the pictures are the 3D view alone."""
    tree, path = sample_tree
    cam = overview_camera(tree.bboxes[0], display_scale(tree.terrain))
    eye, target = cam.eye.tolist(), cam.target.tolist()
    script = [{"eye": eye, "target": target, "frames": 4}]
    (tmp_path / "path.json").write_text(json.dumps(script))
    shots = {}
    for name, extra in [("plain", ()), ("furniture", ("--screenshot-furniture",))]:
        folder = tmp_path / name
        folder.mkdir()
        result = run_viewer(
            display, folder, str(path), "--script", "../path.json", "--screenshots", "shots",
            "--size", f"{SIZE[0]}x{SIZE[1]}", "--max-uploads", "0",
            "--screenshot-name", "nc-{n:03d}.png", "--keys", "2:P", *extra,
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        assert [p.name for p in folder.glob("*.png")] == ["nc-001.png"]
        key = np.asarray(Image.open(folder / "shots" / "keyframe_000.png")).astype(int)
        pressed = np.asarray(Image.open(folder / "nc-001.png")).astype(int)
        assert pressed.shape == key.shape
        shots[name] = (key, pressed)
    w, h = SIZE
    for k in range(2):
        plain, kept = shots["plain"][k], shots["furniture"][k]
        changed = np.abs(plain - kept).max(axis=2) > 20
        # The legend (bottom right) and the scale bar (bottom left) are in the picture...
        assert changed[h - 60 :, w - 190 : w - 20].mean() > 0.2
        assert changed[h - 45 :, :150].mean() > 0.2
        # ...the Map panel (top left) is not.
        assert not changed[:60, :120].any()


def test_bad_screenshot_name_is_one_error_line(sample_tree, tmp_path):
    """A screenshot name with an unknown field or a folder: one Error line before any
    window opens."""
    _, path = sample_tree
    for name in ("shot-{x}.png", "sub/shot.png", "shot.jpg"):
        result = subprocess.run(
            [sys.executable, "-m", "approxtree", "view", str(path), "--screenshot-name", name],
            cwd=tmp_path, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert result.returncode == 2, result.stderr
        assert result.stderr.startswith("Error: Bad screenshot name") and (
            result.stderr.count("\n") == 1
        ), result.stderr
