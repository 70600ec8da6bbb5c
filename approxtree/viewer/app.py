"""Viewer: a glfw window showing an approximation tree through the public Engine API.

The viewer is a composition of parts with one role each (parts.py lists them): the window
and its GL context, the FrameDriver (every call into the Engine), the cameras, the map
session, the input handler, the imgui interface, and the tables of what actions and script
actions do (actions.py, replay.py). This class builds them, runs the frame loop and frees
them.

A frame (``run``):

1. poll events; apply the scripted key presses of this frame through the key handler glfw
   calls; a fly-to in flight, else the script frame, sets the pose; the script frame's
   map-tool actions (replay.SCRIPT_ACTIONS);
2. move the fly camera by the held keys (scripted runs use a fixed 1/30 s step);
3. the terrain (FrameDriver.draw: paging within the upload budget, the frozen frustum);
   the map tools read the frame (cursor readout, measure clicks);
4. screenshots read the window's back buffer: the terrain only, before the interface, or,
   with ``furniture_in_shots``, after an interface frame of the map furniture alone (legend,
   scale bar, north arrow; the panels come back the next frame);
5. the interface (ui.Interface), window title, swap buffers; one stats line
   (replay.stats_line), written at the end when asked.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import Any

from approxtree.errors import InvalidParameterError
from approxtree.textures.detail import open_drape
from approxtree.textures.pyramid import TexturePyramid
from approxtree.tree.loading import load_tree
from approxtree.viewer.actions import ACTIONS
from approxtree.viewer.frame_driver import FrameDriver
from approxtree.viewer.input import Input
from approxtree.viewer.keys import KeyPress
from approxtree.viewer.map_session import MapSession
from approxtree.viewer.map_tools import (
    DEFAULT_SCREENSHOT_NAME,
    Bookmarks,
    default_bookmarks_path,
)
from approxtree.viewer.map_tools import screenshot_name as screenshot_name_of
from approxtree.viewer.map_ui import check_legend
from approxtree.viewer.navigation import Navigation
from approxtree.viewer.replay import Replay, frame_title, stats_line
from approxtree.viewer.script import ScriptFrame
from approxtree.viewer.settings import ViewSettings
from approxtree.viewer.ui import Interface
from approxtree.viewer.window import Window

#: Poses of a fly-to flight ahead of the current one whose cuts the paging prefetches.
FLIGHT_LOOKAHEAD = 8


class Viewer:
    """An interactive window over ``tree``.

    textures: texture pyramids, their folders or DetailTextures (thematic layers, cycled with
    TAB); size: window
    (w, h); alpha, gamma: initial thresholds; fov: degrees; max_uploads, budget_ms: the
    per-frame upload budget (0 and None: no budget, every frame waits for its whole cut);
    screenshot_dir: where P writes its PNGs (and the measure tool its profiles);
    screenshot_name: their file name, with {time} and {n} (``map_tools.screenshot_name``);
    furniture_in_shots: P and keyframe screenshots keep the map furniture; visible: show
    the window (False for benchmarks that only need the context). exaggeration, sun
    (azimuth, altitude), palette, background, lighting: the carto picture options
    (Engine and ``Engine.render``); legend: the land-cover legend of the thematic layer
    ("nlcd", "landclass96"; None: the hypsometric palette's legend when untextured);
    bookmarks: the bookmark file (default ``default_bookmarks_path()``); source: the key of
    this terrain in it (the opened path). follow: when ``source`` is a tree store folder, show
    its updates by another process (``approxtree update``) and the re-bakes of the texture
    pyramids given as folders, live (render/live.py).
    """

    def __init__(
        self,
        tree: Any,
        textures: Sequence[Any] = (),
        size: tuple[int, int] = (1280, 720),
        alpha: float = 1.0,
        gamma: float = 2.0,
        fov: float = 45.0,
        max_uploads: int = 32,
        budget_ms: float | None = None,
        screenshot_dir: str | Path = ".",
        screenshot_name: str = DEFAULT_SCREENSHOT_NAME,
        furniture_in_shots: bool = False,
        title: str = "approxtree viewer",
        visible: bool = True,
        exaggeration: float = 1.0,
        sun: tuple[float, float] = (315.0, 45.0),
        palette: str | None = None,
        background: str = "sky",
        lighting: str = "auto",
        legend: str | None = None,
        bookmarks: str | Path | None = None,
        source: str | None = None,
        follow: bool = True,
    ) -> None:
        # 1. What needs no window fails first: settings, legend, texture folders.
        self.settings = ViewSettings(
            alpha=float(alpha),
            gamma=float(gamma),
            exaggeration=float(exaggeration),
            sun_azimuth=float(sun[0]),
            sun_altitude=float(sun[1]),
            lighting=str(lighting),
            furniture_in_shots=bool(furniture_in_shots),
        )
        check_legend(legend)
        # A bad file name fails before the window opens.
        screenshot_name_of(screenshot_name, 1)
        self.screenshot_name = screenshot_name
        self.screenshots_taken = 0
        self.legend = legend
        self.title = title
        self.screenshot_dir = Path(screenshot_dir)
        self.pyramids: list[Any] = [open_drape(d) for d in textures]
        self.messages: list[str] = []
        # 2. The window, the Engine drawing into it, the cameras (home: the overview).
        self.window = Window(size, title, visible)
        self.driver = FrameDriver(
            tree,
            self.window.ctx,
            self.settings,
            exaggeration=exaggeration,
            palette=palette,
            background=background,
            max_uploads=max_uploads,
            budget_ms=budget_ms,
        )
        self.nav = Navigation(self.settings, tree, self.driver.scale, fov, size)
        # 3. Map tools, interface, and the input that drives them all.
        marks = Bookmarks(
            bookmarks if bookmarks is not None else default_bookmarks_path(),
            str(Path(source).resolve()) if source else "(unsaved terrain)",
        )
        self.map = MapSession(
            self.settings, tree, self.nav, self.window, marks, self.screenshot_dir, self.messages
        )
        self.interface = Interface(self)
        self.input = Input(
            self.window, self.settings, self.nav, self.map, self.interface.gui, self.do
        )
        if self.pyramids:
            self.apply_textures()
        if follow:
            self._follow(source)
        self.frame_state: Any = None
        self._screenshot_due = False
        self.window.listen(self.input)

    # -- what changes several parts -------------------------------------------------------------

    def do(self, action: str) -> None:
        """Carry out the action named ``action`` (keys.BINDINGS, actions.ACTIONS)."""
        fn = ACTIONS.get(action)
        if fn is None:
            raise InvalidParameterError(
                f"Unknown action {action!r}; use one of {', '.join(ACTIONS)}."
            )
        fn(self)

    def set_exaggeration(self, factor: float) -> None:
        """Draw z times ``factor``; the camera stays where it is in the world, the frozen
        cut (made at the former scale) is let go."""
        self.driver.set_exaggeration(factor)
        self.driver.thaw()
        self.settings.exaggeration = factor
        self.settings.frozen = False
        self.nav.rescale(self.driver.scale)

    def apply_textures(self) -> None:
        """Give the Engine the texture layer the settings choose (none when thematic is off)."""
        s = self.settings
        pyramid = self.pyramids[s.texture_index] if (self.pyramids and s.thematic) else None
        self.driver.set_textures(pyramid)

    def _follow(self, source: str | None) -> None:
        """Follow the store ``source`` (a folder holding a tree store) and the pyramids."""
        store = Path(source) if source else None
        if store is not None and not (store / "zarr.json").is_file():
            store = None
        folders = [p.folder for p in self.pyramids if isinstance(p, TexturePyramid)]
        if store is not None or folders:
            self.driver.follow(store, folders, partial(load_tree, verify=False))

    def _take_changes(self) -> None:
        """Give the parts that read the terrain the tree the last frames followed, and the
        texture list the re-baked pyramids."""
        for change in self.driver.take_changes():
            if change.tree is not None:
                self.nav.terrain = self.map.terrain = change.tree.terrain
                kept = 0 if change.kept is None else int((change.kept >= 0).sum())
                self.messages.append(f"store updated: {kept} of {len(change.tree)} nodes kept")
            for folder, pyramid in change.pyramids.items():
                self.pyramids = [
                    pyramid if getattr(p, "folder", None) == folder else p for p in self.pyramids
                ]
                self.messages.append(f"textures re-baked: {folder}")

    def request_screenshot(self) -> None:
        self._screenshot_due = True

    # -- frames ---------------------------------------------------------------------------------

    def render_frame(self) -> dict[str, Any]:
        """Draw one frame's terrain into the window's back buffer; returns its stats. The
        frame also reads the drawn world positions when a measure click waits."""
        positions, hover = self.map.frame_wants()
        # A fly-to knows where the view goes: the paging prefetches those cuts.
        path = [self.nav.camera_at(*pose) for pose in self.map.upcoming(FLIGHT_LOOKAHEAD)]
        frame = self.driver.draw(
            self.nav.camera(), self.window.framebuffer_size(), positions, path=path
        )
        self._take_changes()
        self.frame_state = frame.frame_state
        self.map.after_frame(frame.positions, hover)
        return dict(frame.stats)

    def run(
        self,
        script: Sequence[ScriptFrame] | None = None,
        key_presses: Sequence[KeyPress] = (),
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
        replay = Replay(script, key_presses, stats_path, screenshots, self.screenshot_dir)
        frames = 0
        last = time.perf_counter()
        while not self.window.closing and not replay.ended(frames):
            if max_frames is not None and frames >= max_frames:
                break
            t0 = time.perf_counter()
            dt, last = replay.dt(t0, last), t0
            step = self._input(replay, frames, dt)
            size = self.window.framebuffer_size()
            if size[0] == 0 or size[1] == 0:
                # Minimised: nothing to draw.
                self.window.idle(0.1)
                continue
            self._frame(replay, frames, step, size, t0, dt)
            frames += 1
            # A scripted replay lets this frame's requests load before the next frame, so a
            # script draws the same frames on any machine (outside frame_ms).
            if replay.scripted:
                self.driver.settle()
        replay.write()
        return frames

    def _input(self, replay: Replay, frame: int, dt: float) -> ScriptFrame | None:
        """Steps 1-2 of a frame: events, scripted presses and pose, actions, fly."""
        self.window.poll()
        pressed = replay.presses(frame)
        step = replay.step(frame)
        for key, mods in pressed:
            self.input.press(key, mods)
        # A fly-to flight owns the camera until it lands; otherwise the script's pose.
        if self.map.flying:
            self.map.fly_on()
        elif step is not None:
            self.nav.set_pose_world(step.eye, step.target)
        if step is not None:
            replay.act(self, step)
        self.nav.fly_step(self.input.held, dt)
        for key, mods in pressed:
            self.input.press(key, mods, action=self.window.glfw.RELEASE)
        return step

    def _frame(
        self,
        replay: Replay,
        frame: int,
        step: ScriptFrame | None,
        size: tuple[int, int],
        t0: float,
        dt: float,
    ) -> None:
        """Steps 3-5 of a frame: terrain, screenshots, interface, title, stats line."""
        stats = self.render_frame()
        shots = self._shots_due(replay, step)
        furniture = bool(shots) and self.settings.furniture_in_shots
        if not furniture:
            for path in shots:
                self.window.save_png(path)
        frame_ms = (time.perf_counter() - t0) * 1e3
        boxes = self.interface.draw(self.frame_state, stats, size, dt, furniture_only=furniture)
        for path in [*(shots if furniture else []), *replay.take_ui_shots()]:
            self.window.save_png(path)
        self.window.show(frame_title(self.title, stats, frame_ms))
        frame_ms = (time.perf_counter() - t0) * 1e3
        replay.record(stats_line(stats, frame, frame_ms, size, step, self, boxes))

    def _shots_due(self, replay: Replay, step: ScriptFrame | None) -> list[Path]:
        """The screenshots this frame takes: a completed keyframe's, P's (its name told in
        the messages)."""
        shots = []
        keyframe = replay.keyframe_shot(step)
        if keyframe is not None:
            shots.append(keyframe)
        if self._screenshot_due:
            self._screenshot_due = False
            self.screenshots_taken += 1
            name = screenshot_name_of(self.screenshot_name, self.screenshots_taken)
            path = self.screenshot_dir / name
            shots.append(path)
            self.messages.append(f"screenshot {path}")
        return shots

    def close(self) -> None:
        """Free the interface and the engine, close the window and end glfw."""
        self.interface.release()
        self.driver.release()
        self.window.close()

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
