"""Navigation: the viewer's two cameras (orbit and fly) and how input moves them.

The controllers (controllers.py) work in display coordinates (world minus the tree's origin,
times the display scale, exaggeration included); poses given to or read from the viewer are
world coordinates. ``settings.fly`` says which camera is in use; "home" is the fitted view of
``approxtree render`` (``framing_camera``: the terrain fills the window, seen from the south).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from approxtree.render.camera import Camera
from approxtree.render.frame_state import framing_camera
from approxtree.viewer.controllers import (
    FlyController,
    OrbitController,
    cursor_ray,
    pick_terrain,
    to_camera,
    to_display,
    to_world,
)
from approxtree.viewer.keys import FLY_KEYS
from approxtree.viewer.settings import ViewSettings

#: Zoom factor per wheel notch, fly speed (root box diagonals per second), shift multiplier.
ZOOM_STEP, FLY_SPEED, FAST = 0.85, 0.1, 4.0


class Navigation:
    """Orbit and fly cameras over ``tree`` seen with display ``scale`` (3,) and ``fov``
    (degrees) in a window of ``size`` (w, h) pixels; ``settings.fly`` picks the one in use."""

    def __init__(
        self,
        settings: ViewSettings,
        tree: Any,
        scale: np.ndarray,
        fov: float,
        size: tuple[int, int] = (1280, 720),
    ) -> None:
        self.settings = settings
        self.terrain = tree.terrain
        self.origin = tree.origin
        self.root_box = np.asarray(tree.bboxes[0], dtype=np.float64).reshape(2, 3)
        self.scale = scale
        self.fov = float(fov)
        home = framing_camera(tree.bboxes[0], scale, size, fov=self.fov)
        self.home_world = (home.eye.copy(), home.target.copy())
        eye, target = self.to_display(*self.home_world)
        self.orbit = OrbitController(eye, target)
        self.fly = FlyController(eye, target)
        self.fly_speed = FLY_SPEED * self.diagonal()

    # -- coordinates ----------------------------------------------------------------------------

    def to_display(self, eye: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (eye, target) (3,) each → display coordinates."""
        o, s = self.origin, self.scale
        return to_display(eye, o, s), to_display(target, o, s)

    def diagonal(self) -> float:
        """Root box diagonal in display units."""
        b = self.root_box
        return float(np.linalg.norm((b[1] - b[0]) * self.scale))

    @property
    def controller(self) -> OrbitController | FlyController:
        return self.fly if self.settings.fly else self.orbit

    def pose_world(self) -> tuple[np.ndarray, np.ndarray]:
        """(eye, target) of the current camera, world coordinates."""
        c = self.controller
        return to_world(c.eye, self.origin, self.scale), to_world(c.target, self.origin, self.scale)

    def set_pose_world(self, eye: np.ndarray, target: np.ndarray) -> None:
        """Put the current camera at world ``eye`` looking at ``target``."""
        self.controller.set_pose(*self.to_display(eye, target))

    def camera(self) -> Camera:
        """The current camera for the Engine."""
        return self.controller.camera(self.origin, self.scale, self.fov)

    def camera_at(self, eye: np.ndarray, target: np.ndarray) -> Camera:
        """The Engine's camera at world ``eye`` looking at ``target``; the pose stays."""
        display_eye, display_target = self.to_display(eye, target)
        return to_camera(display_eye, display_target, self.origin, self.scale, self.fov)

    def rescale(self, scale: np.ndarray) -> None:
        """A new display scale (exaggeration): the current camera keeps its world pose, the
        other one goes home."""
        eye, target = self.pose_world()
        self.scale = scale
        self.set_pose_world(eye, target)
        other = self.orbit if self.settings.fly else self.fly
        other.set_pose(*self.to_display(*self.home_world))

    # -- moves ----------------------------------------------------------------------------------

    def toggle_fly(self) -> None:
        """Switch between orbit and fly, keeping the pose."""
        eye, target = self.controller.eye, self.controller.target
        self.settings.fly = not self.settings.fly
        self.controller.set_pose(eye, target)

    def reset(self) -> None:
        """Back to orbiting from home."""
        self.settings.fly = False
        self.orbit.set_pose(*self.to_display(*self.home_world))

    def fly_step(self, held: set[str], dt: float) -> None:
        """Fly by the ``held`` keys for ``dt`` seconds (nothing in orbit mode)."""
        if not self.settings.fly:
            return
        move = np.zeros(3)
        for key in held & FLY_KEYS.keys():
            move += FLY_KEYS[key]
        fast = FAST if held & {"LEFT_SHIFT", "RIGHT_SHIFT"} else 1.0
        self.fly.move(move[0], move[1], move[2], self.fly_speed * fast * dt)

    def drag(self, kind: str, dx: float, dy: float, height: int) -> None:
        """A mouse drag of (dx, dy) window pixels in a framebuffer ``height`` pixels high:
        "rotate" (orbit, or look when flying) or "pan"."""
        if self.settings.fly:
            self.fly.look(dx, dy)
        elif kind == "rotate":
            self.orbit.orbit(dx, dy)
        else:
            self.orbit.pan(dx, dy, height, self.fov)

    def wheel(self, notches: float, pixel: tuple[float, float], size: tuple[int, int]) -> None:
        """Zoom towards the terrain under ``pixel`` (GL window coordinates) of a framebuffer
        of ``size``; when flying, change the fly speed instead."""
        if self.settings.fly:
            self.fly_speed *= 1.25**notches
            return
        o = self.orbit
        ray = cursor_ray(o.eye, o.target, self.fov, size, pixel)
        far = float(np.linalg.norm(o.eye - o.target)) + self.diagonal()
        point = pick_terrain(self.terrain, self.origin, self.scale, o.eye, ray, far)
        o.zoom_to(o.target if point is None else point, ZOOM_STEP**notches)
