"""ViewerParts: what the viewer (app.Viewer) offers to its actions, its script actions and its
interface — the parts it is made of and the few verbs that change several of them.

    window      Window        glfw window and GL context          (window.py)
    driver      FrameDriver   every call into the Engine          (frame_driver.py)
    nav         Navigation    orbit and fly cameras               (navigation.py)
    map         MapSession    readout, measure, bookmarks, fly-to (map_session.py)
    input       Input         glfw and scripted events            (input.py)
    settings    ViewSettings  what keys and panels change         (settings.py)

Actions (actions.py) and script actions (replay.py) are functions of a ViewerParts, so they
are tables, not branches of one method.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

from approxtree.viewer.frame_driver import FrameDriver
from approxtree.viewer.input import Input
from approxtree.viewer.map_session import MapSession
from approxtree.viewer.navigation import Navigation
from approxtree.viewer.settings import ViewSettings
from approxtree.viewer.window import Window


class ViewerParts(Protocol):
    """The viewer as its actions and interface see it (see the module docstring).

    pyramids: the texture pyramids TAB cycles through; legend: the land-cover legend's name
    (None: the palette's); screenshot_dir: where P and script shots without --screenshots go;
    messages: lines shown in the Map panel.
    """

    settings: ViewSettings
    window: Window
    driver: FrameDriver
    nav: Navigation
    map: MapSession
    input: Input
    pyramids: list[Any]
    legend: str | None
    screenshot_dir: Path
    messages: list[str]

    def do(self, action: str) -> None:
        """Carry out the action named ``action`` (keys.BINDINGS' names)."""
        ...

    def set_exaggeration(self, factor: float) -> None:
        """Draw z times ``factor``, the camera staying where it is in the world."""
        ...

    def apply_textures(self) -> None:
        """Give the Engine the texture layer the settings choose (or none)."""
        ...

    def request_screenshot(self) -> None:
        """Save a timestamped screenshot after the next frame's terrain is drawn."""
        ...
