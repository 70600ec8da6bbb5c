"""The viewer's map tools in a real window under Xvfb: legend, scale bar and north arrow are
drawn, the cursor readout and the measure tool report what the terrain has at the pixels,
the elevation profile samples h_T, bookmarks round-trip through their file."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from approxtree import ApproximationTree
from approxtree.datasets import sample_terrain
from approxtree.render.camera import Camera
from approxtree.render.frame_state import FrameState, display_scale
from approxtree.viewer.map_session import FLIGHT_FRAMES
from approxtree.viewer.map_tools import LonLat, nice_length
from approxtree.viewer.xvfb import virtual_display

SIZE = (640, 400)
EPSILON = 1.0


@pytest.fixture(scope="module")
def display():
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian/Ubuntu: apt-get install -y xvfb)")
    pytest.importorskip("imgui_bundle", reason="the viewer's interface needs imgui-bundle")
    with virtual_display("1280x1024x24") as name:
        yield name


@pytest.fixture(scope="module")
def session(display, tmp_path_factory):
    """One scripted viewer run over the sample terrain exercising every map tool; returns
    (tree, folder, stats lines by keyframe, script)."""
    tmp = tmp_path_factory.mktemp("map")
    tree = ApproximationTree.build(sample_terrain(), epsilon=EPSILON, progress=False)
    tree.save(tmp / "sample.zarr")
    b = np.asarray(tree.bboxes[0]).reshape(2, 3)
    c = b.mean(axis=0)
    c[2] = b[0, 2]
    # Poses in display units (metres: the sample terrain is geographic), back to world.
    scale = display_scale(tree.terrain)
    span = float(np.max((b[1, :2] - b[0, :2]) * scale[:2]))

    def at(dx: float, dy: float, dz: float) -> list[float]:
        return (c + np.array([dx, dy, dz]) * span / scale).tolist()

    south, east = at(0.0, -1.1, 0.8), at(1.1, 0.0, 0.8)
    # Nearly straight down (a small offset south keeps the view's up vector north).
    down = at(0.0, -0.02, 1.3)
    target = c.tolist()
    w, h = SIZE
    script = [
        {"eye": south, "target": target, "frames": 6},
        {"eye": south, "target": target, "frames": 1, "actions": [{"shot": "ui.png"}]},
        {"eye": south, "target": target, "frames": 1,
         "actions": [{"ui": False}, {"shot": "noui.png"}]},
        {"eye": east, "target": target, "frames": 3, "actions": [{"ui": True}]},
        {"eye": east, "target": target, "frames": 1, "actions": [{"shot": "east.png"}]},
        {"eye": down, "target": target, "frames": 4},
        {"eye": down, "target": target, "frames": 1, "actions": [
            {"click": [w * 0.35, h * 0.40]},
            {"click": [w * 0.62, h * 0.66]},
            # After the clicks (a click moves the cursor too).
            {"cursor": [w * 0.55, h * 0.45]},
            {"shot": "measure.png"},
        ]},
        {"eye": down, "target": target, "frames": 1, "actions": [
            # A hover without a click: a ray cast against h_T.
            {"cursor": [w * 0.3, h * 0.7]},
            {"bookmark": "straight down"},
        ]},
        {"eye": south, "target": target, "frames": 1, "keys": ["RIGHT", "UP", "UP"]},
        # The flight takes FLIGHT_FRAMES frames: the keyframe ends as it lands.
        {"eye": south, "target": target, "frames": FLIGHT_FRAMES,
         "actions": [{"fly_to": "straight down"}]},
    ]  # fmt: skip
    (tmp / "path.json").write_text(json.dumps(script))
    env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(tmp / "config"))
    result = subprocess.run(
        [
            sys.executable, "-m", "approxtree", "view", "sample.zarr", "--script", "path.json",
            "--stats", "stats.jsonl", "--screenshots", "shots", "--size", f"{w}x{h}",
            "--max-uploads", "0", "--bookmarks", "marks.json",
        ],
        cwd=tmp, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = [json.loads(s) for s in (tmp / "stats.jsonl").read_text().splitlines()]
    by_key = {s["keyframe"]: s for s in lines if s["keyframe"] is not None}
    return tree, tmp, by_key, lines, script


def shot(folder, name) -> np.ndarray:
    return np.asarray(Image.open(folder / "shots" / name)).astype(int)


def box_change(a: np.ndarray, b: np.ndarray, box) -> float:
    """Share of pixels inside ``box`` (x0, y0, x1, y1) that differ by more than 20 levels."""
    x0, y0, x1, y1 = (round(v) for v in box)
    d = np.abs(a[y0:y1, x0:x1] - b[y0:y1, x0:x1]).max(axis=2)
    return float((d > 20).mean())


def test_legend_and_scale_bar_are_drawn(session):
    """Pixels in the legend's and the scale bar's boxes change when the interface is shown;
    the legend is the elevation palette's (the terrain is untextured)."""
    _, tmp, by_key, _, _ = session
    ui, noui = shot(tmp, "ui.png"), shot(tmp, "noui.png")
    boxes = by_key[1]["ui"]
    assert by_key[2]["ui"] is None
    assert box_change(ui, noui, boxes["legend"]) > 0.3
    assert box_change(ui, noui, boxes["scale_bar"]) > 0.3
    # Away from every interface box the two screenshots are the same terrain (the region
    # stops left of the legend, whose width follows the palette's name).
    x1 = min(470, int(boxes["legend"][0]) - 1)
    assert x1 > 380
    assert np.abs(ui[250:340, 290:x1] - noui[250:340, 290:x1]).max() == 0
    # The bar's length is a nice number and its pixels fit the box.
    length, px = boxes["scale_length"], boxes["scale_px"]
    assert length == nice_length(length) and 0 < px <= 160


