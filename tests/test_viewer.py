"""Viewer parts without a window: camera controllers, picking, keys, scripts, the action
tables, navigation, bookmarks and flights, replay and stats lines."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from approxtree.errors import InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.render.camera import Camera
from approxtree.render.frame_state import FrameState
from approxtree.render.traversal import drop_covered, nearest_resident, upload_order
from approxtree.viewer.actions import ACTIONS
from approxtree.viewer.controllers import (
    FlyController,
    OrbitController,
    cursor_ray,
    pick_terrain,
    to_display,
)
from approxtree.viewer.keys import BINDINGS, MOD_SHIFT, action_for, help_lines, parse_key_presses
from approxtree.viewer.map_session import FLIGHT_FRAMES, MapSession
from approxtree.viewer.map_tools import Bookmarks
from approxtree.viewer.navigation import Navigation
from approxtree.viewer.replay import SCRIPT_ACTIONS, SCRIPT_DT, Replay, stats_line
from approxtree.viewer.script import ACTIONS as SCRIPT_ACTION_CHECKS
from approxtree.viewer.script import parse_script, script_frames
from approxtree.viewer.settings import ViewSettings

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


# -- paging helpers (render/traversal.py) as the viewer relies on them -----------------------


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


# -- the action tables ------------------------------------------------------------------------


def test_action_tables_name_every_binding_and_script_action():
    """Every action name of keys.BINDINGS has a function in ACTIONS and nothing else does;
    every script action that script.py accepts has one in SCRIPT_ACTIONS."""
    assert set(ACTIONS) == {action for action, _ in BINDINGS.values()}
    assert set(SCRIPT_ACTIONS) == set(SCRIPT_ACTION_CHECKS)


def test_actions_change_the_settings_as_their_keys_say():
    """Threshold keys scale by 1.5 and back, the sun turns and stops at its limits, H cycles
    the lighting (with a message), toggles flip."""
    v = SimpleNamespace(settings=ViewSettings(), messages=[])
    ACTIONS["alpha_up"](v)
    ACTIONS["gamma_down"](v)
    assert v.settings.alpha == pytest.approx(1.5) and v.settings.gamma == pytest.approx(2 / 1.5)
    ACTIONS["alpha_down"](v)
    assert v.settings.alpha == pytest.approx(1.0)
    ACTIONS["sun_left"](v)
    assert v.settings.sun_azimuth == 300.0
    for _ in range(20):
        ACTIONS["sun_up"](v)
    assert v.settings.sun_altitude == 90.0
    for _ in range(3):
        ACTIONS["shading"](v)
    assert v.settings.lighting == "auto"
    assert v.messages == ["lighting on", "lighting off", "lighting auto"]
    for name in ("wireframe", "ui", "help"):
        before = getattr(v.settings, name)
        ACTIONS[name](v)
        assert getattr(v.settings, name) is not before


# -- navigation, bookmarks and flights (no window) ---------------------------------------------


def fake_tree(crs=None):
    """The parts of a tree the cameras and map session read: a 1000 × 1000 m box."""
    terrain = SimpleNamespace(crs=crs, domain=SimpleNamespace(center=(500.0, 500.0)))
    box = np.array([[0.0, 0.0, 0.0, 1000.0, 1000.0, 100.0]])
    return SimpleNamespace(terrain=terrain, origin=np.array([500.0, 500.0, 0.0]), bboxes=box)


def test_navigation_keeps_the_world_pose():
    """Switching to fly mode and changing the exaggeration keep the world pose; reset goes
    home; W flies fly_speed × dt forward, shift four times that."""
    settings = ViewSettings()
    nav = Navigation(settings, fake_tree(), np.ones(3), FOV)
    home = nav.pose_world()
    pose = (np.array([100.0, -300.0, 400.0]), np.array([520.0, 480.0, 10.0]))
    nav.set_pose_world(*pose)
    nav.toggle_fly()
    assert settings.fly and np.allclose(nav.pose_world(), pose)
    nav.rescale(np.array([1.0, 1.0, 3.0]))
    assert np.allclose(nav.pose_world(), pose)
    eye = nav.fly.eye.copy()
    nav.fly_step({"W"}, 0.5)
    assert np.linalg.norm(nav.fly.eye - eye) == pytest.approx(0.5 * nav.fly_speed)
    eye = nav.fly.eye.copy()
    nav.fly_step({"W", "LEFT_SHIFT"}, 0.5)
    assert np.linalg.norm(nav.fly.eye - eye) == pytest.approx(4 * 0.5 * nav.fly_speed)
    nav.reset()
    assert not settings.fly
    assert np.allclose(nav.pose_world()[1], home[1])


def test_home_is_the_fitted_view_of_render():
    """The viewer's home pose is render's fitted view for the window's size (the terrain
    fills the window), not the bounding-sphere overview that left it ~20-25 % of it."""
    from approxtree.render.frame_state import framing_camera

    tree = fake_tree()
    for size in [(1280, 720), (640, 640)]:
        nav = Navigation(ViewSettings(), tree, np.ones(3), FOV, size)
        fitted = framing_camera(tree.bboxes[0], np.ones(3), size, fov=FOV)
        eye, target = nav.pose_world()
        assert np.allclose(eye, fitted.eye) and np.allclose(target, fitted.target)
        # The box top's corners land inside the window, spanning most of its width.
        fs = FrameState.from_camera(fitted, size, tree.bboxes[0], np.zeros(3), np.ones(3))
        top = np.array([[x, y, 100.0] for x in (0.0, 1000.0) for y in (0.0, 1000.0)])
        px = fs.world_to_pixels(top)[0]
        assert (px >= 0).all() and (px[:, 0] <= size[0]).all() and (px[:, 1] <= size[1]).all()
        assert np.ptp(px[:, 0]) > 0.9 * size[0] or np.ptp(px[:, 1]) > 0.9 * size[1]


def test_bookmark_and_flight(tmp_path):
    """B saves "view 1"; G flies there in FLIGHT_FRAMES eased poses, landing exactly on it."""
    settings = ViewSettings()
    tree = fake_tree()
    nav = Navigation(settings, tree, np.ones(3), FOV)
    messages: list[str] = []
    marks = Bookmarks(tmp_path / "marks.json", "t")
    session = MapSession(settings, tree, nav, None, marks, tmp_path, messages)
    saved = (np.array([10.0, 20.0, 500.0]), np.array([600.0, 700.0, 0.0]))
    nav.set_pose_world(*saved)
    session.save_bookmark()
    assert marks.names() == ["view 1"] and "view 1" in messages[-1]
    nav.reset()
    session.fly_to_next()
    eyes = []
    while session.flying:
        session.fly_on()
        eyes.append(nav.pose_world()[0])
    assert len(eyes) == FLIGHT_FRAMES
    assert np.allclose(nav.pose_world(), saved)
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert steps[len(steps) // 2] > steps[0] and steps[len(steps) // 2] > steps[-1]


def test_flight_ahead_gives_the_cameras_the_view_will_pass(tmp_path):
    """During a fly-to, the poses after the next one are the cameras the frames will have
    (what the viewer hands the paging as ``Paging.path``), and looking at them moves nothing."""
    settings = ViewSettings()
    tree = fake_tree()
    nav = Navigation(settings, tree, np.ones(3), FOV)
    marks = Bookmarks(tmp_path / "marks.json", "t")
    session = MapSession(settings, tree, nav, None, marks, tmp_path, [])
    nav.set_pose_world(np.array([10.0, 20.0, 500.0]), np.array([600.0, 700.0, 0.0]))
    session.save_bookmark()
    nav.reset()
    session.fly_to_next()
    ahead = [nav.camera_at(*pose) for pose in session.upcoming(3)]
    pose = nav.pose_world()
    assert len(ahead) == 3 and np.allclose(nav.pose_world(), pose)
    session.fly_on()
    for camera in ahead:
        session.fly_on()
        assert np.allclose(camera.eye, nav.camera().eye)
        assert np.allclose(camera.target, nav.camera().target)


# -- replay and stats lines -------------------------------------------------------------------


def test_replay_presses_steps_and_stats_lines(tmp_path):
    """A replay presses --keys before the script's keys, steps 1/30 s, names keyframe shots,
    and writes one JSON line per frame with inf as null and no interface boxes while hidden."""
    frames = script_frames(
        parse_script([{"eye": [0, 0, 10], "target": [0, 10, 0], "frames": 2, "keys": ["L"]}])
    )
    replay = Replay(
        frames, parse_key_presses("0:F1"), tmp_path / "s.jsonl", tmp_path / "shots", tmp_path
    )
    assert replay.presses(0) == [("F1", 0), ("L", 0)] and replay.presses(1) == []
    assert replay.dt(10.0, 0.0) == SCRIPT_DT
    assert replay.keyframe_shot(frames[0]) is None
    assert replay.keyframe_shot(frames[1]) == tmp_path / "shots" / "keyframe_000.png"
    assert not replay.ended(1) and replay.ended(2)
    settings = ViewSettings(ui=False)
    tree = fake_tree()
    nav = Navigation(settings, tree, np.ones(3), FOV)
    session = MapSession(settings, tree, nav, None, Bookmarks(tmp_path / "b", "t"), tmp_path, [])
    v = SimpleNamespace(settings=settings, nav=nav, map=session)
    stats = {"triangles": 7, "max_alpha": math.inf}
    line = stats_line(stats, 1, 2.5, (64, 32), frames[1], v, {"legend": [0, 0, 1, 1]})
    assert list(line)[:6] == ["triangles", "max_alpha", "frame", "frame_ms", "size", "keyframe"]
    assert line["ui"] is None and line["keyframe"] == 0 and line["mode"] == "orbit"
    replay.record(line)
    replay.write()
    (written,) = [json.loads(s) for s in (tmp_path / "s.jsonl").read_text().splitlines()]
    assert written["max_alpha"] is None and written["eye"] == nav.pose_world()[0].tolist()
    assert Replay(None, (), None).dt(10.0, 9.99) == pytest.approx(0.01)
