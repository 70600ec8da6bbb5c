"""MapSession: the map tools of one viewer session, between frames.

- cursor readout: hovering ray-casts h_T (``map_tools.ray_hit``, no GL work); a frame drawn
  with world positions reads the drawn point instead;
- measure: clicks wait for the next frame, drawn with world positions (an extra pass, exact,
  only on click frames); two points give the distances and an elevation profile (PNG + CSV
  in the screenshot folder);
- bookmarks: the current pose saved by name (map_tools.Bookmarks); a fly-to is a flight of
  FLIGHT_FRAMES eased poses that owns the camera until it lands.

The pure tools are in map_tools.py; this class keeps their state and the viewer's messages.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from approxtree.render.frame_state import display_scale
from approxtree.viewer.controllers import cursor_ray, to_world
from approxtree.viewer.map_tools import (
    Bookmarks,
    LonLat,
    Readout,
    distances,
    profile,
    ray_hit,
    read_point,
    readout,
    save_profile,
    timestamp,
)
from approxtree.viewer.navigation import Navigation
from approxtree.viewer.settings import ViewSettings
from approxtree.viewer.window import Window

#: Frames of a fly-to flight.
FLIGHT_FRAMES = 30


class MapSession:
    """Cursor readout, measure, profile, bookmarks and fly-to over ``tree``.

    settings, nav, window: the viewer's; bookmarks: its bookmark file; folder: where
    profiles are written; messages: the viewer's message list (shown in the Map panel).
    """

    def __init__(
        self,
        settings: ViewSettings,
        tree: Any,
        nav: Navigation,
        window: Window,
        bookmarks: Bookmarks,
        folder: Path,
        messages: list[str],
    ) -> None:
        self.settings = settings
        self.terrain = tree.terrain
        self.nav = nav
        self.window = window
        self.bookmarks = bookmarks
        self.folder = folder
        self.messages = messages
        # Lengths in display units at exaggeration 1; lon/lat of the data's CRS.
        self.unit_scale = display_scale(tree.terrain)
        self.lonlat = LonLat(tree.terrain.crs)
        # The cursor (window coordinates) and where the last readout was taken.
        self.mouse: tuple[float, float] | None = None
        self._mouse_read: tuple[float, float] | None = None
        self._pose_read: tuple | None = None
        self.cursor_readout: Readout | None = None
        # Measure clicks waiting for a frame with positions, points (world) and result.
        self._clicks: list[tuple[float, float]] = []
        self.measure_points: list[np.ndarray] = []
        self.measurement: dict[str, Any] | None = None
        # The fly-to in progress (world poses still to take) and the last bookmark flown to.
        self._flight: list[tuple[np.ndarray, np.ndarray]] = []
        self._bookmark_index = -1

    # -- pointer ------------------------------------------------------------------------------

    def hover(self, x: float, y: float) -> None:
        """The cursor is at window position (x, y) (y down)."""
        self.mouse = (float(x), float(y))

    def click(self, x: float, y: float) -> None:
        """A measure click at window position (x, y), measured after the next frame."""
        self._clicks.append((float(x), float(y)))

    def toggle_measure(self) -> None:
        self.settings.tool = None if self.settings.tool == "measure" else "measure"
        self.measure_points = []

    # -- frames ---------------------------------------------------------------------------------

    def frame_wants(self) -> tuple[bool, bool]:
        """(positions, hover) for the coming frame: world positions when clicks wait; a hover
        readout when the interface is on and the cursor or the camera moved since the last."""
        pose = tuple(np.concatenate(self.nav.pose_world()).round(9))
        hover = (
            self.settings.ui
            and self.mouse is not None
            and (self.mouse != self._mouse_read or pose != self._pose_read)
        )
        if hover:
            self._pose_read = pose
        return bool(self._clicks), hover

    def after_frame(self, positions: np.ndarray | None, hover: bool) -> None:
        """After a frame: the hover readout when asked, then, with the frame's world
        positions (h, w, 4), the readout of the drawn point and the waiting clicks."""
        if hover:
            self._hover_readout()
        if positions is None:
            return
        if self.mouse is not None:
            p = read_point(positions, self.window.to_image(*self.mouse))
            self.cursor_readout = None if p is None else readout(self.terrain, p, self.lonlat)
        for x, y in self._clicks:
            p = read_point(positions, self.window.to_image(x, y))
            if p is None:
                self.messages.append("measure: no terrain under the click")
                continue
            if len(self.measure_points) >= 2:
                self.measure_points = []
            self.measure_points.append(p)
            if len(self.measure_points) == 2:
                self._measured()
        self._clicks = []

    def _hover_readout(self) -> None:
        """The cursor readout by a ray cast against h_T (``map_tools.ray_hit``): the ray
        through the cursor's pixel centre, its first crossing of the terrain.
        (Reading the window's depth buffer instead garbled the default framebuffer's colour
        read-back under Xvfb/llvmpipe, and a position pass per hover frame costs a second
        draw.) The drawn z is only known on click frames (position pass)."""
        if self.mouse is None:
            return
        self._mouse_read = self.mouse
        ix, iy = self.window.to_image(*self.mouse)
        w, h = self.window.framebuffer_size()
        c, r = int(ix), int(iy)
        self.cursor_readout = None
        if not (0 <= c < w and 0 <= r < h):
            return
        nav = self.nav
        cam = nav.controller
        ray = cursor_ray(cam.eye, cam.target, nav.fov, (w, h), (c + 0.5, h - (r + 0.5)))
        far = float(np.linalg.norm(cam.eye - cam.target)) + 2.0 * nav.diagonal()
        # The ray in world units: display → world divides each axis by the scale.
        eye = to_world(cam.eye, nav.origin, nav.scale)
        direction = to_world(cam.eye + ray, nav.origin, nav.scale) - eye
        hit = ray_hit(self.terrain, eye, direction, far)
        if hit is not None:
            self.cursor_readout = readout(self.terrain, hit, self.lonlat, drawn=False)

    def _measured(self) -> None:
        """Two points: distances and the elevation profile (PNG + CSV in the folder)."""
        a, b = self.measure_points
        horizontal, d3 = distances(a, b, self.unit_scale)
        samples = profile(self.terrain, a, b, self.unit_scale)
        self.folder.mkdir(parents=True, exist_ok=True)
        path = save_profile(samples, self.folder / f"profile-{timestamp()}.png")
        self.measurement = {
            "a": a.tolist(),
            "b": b.tolist(),
            "horizontal": horizontal,
            "distance_3d": d3,
            "profile": str(path),
            "profile_z": samples[:, 3].tolist(),
        }
        self.messages.append(f"profile {path}")

    # -- bookmarks and flights ------------------------------------------------------------------

    def save_bookmark(self, name: str | None = None) -> None:
        """Save the current pose under ``name`` (None: "view N", the next number)."""
        if name is None:
            name = f"view {len(self.bookmarks.names()) + 1}"
        self.bookmarks.save(name, *self.nav.pose_world())
        self.messages.append(f"bookmark {name!r} saved to {self.bookmarks.path}")

    def fly_to(self, name: str) -> None:
        """Fly to the bookmark ``name`` in FLIGHT_FRAMES frames (eased, world coordinates)."""
        eye1, target1 = self.bookmarks.get(name)
        eye0, target0 = self.nav.pose_world()
        t = np.arange(1, FLIGHT_FRAMES + 1) / FLIGHT_FRAMES
        w = t * t * (3.0 - 2.0 * t)
        self._flight = [(eye0 + k * (eye1 - eye0), target0 + k * (target1 - target0)) for k in w]

    def fly_to_next(self) -> None:
        """Fly to the bookmark after the last one flown to (none saved: nothing)."""
        names = self.bookmarks.names()
        if names:
            self._bookmark_index = (self._bookmark_index + 1) % len(names)
            self.fly_to(names[self._bookmark_index])

    @property
    def flying(self) -> bool:
        return bool(self._flight)

    def upcoming(self, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """The flight's next ``n`` world poses (eye, target) after the one taken next."""
        return self._flight[1 : 1 + n]

    def fly_on(self) -> None:
        """Take the flight's next pose."""
        self.nav.set_pose_world(*self._flight.pop(0))

    # -- stats ----------------------------------------------------------------------------------

    def figures(self) -> dict[str, Any]:
        """The stats line's map fields: cursor readout and measurement (without the
        profile's samples)."""
        m = self.measurement
        return {
            "cursor": None if self.cursor_readout is None else self.cursor_readout.as_dict(),
            "measure": None if m is None else {k: v for k, v in m.items() if k != "profile_z"},
        }
