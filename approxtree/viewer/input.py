"""Input: glfw's events, and scripted ones, turned into what they mean for the viewer.

- keys: held keys are state (the fly camera reads them); a press fires the action bound to it
  (keys.BINDINGS) through ``act``, except the fly keys while flying;
- mouse: imgui sees every event first and keeps those over its windows; a left drag orbits
  (looks when flying), right/middle or shift+left pans; with the measure tool, a press and a
  release in place is a measure click; the wheel zooms towards the cursor;
- scripted presses (``press``) and the script's cursor and click actions (``move_cursor``,
  ``click``) go through the same handlers, so a replay exercises the real input path.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from approxtree.viewer.imgui_renderer import ImguiRenderer
from approxtree.viewer.keys import FLY_KEYS, MOD_SHIFT, action_for
from approxtree.viewer.map_session import MapSession
from approxtree.viewer.navigation import Navigation
from approxtree.viewer.settings import ViewSettings
from approxtree.viewer.window import Window

#: A press and release closer than this (window pixels) is a click, not a drag.
CLICK_SLOP = 4.0


class Input:
    """The window's event handler (``window.listen(input)``): keys to ``act(action)``,
    the mouse to the cameras (``nav``), the map tools (``map``) and imgui (``gui``)."""

    def __init__(
        self,
        window: Window,
        settings: ViewSettings,
        nav: Navigation,
        map: MapSession,
        gui: ImguiRenderer,
        act: Callable[[str], None],
    ) -> None:
        self.window = window
        self.settings = settings
        self.nav = nav
        self.map = map
        self.gui = gui
        self.act = act
        self.held: set[str] = set()
        # The drag in progress ("rotate", "pan"), the cursor it last moved from, and where
        # the button went down (a release there is a click).
        self._drag: str | None = None
        self._cursor: tuple[float, float] | None = None
        self._press_at: tuple[float, float] | None = None

    # -- keys -----------------------------------------------------------------------------------

    def press(self, key: str, mods: int = 0, action: int | None = None) -> None:
        """Send a key event for the key named ``key`` through the glfw key handler
        (``action``: glfw.PRESS by default, or glfw.RELEASE)."""
        glfw = self.window.glfw
        code = self.window.key_code(key)
        self.on_key(self.window.handle, code, 0, glfw.PRESS if action is None else action, mods)

    def on_key(self, window: Any, key: int, scancode: int, action: int, mods: int) -> None:
        """glfw key callback: held keys as state, bindings fire on press."""
        glfw = self.window.glfw
        name = self.window.key_name(key)
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
        bound = action_for(name, mods)
        if bound is not None:
            self.act(bound)

    # -- pointer --------------------------------------------------------------------------------

    def move_cursor(self, x: float, y: float) -> None:
        """Put the cursor at window position (x, y) (y down): readout and imgui follow."""
        self.map.hover(x, y)
        self.gui.mouse(x, y)

    def click(self, x: float, y: float) -> None:
        """A measure click at window position (x, y); switches the measure tool on."""
        self.settings.tool = "measure"
        self.move_cursor(x, y)
        self.map.click(x, y)

    def on_mouse_button(self, window: Any, button: int, action: int, mods: int) -> None:
        glfw = self.window.glfw
        if button < 5:  # imgui knows five mouse buttons
            self.gui.button(button, action == glfw.PRESS)
        if action == glfw.RELEASE:
            self._drag = None
            # A press and release in place with the measure tool is a measure click.
            pos = self.window.cursor()
            if (
                self.settings.tool == "measure"
                and button == glfw.MOUSE_BUTTON_LEFT
                and self._press_at is not None
                and math.dist(pos, self._press_at) <= CLICK_SLOP
            ):
                self.map.click(*pos)
            self._press_at = None
            return
        if self.gui.wants_mouse:
            return
        self._press_at = self.window.cursor()
        if button == glfw.MOUSE_BUTTON_LEFT and not mods & MOD_SHIFT:
            self._drag = "rotate"
        else:
            self._drag = "pan"
        self._cursor = self.window.cursor()

    def on_cursor(self, window: Any, x: float, y: float) -> None:
        self.move_cursor(x, y)
        if self._drag is None or self._cursor is None:
            self._cursor = (x, y)
            return
        dx, dy = x - self._cursor[0], y - self._cursor[1]
        self._cursor = (x, y)
        self.nav.drag(self._drag, dx, dy, self.window.framebuffer_size()[1])

    def on_scroll(self, window: Any, xoff: float, yoff: float) -> None:
        self.gui.wheel(xoff, yoff)
        if self.gui.wants_mouse:
            return
        x, y = self.window.cursor()
        self.nav.wheel(yoff, self.window.to_pixel(x, y), self.window.framebuffer_size())
