"""Viewer parts without a window: camera controllers, picking, keys, scripts, upload queue."""

from __future__ import annotations

import math

import numpy as np
import pytest

from approxtree import ApproximationTree
from approxtree.datasets import sample_terrain
from approxtree.errors import InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.render.camera import Camera
from approxtree.render.frame_state import FrameState, display_scale, overview_camera
from approxtree.render.selector import select
from approxtree.render.visual_error import texel_sizes, visual_errors
from approxtree.viewer.controllers import (
    FlyController,
    OrbitController,
    cursor_ray,
    pick_terrain,
    to_display,
)
from approxtree.viewer.keys import MOD_SHIFT, action_for, help_lines, parse_key_presses
from approxtree.viewer.script import parse_script, script_frames
from approxtree.viewer.upload_queue import (
    UploadQueue,
    drop_covered,
    nearest_resident,
    upload_order,
)

SIZE = (640, 360)
FOV = 45.0
BOUNDS = np.array([-1e4, -1e4, -1e3, 1e4, 1e4, 1e3])


def pixels_of(eye, target, points) -> np.ndarray:
    """Pixel coordinates of world ``points`` (…, 3) seen from eye to target (origin 0, scale 1)."""
    cam = Camera.look_at(tuple(eye), tuple(target), fov=FOV)
    fs = FrameState.from_camera(cam, SIZE, BOUNDS, np.zeros(3), np.ones(3))
    return fs.world_to_pixels(np.asarray(points, dtype=np.float64))[0]


# -- orbit, pan, zoom -------------------------------------------------------------------------


def test_orbit_keeps_target_and_distance_and_clamps_pitch():
    """Orbiting turns the eye around the target at a fixed distance, never over the zenith."""
    o = OrbitController(np.array([0.0, -100.0, 100.0]), np.zeros(3))
    assert np.allclose(o.eye, [0.0, -100.0, 100.0])
    d0, z0 = o.distance, o.eye[2]
    o.orbit(300.0, 0.0)
    assert np.allclose(o.target, 0.0)
    assert math.isclose(np.linalg.norm(o.eye - o.target), d0)
    assert math.isclose(o.eye[2], z0)
    assert not np.allclose(o.eye[:2], [0.0, -100.0])
    o.orbit(0.0, 1e6)
    assert o.eye[2] < d0 and o.pitch < math.pi / 2
    o.orbit(0.0, -1e6)
    assert o.eye[2] > 0.0


def test_pan_moves_the_ground_with_the_cursor():
    """A horizontal drag of dx pixels moves the ground point at the target dx pixels across."""
    o = OrbitController(np.array([30.0, -400.0, 250.0]), np.array([10.0, 20.0, 0.0]))
    point = o.target.copy()
    offset = o.eye - o.target
    before = pixels_of(o.eye, o.target, point)
    o.pan(37.0, 0.0, SIZE[1], FOV)
    after = pixels_of(o.eye, o.target, point)
    assert np.allclose(o.eye - o.target, offset)
    assert o.target[2] == 0.0
    # Dragging right moves the grabbed ground right (x grows) by the same pixels.
    assert after[0] - before[0] == pytest.approx(37.0, abs=1e-6)
    assert after[1] == pytest.approx(before[1], abs=1e-6)


def test_zoom_to_keeps_the_point_under_the_cursor():
    """Zooming towards a point keeps it at its pixel while the eye gets closer to it."""
    o = OrbitController(np.array([50.0, -500.0, 300.0]), np.array([0.0, 0.0, 0.0]))
    point = np.array([120.0, 80.0, 15.0])
    before = pixels_of(o.eye, o.target, point)
    d_before = np.linalg.norm(o.eye - point)
    o.zoom_to(point, 0.5)
    after = pixels_of(o.eye, o.target, point)
    assert np.allclose(after, before, atol=1e-6)
    assert np.linalg.norm(o.eye - point) == pytest.approx(0.5 * d_before)
    with pytest.raises(InvalidParameterError):
        o.zoom_to(point, 0.0)


def test_cursor_ray_goes_through_its_pixel():
    """The ray of a pixel projects back onto that pixel; the centre pixel's ray looks ahead."""
    eye, target = np.array([10.0, -300.0, 200.0]), np.array([0.0, 50.0, 0.0])
    centre = cursor_ray(eye, target, FOV, SIZE, (SIZE[0] / 2, SIZE[1] / 2))
    assert np.allclose(centre, (target - eye) / np.linalg.norm(target - eye))
    for pixel in [(17.5, 300.25), (600.0, 12.0)]:
        ray = cursor_ray(eye, target, FOV, SIZE, pixel)
        assert np.allclose(pixels_of(eye, target, eye + 250.0 * ray), pixel, atol=1e-6)