def test_north_arrow_turns_with_the_heading(session):
    """Seen from the south north is up; seen from the east it points right, in the stats and
    in the arrow's red needle pixels."""
    _, tmp, by_key, _, _ = session
    assert by_key[1]["ui"]["north_deg"] == pytest.approx(0.0, abs=1.0) or by_key[1]["ui"][
        "north_deg"
    ] == pytest.approx(360.0, abs=1.0)
    assert by_key[4]["ui"]["north_deg"] == pytest.approx(90.0, abs=1.0)

    def needle_angle(image, box):
        x0, y0, x1, y1 = (round(v) for v in box)
        part = image[y0:y1, x0:x1]
        red = (part[..., 0] > 150) & (part[..., 1] < 90) & (part[..., 2] < 90)
        rows, cols = np.nonzero(red)
        assert len(rows) > 20
        dx = cols.mean() - (x1 - x0) / 2
        dy = (y1 - y0) / 2 - rows.mean()
        return math.degrees(math.atan2(dx, dy)) % 360.0

    south = needle_angle(shot(tmp, "ui.png"), by_key[1]["ui"]["north_arrow"])
    east = needle_angle(shot(tmp, "east.png"), by_key[4]["ui"]["north_arrow"])
    assert min(south, 360 - south) < 10
    assert abs(east - 90) < 10


def _frame_state(tree, stats):
    cam = Camera.look_at(tuple(stats["eye"]), tuple(stats["target"]), fov=45.0)
    return FrameState.from_camera(
        cam, SIZE, tree.bboxes[0], tree.origin, display_scale(tree.terrain)
    )


