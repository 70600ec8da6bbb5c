"""Viewer: a glfw window showing an approximation tree through the public Engine API.

The window owns an OpenGL 3.3 core context (glfw), wrapped by moderngl; the Engine is
embedded in it (``Engine(tree, context=ctx)``) and draws into the window's framebuffer.
Input goes through one handler per glfw callback; scripted key presses (``--keys``, keyframe
``keys``) call the same key handler glfw calls, so a replay exercises the real input path.

A frame:

1. poll events; apply the scripted key presses of this frame; in a replay, take the pose of
   the script frame;
2. move the fly camera by the held keys (scripted runs use a fixed 1/30 s step);
3. ``engine.render(..., wait=False)`` into the window: the Engine's traversal requests the
   missing patches from its provider (background loads) and draws their nearest resident
   ancestors meanwhile, uploading at most ``max_uploads`` meshes (``budget_ms``) per frame;
   the frozen frustum, when on, replaces the selection's view (the selection filter);
4. screenshots read the window's back buffer (terrain only, before the interface);
5. the map interface (imgui, map_ui.py): cursor readout from the frame's world positions,
   measure clicks, scale bar, north arrow, legend, panels; window title; swap buffers; one
   JSON line of stats when asked.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import ContextUnavailableError, InvalidParameterError
from approxtree.io.atomic import atomic_write
from approxtree.render.cut import Cut
from approxtree.render.frame_state import overview_camera
from approxtree.render.style import Style, Sun
from approxtree.render.traversal import Paging
from approxtree.viewer.controllers import (
    FlyController,
    OrbitController,
    cursor_ray,
    pick_terrain,
    to_display,
    to_world,
)
from approxtree.viewer.features import EngineFeatures
from approxtree.viewer.keys import FLY_KEYS, MOD_SHIFT, KeyPress, action_for, help_lines
from approxtree.viewer.map_tools import (
    Bookmarks,
    LonLat,
    Readout,
    default_bookmarks_path,
    distances,
    profile,
    ray_hit,
    read_point,
    readout,
    save_profile,
)
from approxtree.viewer.script import ScriptFrame

#: Threshold and exaggeration steps of one key press.
THRESHOLD_STEP, EXAGGERATION_STEP = 1.5, 1.25
#: Zoom factor per wheel notch, fly speed (root box diagonals per second), shift multiplier.
ZOOM_STEP, FLY_SPEED, FAST = 0.85, 0.1, 4.0
#: Time step of scripted frames (seconds), so replays move the same on any machine.
SCRIPT_DT = 1.0 / 30.0
#: Sun steps of one key press (degrees); frames of a fly-to flight; lighting cycle (H).
SUN_AZIMUTH_STEP, SUN_ALTITUDE_STEP, FLIGHT_FRAMES = 15.0, 5.0, 30
LIGHTING_MODES = ("auto", "on", "off")
#: A press and release closer than this (window pixels) is a click, not a drag.
CLICK_SLOP = 4.0

_INSTALL_HINT = (
    "The viewer needs a display: run it on a desktop, or under a virtual X server "
    "(Debian/Ubuntu: apt-get install -y xvfb; then xvfb-run -a approxtree view ...)."
)


@dataclass
class ViewSettings:
    """What the keys and the panel change. alpha: px; gamma: px²; exaggeration: z factor;
    lighting: "auto", "on" or "off"; sun: degrees; ui: the map interface shown; tool: the
    active map tool ("measure") or None."""

    alpha: float = 1.0
    gamma: float = 2.0
    wireframe: bool = False
    skirts: bool = True
    exaggeration: float = 1.0
    thematic: bool = True
    texture_index: int = 0
    lighting: str = "auto"
    frozen: bool = False
    help: bool = False
    fly: bool = False
    sun_azimuth: float = 315.0
    sun_altitude: float = 45.0
    ui: bool = True
    tool: str | None = None


def _glfw():
    try:
        import glfw
    except ImportError as exc:  # pragma: no cover - glfw is a dependency
        raise ContextUnavailableError(f"The glfw package is missing ({exc}).") from exc
    return glfw


class Viewer:
    """An interactive window over ``tree``.

    textures: texture pyramid folders (thematic layers, cycled with TAB); size: window
    (w, h); alpha, gamma: initial thresholds; fov: degrees; max_uploads, budget_ms: the
    per-frame upload budget (0 and None: no budget, every frame waits for its whole cut);
    screenshot_dir: where P writes its PNGs (and the measure tool its profiles); visible: show
    the window (False for benchmarks that only need the context). exaggeration, sun
    (azimuth, altitude), palette, background, lighting: the carto picture options
    (Engine and ``Engine.render``); legend: the land-cover legend of the thematic layer
    ("nlcd", "landclass96"; None: the hypsometric palette's legend when untextured);
    bookmarks: the bookmark file (default ``default_bookmarks_path()``); source: the key of
    this terrain in it (the opened path).
    """

    def __init__(
        self,
        tree,
        textures: list[str] | tuple[str, ...] = (),
        size: tuple[int, int] = (1280, 720),
        alpha: float = 1.0,
        gamma: float = 2.0,
        fov: float = 45.0,
        max_uploads: int = 32,
        budget_ms: float | None = None,
        screenshot_dir: str | Path = ".",
        title: str = "approxtree viewer",
        visible: bool = True,
        exaggeration: float = 1.0,
        sun: tuple[float, float] = (315.0, 45.0),
        palette: str = "relief",
        background: str = "sky",
        lighting: str = "auto",
        legend: str | None = None,
        bookmarks: str | Path | None = None,
        source: str | None = None,
    ) -> None:
        import moderngl

        from approxtree.render.engine import Engine
        from approxtree.textures.pyramid import TexturePyramid

        self.tree = tree
        self.settings = ViewSettings(
            alpha=float(alpha),
            gamma=float(gamma),
            exaggeration=float(exaggeration),
            sun_azimuth=float(sun[0]),
            sun_altitude=float(sun[1]),
            lighting=str(lighting),
        )
        self.background = background
        self.legend = legend
        if legend is not None:
            from approxtree.textures.thematic import LEGENDS

            if legend not in LEGENDS:
                raise InvalidParameterError(
                    f"Unknown legend {legend!r}; choose one of {', '.join(LEGENDS)}."
                )
        self.fov = float(fov)
        self.title = title
        self.screenshot_dir = Path(screenshot_dir)
        self.pyramids = [TexturePyramid(d) for d in textures]
        glfw = self.glfw = _glfw()
        self._keycodes = {getattr(glfw, n): n[4:] for n in dir(glfw) if n.startswith("KEY_")}
        self._keynames = {v: k for k, v in self._keycodes.items()}
        # 1. Window and context: OpenGL 3.3 core, forward compatible (macOS needs it).
        if not glfw.init():
            raise ContextUnavailableError(f"glfw could not initialise. {_INSTALL_HINT}")
        for hint, value in (
            (glfw.CONTEXT_VERSION_MAJOR, 3),
            (glfw.CONTEXT_VERSION_MINOR, 3),
            (glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE),
            (glfw.OPENGL_FORWARD_COMPAT, True),
            (glfw.VISIBLE, bool(visible)),
        ):
            glfw.window_hint(hint, value)
        self.window = glfw.create_window(int(size[0]), int(size[1]), title, None, None)
        if not self.window:
            glfw.terminate()
            raise ContextUnavailableError(
                f"glfw could not open an OpenGL 3.3 core window. {_INSTALL_HINT}"
            )
        glfw.make_context_current(self.window)
        glfw.swap_interval(0)
        self.ctx = moderngl.create_context()
        # 2. The embedded engine, its per-frame upload budget and what it supports. Frames
        # page (Engine.render(wait=False)): the provider loads in the background, the
        # traversal draws resident ancestors meanwhile; only the root is read up front.
        self.engine = Engine(
            tree, context=self.ctx, exaggeration=float(exaggeration), palette=palette
        )
        self.features = EngineFeatures(self.engine)
        if max_uploads < 0:
            raise ValueError(f"max_uploads must be >= 0, got {max_uploads}")
        self.max_uploads = int(max_uploads)
        self.budget_ms = budget_ms
        # The root's mesh now: it also loads the compiled skirt kernels before frame 0.
        self.engine.upload(0)
        self._frozen_frame: Any = None
        from approxtree.viewer.imgui_renderer import ImguiRenderer
        from approxtree.viewer.map_ui import MapUI

        self.gui = ImguiRenderer(self.ctx, self.glfw.get_window_size(self.window))
        self.map_ui = MapUI(self)
        # Map tools: lon/lat of the data's CRS, the cursor (window coordinates), the last
        # readout, measure points (world) and result, bookmarks, a fly-to in progress.
        from approxtree.render.frame_state import display_scale

        self.unit_scale = display_scale(tree.terrain)
        self.lonlat = LonLat(tree.terrain.crs)
        self.mouse: tuple[float, float] | None = None
        self._mouse_read: tuple[float, float] | None = None
        self._press_at: tuple[float, float] | None = None
        self._clicks: list[tuple[float, float]] = []
        self.cursor_readout: Readout | None = None
        self.measure_points: list[np.ndarray] = []
        self.measurement: dict[str, Any] | None = None
        self.bookmarks = Bookmarks(
            bookmarks if bookmarks is not None else default_bookmarks_path(),
            str(Path(source).resolve()) if source else "(unsaved terrain)",
        )
        self._flight: list[tuple[np.ndarray, np.ndarray]] = []
        self._bookmark_index = -1
        self._ui_shots: list[Path] = []
        self.ui_boxes: dict[str, Any] = {}
        self._pose_read: tuple | None = None
        self.frame_state: Any = None
        if self.pyramids:
            self._apply_textures()
        # 3. Cameras: the overview pose is "home".
        home = overview_camera(tree.bboxes[0], self.engine.scale, fov=self.fov)
        self._home_world = (home.eye.copy(), home.target.copy())
        eye, target = self._to_display(*self._home_world)
        self.orbit = OrbitController(eye, target)
        self.fly = FlyController(eye, target)
        self.held: set[str] = set()
        self._drag: str | None = None
        self._cursor: tuple[float, float] | None = None
        self._pending_screenshot = False
        self.last_stats: dict[str, Any] = {}
        self.messages: list[str] = []
        self._fly_speed = FLY_SPEED * self._diagonal()
        self._install_callbacks()

    # -- coordinates ------------------------------------------------------------------------

    def _to_display(self, eye, target) -> tuple[np.ndarray, np.ndarray]:
        o, s = self.tree.origin, self.engine.scale
        return to_display(eye, o, s), to_display(target, o, s)

    def _diagonal(self) -> float:
        """Root box diagonal in display units."""
        b = np.asarray(self.tree.bboxes[0], dtype=np.float64).reshape(2, 3)
        return float(np.linalg.norm((b[1] - b[0]) * self.engine.scale))

    @property
    def controller(self) -> OrbitController | FlyController:
        return self.fly if self.settings.fly else self.orbit

    def pose_world(self) -> tuple[np.ndarray, np.ndarray]:
        """(eye, target) of the current camera, world coordinates."""
        c = self.controller
        o, s = self.tree.origin, self.engine.scale
        return to_world(c.eye, o, s), to_world(c.target, o, s)

    def set_pose_world(self, eye, target) -> None:
        """Put the current camera at world ``eye`` looking at ``target``."""
        self.controller.set_pose(*self._to_display(eye, target))

    # -- input ------------------------------------------------------------------------------

    def _install_callbacks(self) -> None:
        glfw, w = self.glfw, self.window
        glfw.set_key_callback(w, self.on_key)
        glfw.set_mouse_button_callback(w, self.on_mouse_button)
        glfw.set_cursor_pos_callback(w, self.on_cursor)
        glfw.set_scroll_callback(w, self.on_scroll)

    def press(self, key: str, mods: int = 0, action: int | None = None) -> None:
        """Send a key event for the key named ``key`` through the glfw key handler."""
        glfw = self.glfw
        code = self._keynames.get(key.upper())
        if code is None:
            raise InvalidParameterError(f"Unknown key {key!r}; use glfw key names (W, F1, TAB).")
        self.on_key(self.window, code, 0, glfw.PRESS if action is None else action, mods)

    def on_key(self, window, key: int, scancode: int, action: int, mods: int) -> None:
        """glfw key callback: held keys as state, bindings fire on press."""
        glfw = self.glfw
        name = self._keycodes.get(key)
        if name is None:
            return
        if action == glfw.RELEASE:
            self.held.discard(name)
            return
        if action == glfw.PRESS:
            self.held.add(name)
            if mods & MOD_SHIFT:
                self.held.add("LEFT_SHIFT")
        if action != glfw.PRESS or (self.settings.fly and name in FLY_KEYS):
            return
        act = action_for(name, mods)
        if act is not None:
            self.do(act)

    def do(self, action: str) -> None:
        """Carry out a bound action (see keys.BINDINGS)."""
        s = self.settings
        engine = self.engine
        if action == "help":
            s.help = not s.help
        elif action in ("alpha_down", "alpha_up"):
            s.alpha = s.alpha * (THRESHOLD_STEP if action == "alpha_up" else 1 / THRESHOLD_STEP)
        elif action in ("gamma_down", "gamma_up"):
            s.gamma = s.gamma * (THRESHOLD_STEP if action == "gamma_up" else 1 / THRESHOLD_STEP)
        elif action == "wireframe":
            s.wireframe = not s.wireframe
        elif action == "skirts":
            s.skirts = not s.skirts
            engine.set_skirts(s.skirts)
        elif action in ("exaggerate_up", "exaggerate_down"):
            step = EXAGGERATION_STEP if action == "exaggerate_up" else 1 / EXAGGERATION_STEP
            self._set_exaggeration(s.exaggeration * step)
        elif action == "thematic":
            s.thematic = not s.thematic
            self._apply_textures()
        elif action == "next_texture":
            if self.pyramids:
                s.texture_index = (s.texture_index + 1) % len(self.pyramids)
                s.thematic = True
            self._apply_textures()
        elif action == "shading":
            s.lighting = LIGHTING_MODES[(LIGHTING_MODES.index(s.lighting) + 1) % 3]
            self.messages.append(f"lighting {s.lighting}")
        elif action in ("sun_left", "sun_right"):
            step = SUN_AZIMUTH_STEP if action == "sun_right" else -SUN_AZIMUTH_STEP
            s.sun_azimuth = (s.sun_azimuth + step) % 360.0
        elif action in ("sun_up", "sun_down"):
            step = SUN_ALTITUDE_STEP if action == "sun_up" else -SUN_ALTITUDE_STEP
            s.sun_altitude = min(90.0, max(1.0, s.sun_altitude + step))
        elif action == "measure":
            s.tool = None if s.tool == "measure" else "measure"
            self.measure_points = []
        elif action == "bookmark":
            self.save_bookmark(f"view {len(self.bookmarks.names()) + 1}")
        elif action == "fly_to_next":
            names = self.bookmarks.names()
            if names:
                self._bookmark_index = (self._bookmark_index + 1) % len(names)
                self.fly_to(names[self._bookmark_index])
        elif action == "ui":
            s.ui = not s.ui
        elif action == "freeze":
            s.frozen = not s.frozen
            self._frozen_frame = None
            if s.frozen:
                size = self.framebuffer_size()
                self._frozen_frame = engine.frame_state(self._camera(), size)
        elif action == "screenshot":
            self._pending_screenshot = True
        elif action == "fly":
            eye, target = self.controller.eye, self.controller.target
            s.fly = not s.fly
            self.controller.set_pose(eye, target)
        elif action == "reset":
            s.fly = False
            self.orbit.set_pose(*self._to_display(*self._home_world))
        elif action == "quit":
            self.glfw.set_window_should_close(self.window, True)

    def _apply_textures(self) -> None:
        s = self.settings
        pyramid = self.pyramids[s.texture_index] if (self.pyramids and s.thematic) else None
        if not self.features.set_textures(pyramid) and self.pyramids:
            self.messages.append("textures: this Engine cannot draw texture pyramids yet")

    def _set_exaggeration(self, factor: float) -> None:
        # Keep the camera where it is in the world while the display scale changes.
        eye, target = self.pose_world()
        home = self._home_world
        self.engine.set_vertical_exaggeration(factor)
        self.settings.exaggeration = factor
        self._frozen_frame = None
        self.settings.frozen = False
        self.set_pose_world(eye, target)
        other = self.orbit if self.settings.fly else self.fly
        other.set_pose(*self._to_display(*home))

    # -- map tools ----------------------------------------------------------------------------

    def save_bookmark(self, name: str) -> None:
        """Save the current pose under ``name`` in the bookmark file."""
        self.bookmarks.save(name, *self.pose_world())
        self.messages.append(f"bookmark {name!r} saved to {self.bookmarks.path}")

    def fly_to(self, name: str) -> None:
        """Fly to the bookmark ``name`` in FLIGHT_FRAMES frames (eased, world coordinates)."""
        eye1, target1 = self.bookmarks.get(name)
        eye0, target0 = self.pose_world()
        t = np.arange(1, FLIGHT_FRAMES + 1) / FLIGHT_FRAMES
        w = t * t * (3.0 - 2.0 * t)
        self._flight = [(eye0 + k * (eye1 - eye0), target0 + k * (target1 - target0)) for k in w]

    def move_cursor(self, x: float, y: float) -> None:
        """Put the cursor at window position (x, y) (y down): readout and imgui follow."""
        self.mouse = (float(x), float(y))
        self.gui.mouse(x, y)

    def click(self, x: float, y: float) -> None:
        """A measure click at window position (x, y); switches the measure tool on."""
        self.settings.tool = "measure"
        self.move_cursor(x, y)
        self._clicks.append((float(x), float(y)))

    def legend_entries(self) -> dict[str, Any]:
        """What the legend shows: the thematic layer's classes (its legend name) when it is
        drawn, a note when a coloured layer has no legend named, else (untextured or baked
        shading only) the hypsometric palette's colours at LEGEND_STOPS elevations."""
        from approxtree.viewer.map_ui import LEGEND_STOPS

        s = self.settings
        if self.pyramids and s.thematic and self.legend is not None:
            from approxtree.textures.thematic import LEGENDS, ClassTable

            table = ClassTable.legend(self.legend)
            items = [
                (label, tuple(int(c) for c in table.colours[k][:3]))
                for k, (label, _) in LEGENDS[self.legend].items()
                if k in table.colours
            ]
            return {"kind": "classes", "title": self.legend, "items": items}
        if self.pyramids and s.thematic and not getattr(self.engine, "shade_texture", True):
            # A coloured layer whose legend was not named: the palette would mislead.
            return {
                "kind": "classes",
                "title": "colours of the texture layer (name a legend: --legend)",
                "items": [],
            }
        z0, z1 = self.tree.terrain.z_range
        zs = np.linspace(z1, z0, LEGEND_STOPS)
        palette = self.engine.palette
        rgb = palette.colours(zs, (z0, z1))
        items = [
            (float(z), tuple(round(255 * c) for c in col[:3]))
            for z, col in zip(zs, rgb, strict=True)
        ]
        return {"kind": "palette", "title": f"elevation ({palette.name})", "items": items}

    def _window_to_image(self, x: float, y: float) -> tuple[float, float]:
        """Window coordinates (y down) → image pixel (column, row from the top)."""
        px, py = self._window_to_pixel(x, y)
        return px, self.framebuffer_size()[1] - py

    def _hover_readout(self) -> None:
        """The cursor readout by a ray cast against h_T (``map_tools.ray_hit``): the ray
        through the cursor's pixel centre, its first crossing of the terrain.
        (Reading the window's depth buffer instead garbled the default framebuffer's colour
        read-back under Xvfb/llvmpipe, and a position pass per hover frame costs a second
        draw.) The drawn z is only known on click frames (position pass)."""
        assert self.mouse is not None
        self._mouse_read = self.mouse
        ix, iy = self._window_to_image(*self.mouse)
        w, h = self.framebuffer_size()
        c, r = int(ix), int(iy)
        self.cursor_readout = None
        if not (0 <= c < w and 0 <= r < h):
            return
        cam = self.controller
        ray = cursor_ray(cam.eye, cam.target, self.fov, (w, h), (c + 0.5, h - (r + 0.5)))
        far = np.linalg.norm(cam.eye - cam.target) + 2.0 * self._diagonal()
        # The ray in world units: display → world divides each axis by the scale.
        o, scale = self.tree.origin, self.engine.scale
        eye = to_world(cam.eye, o, scale)
        direction = to_world(cam.eye + ray, o, scale) - eye
        hit = ray_hit(self.tree.terrain, eye, direction, far)
        if hit is not None:
            self.cursor_readout = readout(self.tree.terrain, hit, self.lonlat, drawn=False)

    def _map_tools(self, frame) -> None:
        """After a frame with world positions: the cursor readout and pending clicks."""
        positions = frame.positions
        if positions is None:
            return
        if self.mouse is not None:
            p = read_point(positions, self._window_to_image(*self.mouse))
            self.cursor_readout = None if p is None else readout(self.tree.terrain, p, self.lonlat)
        for x, y in self._clicks:
            p = read_point(positions, self._window_to_image(x, y))
            if p is None:
                self.messages.append("measure: no terrain under the click")
                continue
            if len(self.measure_points) >= 2:
                self.measure_points = []
            self.measure_points.append(p)
            if len(self.measure_points) == 2:
                self._measured()
        self._clicks = []

    def _measured(self) -> None:
        """Two points: distances and the elevation profile (PNG + CSV in screenshot_dir)."""
        a, b = self.measure_points
        horizontal, d3 = distances(a, b, self.unit_scale)
        samples = profile(self.tree.terrain, a, b, self.unit_scale)
        stamp = time.strftime("%Y%m%d-%H%M%S") + f"-{int(time.time() * 1e3) % 1000:03d}"
        self.screenshot_dir.mkdir(parents=True, exist_ok=True)
        path = save_profile(samples, self.screenshot_dir / f"profile-{stamp}.png")
        self.measurement = {
            "a": a.tolist(),
            "b": b.tolist(),
            "horizontal": horizontal,
            "distance_3d": d3,
            "profile": str(path),
            "profile_z": samples[:, 3].tolist(),
        }
        self.messages.append(f"profile {path}")

    def on_mouse_button(self, window, button: int, action: int, mods: int) -> None:
        glfw = self.glfw
        if button < 5:  # imgui knows five mouse buttons
            self.gui.button(button, action == glfw.PRESS)
        if action == glfw.RELEASE:
            self._drag = None
            # A press and release in place with the measure tool is a measure click.
            pos = glfw.get_cursor_pos(window)
            if (
                self.settings.tool == "measure"
                and button == glfw.MOUSE_BUTTON_LEFT
                and self._press_at is not None
                and math.dist(pos, self._press_at) <= CLICK_SLOP
            ):
                self._clicks.append(pos)
            self._press_at = None
            return
        if self.gui.wants_mouse:
            return
        self._press_at = glfw.get_cursor_pos(window)
        if button == glfw.MOUSE_BUTTON_LEFT and not mods & MOD_SHIFT:
            self._drag = "rotate"
        else:
            self._drag = "pan"
        self._cursor = glfw.get_cursor_pos(window)

    def on_cursor(self, window, x: float, y: float) -> None:
        self.move_cursor(x, y)
        if self._drag is None or self._cursor is None:
            self._cursor = (x, y)
            return
        dx, dy = x - self._cursor[0], y - self._cursor[1]
        self._cursor = (x, y)
        self.drag(self._drag, dx, dy)

    def drag(self, kind: str, dx: float, dy: float) -> None:
        """A mouse drag of (dx, dy) window pixels: "rotate" (orbit, or look when flying) or
        "pan"."""
        if self.settings.fly:
            self.fly.look(dx, dy)
        elif kind == "rotate":
            self.orbit.orbit(dx, dy)
        else:
            self.orbit.pan(dx, dy, self.framebuffer_size()[1], self.fov)

    def on_scroll(self, window, xoff: float, yoff: float) -> None:
        self.gui.wheel(xoff, yoff)
        if self.gui.wants_mouse:
            return
        x, y = self.glfw.get_cursor_pos(window)
        self.wheel(yoff, self._window_to_pixel(x, y))

    def wheel(self, notches: float, pixel: tuple[float, float]) -> None:
        """Zoom towards the terrain under ``pixel`` (GL window coordinates); when flying,
        change the fly speed instead."""
        if self.settings.fly:
            self._fly_speed *= 1.25**notches
            return
        o = self.orbit
        size = self.framebuffer_size()
        ray = cursor_ray(o.eye, o.target, self.fov, size, pixel)
        far = np.linalg.norm(o.eye - o.target) + self._diagonal()
        point = pick_terrain(
            self.tree.terrain, self.tree.origin, self.engine.scale, o.eye, ray, far
        )
        o.zoom_to(o.target if point is None else point, ZOOM_STEP**notches)

    def _window_to_pixel(self, x: float, y: float) -> tuple[float, float]:
        """Window coordinates (y down, screen units) → framebuffer pixels (y up)."""
        ww, wh = self.glfw.get_window_size(self.window)
        fw, fh = self.framebuffer_size()
        sx, sy = fw / max(ww, 1), fh / max(wh, 1)
        return x * sx, fh - y * sy

    def framebuffer_size(self) -> tuple[int, int]:
        w, h = self.glfw.get_framebuffer_size(self.window)
        return int(w), int(h)

    # -- frames -----------------------------------------------------------------------------

    def _camera(self):
        return self.controller.camera(self.tree.origin, self.engine.scale, self.fov)

    def _fly_step(self, dt: float) -> None:
        if not self.settings.fly:
            return
        move = np.zeros(3)
        for key in self.held & FLY_KEYS.keys():
            move += FLY_KEYS[key]
        fast = FAST if self.held & {"LEFT_SHIFT", "RIGHT_SHIFT"} else 1.0
        self.fly.move(*move, self._fly_speed * fast * dt)

    def render_frame(self) -> dict[str, Any]:
        """Draw one frame into the window's back buffer; returns its stats. The frame also
        reads the drawn world positions (for the cursor readout) when the cursor moved or a
        measure click waits."""
        s = self.settings
        size = self.framebuffer_size()
        self.ctx.fbo.use()
        pose = tuple(np.concatenate(self.pose_world()).round(9))
        # Hover readouts ray-cast h_T (no GL work); measure clicks ask the Engine for the
        # drawn world positions (an extra pass, exact, only on click frames).
        want_positions = bool(self._clicks)
        want_depth = (
            s.ui
            and self.mouse is not None
            and (self.mouse != self._mouse_read or pose != self._pose_read)
        )
        if want_depth:
            self._pose_read = pose
        frame = self.engine.render(
            self._camera(),
            size,
            # While frozen, the cut of the frozen frustum.
            Cut(s.alpha, s.gamma, frozen=self._frozen_frame),
            style=Style(
                s.lighting, Sun(s.sun_azimuth, s.sun_altitude), self.background, s.wireframe
            ),
            # Without an upload budget every wanted mesh loads in the frame that wants it.
            paging=Paging(
                wait=not self.max_uploads and self.budget_ms is None,
                max_uploads=self.max_uploads or None,
                upload_ms=self.budget_ms,
            ),
        )
        if want_positions:
            self.engine.world_positions(frame)
        self.ctx.fbo.use()
        self.frame_state = frame.frame_state
        if want_depth:
            self._hover_readout()
        self._map_tools(frame)
        stats = dict(frame.stats)
        # The names of the former upload queue's figures, kept for stats files and benchmarks.
        stats["fallbacks"] = stats.get("stand_ins", 0)
        stats["upload_queue_ms"] = stats.get("upload_ms", 0.0)
        stats.setdefault("texture_switches", 0)
        return stats

    def screenshot(self, path: str | Path) -> Path:
        """Write the window's current back buffer to ``path`` as an RGB PNG (atomically)."""
        from PIL import Image

        w, h = self.framebuffer_size()
        raw = self.ctx.fbo.read(viewport=(0, 0, w, h), components=3, alignment=1)
        image = np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 3)[::-1]
        path = Path(path)
        with atomic_write(path) as f:
            Image.fromarray(np.ascontiguousarray(image), mode="RGB").save(f, format="PNG")
        return path

    def _title(self, stats: dict[str, Any], frame_ms: float) -> str:
        return (
            f"{self.title} — {frame_ms:.1f} ms, {stats['triangles']:,} triangles, "
            f"{stats['patches']} patches, {stats['texture_switches']} texture switches, "
            f"max α {stats['max_alpha']:.2f} px, max γ {stats['max_gamma']:.2f} px²"
        )

    def run(
        self,
        script: list[ScriptFrame] | None = None,
        key_presses: list[KeyPress] = (),
        stats_path: str | Path | None = None,
        screenshots: str | Path | None = None,
        max_frames: int | None = None,
    ) -> int:
        """Run the frame loop until the window closes, the script ends or ``max_frames``
        frames were drawn; returns the number of frames drawn.

        script: frames of a camera replay (see script.py); key_presses: scripted presses by
        frame; stats_path: one JSON line of stats per frame; screenshots: folder of one PNG
        per completed keyframe (``keyframe_000.png`` ...).
        """
        glfw = self.glfw
        by_frame: dict[int, list[KeyPress]] = {}
        for p in key_presses:
            by_frame.setdefault(p.frame, []).append(p)
        shots = Path(screenshots) if screenshots is not None else None
        if shots is not None:
            shots.mkdir(parents=True, exist_ok=True)
        lines: list[bytes] = []
        # Scripted runs (a replay or key presses) step time by SCRIPT_DT: same motion anywhere.
        scripted = script is not None or bool(by_frame)
        frames = 0
        last = time.perf_counter()
        while not glfw.window_should_close(self.window):
            if script is not None and frames >= len(script):
                break
            if max_frames is not None and frames >= max_frames:
                break
            t0 = time.perf_counter()
            glfw.poll_events()
            # 1. Scripted input through the key handler, then the script's pose.
            pressed = [(p.key, p.mods) for p in by_frame.get(frames, [])]
            step = script[frames] if script is not None else None
            if step is not None:
                from approxtree.viewer.keys import parse_key

                pressed += [parse_key(k) for k in step.keys]
            for key, mods in pressed:
                self.press(key, mods)
            # A fly-to flight owns the camera until it lands; otherwise the script's pose.
            if self._flight:
                self.set_pose_world(*self._flight.pop(0))
            elif step is not None:
                self.set_pose_world(step.eye, step.target)
            if step is not None:
                self._script_actions(step.actions, shots)
            # 2. Fly by held keys.
            dt = SCRIPT_DT if scripted else min(t0 - last, 0.25)
            last = t0
            self._fly_step(dt)
            for key, mods in pressed:
                self.press(key, mods, action=glfw.RELEASE)
            size = self.framebuffer_size()
            if size[0] == 0 or size[1] == 0:
                # Minimised: nothing to draw.
                glfw.wait_events_timeout(0.1)
                continue
            # 3-4. Terrain, screenshots.
            stats = self.render_frame()
            if step is not None and step.keyframe is not None and shots is not None:
                self.screenshot(shots / f"keyframe_{step.keyframe:03d}.png")
            if self._pending_screenshot:
                self._pending_screenshot = False
                stamp = time.strftime("%Y%m%d-%H%M%S") + f"-{int(time.time() * 1e3) % 1000:03d}"
                path = self.screenshot(self.screenshot_dir / f"approxtree-{stamp}.png")
                self.messages.append(f"screenshot {path}")
            # 5. Map interface, title, swap, stats line.
            frame_ms = (time.perf_counter() - t0) * 1e3
            self._draw_ui(stats, size, dt)
            for path in self._ui_shots:
                self.screenshot(path)
            self._ui_shots = []
            glfw.set_window_title(self.window, self._title(stats, frame_ms))
            glfw.swap_buffers(self.window)
            frame_ms = (time.perf_counter() - t0) * 1e3
            stats.update(frame=frames, frame_ms=round(frame_ms, 3), size=list(size))
            if step is not None:
                stats["keyframe"] = step.keyframe
            eye, target = self.pose_world()
            stats.update(
                alpha=self.settings.alpha,
                gamma=self.settings.gamma,
                eye=eye.tolist(),
                target=target.tolist(),
                mode="fly" if self.settings.fly else "orbit",
                frozen=self.settings.frozen,
                sun=[self.settings.sun_azimuth, self.settings.sun_altitude],
                exaggeration=self.settings.exaggeration,
                lighting=self.settings.lighting,
                cursor=None if self.cursor_readout is None else self.cursor_readout.as_dict(),
                measure=None
                if self.measurement is None
                else {k: v for k, v in self.measurement.items() if k != "profile_z"},
                ui=self.ui_boxes if self.settings.ui else None,
                flying=bool(self._flight),
            )
            self.last_stats = stats
            if stats_path is not None:
                lines.append((json.dumps(_json_safe(stats)) + "\n").encode())
            frames += 1
            # A scripted replay lets this frame's requests load before the next frame, so a
            # script draws the same frames on any machine (outside frame_ms).
            if scripted and getattr(self.engine, "provider", None) is not None:
                self.engine.provider.wait()
        if stats_path is not None:
            with atomic_write(stats_path) as f:
                f.writelines(lines)
        return frames

    def _script_actions(self, actions, shots: Path | None) -> None:
        """Carry out a script frame's map-tool actions (see script.py), pixels → window."""
        fw, fh = self.framebuffer_size()
        ww, wh = self.glfw.get_window_size(self.window)

        def window(xy) -> tuple[float, float]:
            return xy[0] * ww / max(fw, 1), xy[1] * wh / max(fh, 1)

        for name, value in actions:
            if name == "cursor":
                self.move_cursor(*window(value))
            elif name == "click":
                self.click(*window(value))
            elif name == "bookmark":
                self.save_bookmark(value)
            elif name == "fly_to":
                self.fly_to(value)
                self.set_pose_world(*self._flight.pop(0))
            elif name == "ui":
                self.settings.ui = bool(value)
            elif name == "shot":
                folder = shots if shots is not None else self.screenshot_dir
                self._ui_shots.append(folder / value)
            elif name == "sun":
                self.settings.sun_azimuth, self.settings.sun_altitude = map(float, value)
            elif name == "exaggeration":
                self._set_exaggeration(float(value))

    def _draw_ui(self, stats: dict[str, Any], size: tuple[int, int], dt: float) -> None:
        """The imgui frame: map interface and help when on (always ended, so imgui's state
        stays consistent when the interface is hidden)."""
        from imgui_bundle import imgui

        self.gui.new_frame(self.glfw.get_window_size(self.window), dt)
        self.ui_boxes = {}
        if self.settings.ui and self.frame_state is not None:
            self.ui_boxes = self.map_ui.draw(self.frame_state, stats, size)
            if self.settings.help:
                imgui.begin("Keys (F1)")
                for line in help_lines():
                    imgui.text(line)
                imgui.end()
        self.ctx.fbo.use()
        self.gui.render(size)

    def close(self) -> None:
        """Free the interface and the engine, close the window and end glfw."""
        self.gui.release()
        self.engine.release()
        self.ctx.release()
        self.glfw.destroy_window(self.window)
        self.glfw.terminate()

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _on(flag: bool) -> str:
    return "on" if flag else "off"


def _json_safe(stats: dict[str, Any]) -> dict[str, Any]:
    """JSON has no inf or NaN: report them as null."""
    return {
        k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in stats.items()
    }