def test_pick_terrain_lands_on_the_surface():
    """The picked point lies on h_T (to bisection precision) and along the ray."""
    x = np.arange(200.0)
    z = 5.0 * np.sin(x[None, :] / 15.0) + 0.05 * x[:, None]
    from affine import Affine

    grid = Grid(z.astype(np.float32), transform=Affine(1.0, 0, 0, 0, -1.0, 200.0))
    origin = np.array([100.0, 100.0, 0.0])
    scale = np.ones(3)
    eye_w = np.array([60.0, 20.0, 80.0])
    eye = to_display(eye_w, origin, scale)
    direction = np.array([0.3, 0.8, -0.5])
    direction /= np.linalg.norm(direction)
    hit = pick_terrain(grid, origin, scale, eye, direction, 400.0)
    assert hit is not None
    world = hit + origin
    h = float(grid.height_at(np.array([world[0]]), np.array([world[1]]))[0])
    assert abs(world[2] - h) < 1e-3
    assert np.allclose(np.cross(hit - eye, direction), 0.0, atol=1e-6)
    # Looking up into the sky hits nothing.
    assert pick_terrain(grid, origin, scale, eye, np.array([0.0, 0.0, 1.0]), 400.0) is None


# -- fly --------------------------------------------------------------------------------------


def test_fly_moves_along_view_and_world_up():
    """W moves along the view direction, D to its right, E straight up, each by the distance."""
    f = FlyController(np.array([0.0, 0.0, 100.0]), np.array([0.0, 100.0, 100.0]))
    assert np.allclose(f.forward, [0.0, 1.0, 0.0])
    f.move(1.0, 0.0, 0.0, 10.0)
    assert np.allclose(f.eye, [0.0, 10.0, 100.0])
    f.move(0.0, 1.0, 0.0, 5.0)
    assert np.allclose(f.eye, [5.0, 10.0, 100.0])
    f.move(0.0, 0.0, 1.0, 2.0)
    assert np.allclose(f.eye, [5.0, 10.0, 102.0])
    # Diagonal keys move the same distance, not √2 times it.
    start = f.eye.copy()
    f.move(1.0, 1.0, 0.0, 3.0)
    assert np.linalg.norm(f.eye - start) == pytest.approx(3.0)


def test_fly_look_and_pose_round_trip():
    """Looking right turns clockwise seen from above; a pose survives set_pose unchanged."""
    eye, target = np.array([1.0, 2.0, 3.0]), np.array([4.0, 50.0, -7.0])
    f = FlyController(eye, target)
    assert np.allclose(f.target, target)
    f.look(100.0, 0.0)
    assert f.forward[0] > 0.0
    f.look(0.0, 1e6)
    assert f.forward[2] < -0.99
    o = OrbitController(eye, target)
    assert np.allclose(o.eye, eye) and np.allclose(o.target, target)


# -- keys and scripts -------------------------------------------------------------------------


def test_key_presses_parse_and_bind():
    """Scripted presses parse frames and modifiers; bindings cover the issue's toggles."""
    presses = parse_key_presses("L, 3:shift+page_up, F1")
    assert [(p.frame, p.key, p.mods) for p in presses] == [
        (0, "L", 0),
        (3, "PAGE_UP", MOD_SHIFT),
        (2, "F1", 0),
    ]
    actions = {
        action_for(k, 0)
        for k in ["1", "2", "3", "4", "L", "K", "PAGE_UP", "T", "TAB", "H", "C", "P", "F1"]
    }
    assert {"wireframe", "skirts", "thematic", "freeze", "screenshot", "help"} <= actions
    assert action_for("W", 0) is None
    assert len(help_lines()) > 15
    for bad in ("x:L", "-1:L", "hyper+L"):
        with pytest.raises(InvalidParameterError):
            parse_key_presses(bad)


def test_script_frames_interpolate_and_mark_keyframes():
    """Frames hold the first keyframe, end exactly on each keyframe and press keys once."""
    kfs = parse_script(
        [
            {"eye": [0, 0, 10], "target": [0, 10, 0], "frames": 2},
            {"eye": [10, 0, 10], "target": [0, 10, 0], "frames": 4, "keys": ["L"]},
        ]
    )
    frames = script_frames(kfs)
    assert len(frames) == 6
    assert [f.keyframe for f in frames] == [None, 0, None, None, None, 1]
    assert np.allclose(frames[-1].eye, [10, 0, 10])
    xs = [f.eye[0] for f in frames]
    assert xs == sorted(xs) and 0 < xs[3] < 10
    assert [f.keys for f in frames] == [(), (), ("L",), (), (), ()]
    for bad in (
        [],
        [{"eye": [0, 0], "target": [0, 0, 1]}],
        [{"eye": [0, 0, 0], "target": [0, 0, 0]}],
        [{"eye": [0, 0, 1], "target": [0, 0, 0], "frames": 0}],
        [{"eye": [0, 0, 1], "target": [0, 0, 0], "speed": 2}],
    ):
        with pytest.raises(InvalidParameterError):
            parse_script(bad)