def _picked(tree, stats, pixel):
    """World point where the ray through image ``pixel``'s centre meets h_T: the frame's own
    matrix inverted at the near and far planes, h_T sampled densely along the segment, the
    first crossing interpolated (independent of the viewer's code)."""
    fs = _frame_state(tree, stats)
    c, r = int(pixel[0]) + 0.5, SIZE[1] - (int(pixel[1]) + 0.5)
    ndc = np.array([2 * c / SIZE[0] - 1, 2 * r / SIZE[1] - 1])
    inv = np.linalg.inv(fs.world_to_clip)
    ends = []
    for z in (-1.0, 1.0):
        p = inv @ np.array([*ndc, z, 1.0])
        ends.append(p[:3] / p[3])
    t = np.linspace(0.0, 1.0, 200001)
    pts = ends[0] + t[:, None] * (ends[1] - ends[0])
    above = pts[:, 2] - tree.terrain.height_at(pts[:, 0], pts[:, 1])
    k = int(np.nonzero(np.nan_to_num(above, nan=1.0) <= 0)[0][0])
    f = above[k - 1] / (above[k - 1] - above[k])
    return pts[k - 1] + f * (pts[k] - pts[k - 1])


@pytest.mark.parametrize("key, action", [(6, 2), (7, 0)], ids=["positions", "ray"])
def test_cursor_readout_reports_the_terrain_elevation(session, key, action):
    """The readout's elevation is h_T where the cursor's ray meets the terrain, within ε; the
    drawn point lies within ε of it. On a click frame the readout comes from the Engine's
    position pass, on a hover frame from a ray cast."""
    tree, _, by_key, _, script = session
    s = by_key[key]
    r = s["cursor"]
    assert r is not None
    pixel = script[key]["actions"][action]["cursor"]
    expected = _picked(tree, s, pixel)
    z = r["z_drawn"] if key == 6 else r["elevation"]
    # The drawn point is h_T's within the cut's α: seen by the frame, the drawn surface and
    # h_T under the cursor lie within α = 1 px (from above a node's vertical error is seen
    # end-on, so coarser patches than the leaves may be drawn there).
    points = np.array([[r["x"], r["y"], z], [r["x"], r["y"], r["elevation"]]])
    drawn, true = _frame_state(tree, s).world_to_pixels(points)[0]
    assert np.linalg.norm(drawn - true) <= 1.0 + 1e-6
    assert r["elevation"] == pytest.approx(
        float(tree.terrain.height_at(np.array([r["x"]]), np.array([r["y"]]))[0])
    )
    assert abs(r["elevation"] - expected[2]) <= EPSILON
    # The readout's point is drawn in the cursor's pixel.
    px, _ = _frame_state(tree, s).world_to_pixels(np.array([[r["x"], r["y"], z]]))
    assert np.allclose(px[0], [int(pixel[0]) + 0.5, SIZE[1] - int(pixel[1]) - 0.5], atol=0.5)


def test_measure_and_profile(session):
    """Two clicks measure the distance between the points drawn under them; the profile file
    holds h_T sampled along the line."""
    tree, tmp, by_key, _, script = session
    s = by_key[6]
    m = s["measure"]
    assert m is not None
    clicks = [a["click"] for a in script[6]["actions"][0:2]]
    a, b = (_picked(tree, s, p) for p in clicks)
    scale = display_scale(tree.terrain)
    d = (b - a) * scale
    assert m["horizontal"] == pytest.approx(math.hypot(d[0], d[1]), rel=0.01)
    assert m["distance_3d"] == pytest.approx(float(np.linalg.norm(d)), rel=0.01)
    pa, pb = np.asarray(m["a"]), np.asarray(m["b"])
    assert m["horizontal"] == pytest.approx(float(np.hypot(*(pb - pa)[:2] * scale[:2])))
    # The profile: a PNG plot and its samples (distance, x, y, elevation) as CSV.
    png = tmp / m["profile"] if not os.path.isabs(m["profile"]) else m["profile"]
    assert Image.open(png).size[0] > 100
    samples = np.loadtxt(str(png)[:-4] + ".csv", delimiter=",")
    assert samples.shape == (256, 4)
    t = samples[:, 0] / samples[-1, 0]
    assert np.allclose(samples[:, 1], pa[0] + t * (pb[0] - pa[0]), atol=1e-6)
    assert np.allclose(samples[:, 2], pa[1] + t * (pb[1] - pa[1]), atol=1e-6)
    expected = tree.terrain.height_at(samples[:, 1], samples[:, 2])
    assert np.allclose(samples[:, 3], expected, rtol=1e-8, atol=1e-6)
    assert samples[-1, 0] == pytest.approx(m["horizontal"], rel=1e-8)