# -- upload queue -----------------------------------------------------------------------------


class FakeEngine:
    """The part of the Engine the queue uses, with a set of resident node ids (no GL)."""

    def __init__(self, tree) -> None:
        self.tree = tree
        self.texels = texel_sizes(tree)
        self.cached: set[int] = set()
        self.upload_calls = 0

    def resident(self, nodes):
        return np.array([int(i) in self.cached for i in np.asarray(nodes)], dtype=bool)

    def upload(self, node: int) -> bool:
        self.upload_calls += 1
        if node in self.cached:
            return False
        self.cached.add(int(node))
        return True


@pytest.fixture(scope="module")
def tree():
    return ApproximationTree.build(sample_terrain(), epsilon=1.0, progress=False)


def _ancestors_or_self(tree, node: int) -> set[int]:
    out = set()
    while node >= 0:
        out.add(int(node))
        node = int(tree.parents[node])
    return out


def test_queue_bounds_uploads_and_draws_a_partition(tree):
    """Each frame uploads at most the budget, draws a cut covering every wanted node exactly
    once (itself or one ancestor), and reaches the wanted cut once the queue drains."""
    engine = FakeEngine(tree)
    queue = UploadQueue(engine, max_uploads=8)
    cam = overview_camera(tree.bboxes[0], display_scale(tree.terrain))
    fs = FrameState.from_camera(cam, SIZE, tree.bboxes[0], tree.origin, display_scale(tree.terrain))
    wanted = select(tree, fs, 1.0, 2.0, engine.texels)
    assert len(wanted.nodes) > 30
    for frame in range(100):  # noqa: B007 (the frame count is asserted below)
        before = len(engine.cached)
        drawn = queue(wanted, fs)
        assert len(engine.cached) - before <= 8
        covers = [
            [d for d in drawn.nodes if int(d) in _ancestors_or_self(tree, int(w))]
            for w in wanted.nodes
        ]
        assert all(len(c) == 1 for c in covers)
        assert np.all(engine.resident(drawn.nodes))
        if queue.pending == 0:
            break
    assert frame > 2
    assert np.array_equal(drawn.nodes, wanted.nodes)


def test_queue_reports_the_drawn_cuts_errors(tree):
    """With stand-ins drawn, max_alpha and max_gamma are those of the drawn nodes."""
    engine = FakeEngine(tree)
    queue = UploadQueue(engine, max_uploads=3)
    scale = display_scale(tree.terrain)
    cam = overview_camera(tree.bboxes[0], scale)
    fs = FrameState.from_camera(cam, SIZE, tree.bboxes[0], tree.origin, scale)
    wanted = select(tree, fs, 1.0, 2.0, engine.texels)
    drawn = queue(wanted, fs)
    assert queue.fallbacks > 0 and not np.array_equal(drawn.nodes, wanted.nodes)
    a, g = visual_errors(
        tree.bboxes[drawn.nodes], tree.errors[drawn.nodes], engine.texels[drawn.nodes], fs
    )
    assert drawn.stats["max_alpha"] == a.max() and drawn.stats["max_gamma"] == g.max()
    assert drawn.stats["max_gamma"] > wanted.stats["max_gamma"]


def test_queue_refines_progressively(tree):
    """While a large request drains, the drawn cut gets finer from frame to frame."""
    engine = FakeEngine(tree)
    queue = UploadQueue(engine, max_uploads=6)
    cam = overview_camera(tree.bboxes[0], display_scale(tree.terrain))
    fs = FrameState.from_camera(cam, SIZE, tree.bboxes[0], tree.origin, display_scale(tree.terrain))
    wanted = select(tree, fs, 1.0, 2.0, engine.texels)
    counts = [len(queue(wanted, fs).nodes) for _ in range(4)]
    assert counts[0] > 1 and counts == sorted(counts) and counts[-1] > counts[0]


def test_queue_helpers_on_a_small_tree():
    """nearest_resident, drop_covered and upload_order on a hand-made tree."""
    #        0
    #     1     2
    #   3  4   5  6
    parents = np.array([-1, 0, 0, 1, 1, 2, 2])
    levels = np.array([0, 1, 1, 2, 2, 2, 2])
    cached = {0, 1, 5}

    def res(ids):
        return np.isin(ids, list(cached))

    assert nearest_resident(np.array([3, 5, 6, 2]), parents, res).tolist() == [1, 5, 0, 0]
    assert nearest_resident(np.array([3]), parents, lambda i: np.zeros(len(i), bool)).tolist() == [
        -1
    ]
    assert drop_covered(np.array([1, 3, 5, 0, 5]), parents).tolist() == [0]
    assert drop_covered(np.array([3, 4, 2, 4]), parents).tolist() == [3, 4, 2]
    assert upload_order(np.array([3, 4, 5, 6]), parents, levels, res).tolist() == [2, 3, 4, 6]