def test_bookmarks_round_trip(session):
    """A saved pose lands in the bookmark file; flying to it ends exactly there."""
    _, tmp, _, lines, script = session
    data = json.loads((tmp / "marks.json").read_text())
    (poses,) = data.values()
    saved = poses["straight down"]
    assert np.allclose(saved["eye"], script[5]["eye"]) and np.allclose(
        saved["target"], script[5]["target"]
    )
    last = lines[-1]
    assert np.allclose(last["eye"], saved["eye"]) and not last["flying"]
    # The flight moved through the frames in between, not in one jump.
    start = len(lines) - FLIGHT_FRAMES
    eyes = np.array([s["eye"] for s in lines[start - 1 :]])
    assert len({tuple(e) for e in eyes.round(6)}) > 10


def test_sun_keys_and_default_lighting(session):
    """RIGHT turns the sun 15° clockwise, UP raises it 5°, and the image changes; the viewer
    lights "auto" (untextured terrain lit, baked shading never twice) on a sky."""
    _, tmp, by_key, _, _ = session
    assert by_key[1]["sun"] == [315.0, 45.0] and by_key[1]["lighting"] == "auto"
    assert by_key[8]["sun"] == [330.0, 55.0]
    before, after = shot(tmp, "keyframe_001.png"), shot(tmp, "keyframe_008.png")
    assert np.abs(before - after).max(axis=2).mean() > 2
    # The sky: the top row is blue, not the black of an empty framebuffer.
    top = before[0].mean(axis=0)
    assert top[2] > top[0] + 30 and top[2] > 150


def test_lonlat_of_a_projected_point():
    """pyproj turns a UTM 17N point into the lon/lat of its zone's centre meridian."""
    lon, lat = LonLat("EPSG:32617")(500000.0, 4000000.0)
    assert lon == pytest.approx(-81.0, abs=1e-6) and 36.0 < lat < 36.2
    assert LonLat(None)(1.0, 2.0) == (None, None)


def test_nice_lengths_and_bookmark_errors(tmp_path):
    """Scale bar lengths are 1, 2 or 5 × 10^k; a broken bookmark file, an unknown bookmark
    and a bad script action each get a clear error."""
    from approxtree.errors import InvalidParameterError
    from approxtree.viewer.map_tools import Bookmarks
    from approxtree.viewer.script import parse_script

    assert [nice_length(v) for v in (1.0, 1.9, 2.0, 4.99, 7.0, 999.0, 0.03)] == [
        1.0, 1.0, 2.0, 2.0, 5.0, 500.0, 0.02,
    ]  # fmt: skip
    marks = Bookmarks(tmp_path / "b.json", "t")
    marks.save("a", np.zeros(3), np.ones(3))
    assert Bookmarks(tmp_path / "b.json", "t").names() == ["a"]
    assert Bookmarks(tmp_path / "b.json", "other").names() == []
    with pytest.raises(InvalidParameterError, match="No bookmark 'b'"):
        marks.get("b")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(InvalidParameterError, match="not valid JSON"):
        Bookmarks(tmp_path / "bad.json", "t")
    frame = {"eye": [0, 0, 1], "target": [0, 0, 0]}
    with pytest.raises(InvalidParameterError, match="unknown action 'zoom'"):
        parse_script([{**frame, "actions": [{"zoom": 2}]}])
    with pytest.raises(InvalidParameterError, match="bad value for action 'click'"):
        parse_script([{**frame, "actions": [{"click": [1]}]}])
