"""Camera controllers with the habits of terrain viewers: orbit, pan, zoom to the cursor, fly.

Controllers work in *display coordinates*: ``(world − origin) × scale`` with the engine's
display scale (metres for geographic terrains, z times the vertical exaggeration), so that
rotating and flying behave the same over every CRS. ``camera(origin, scale, fov)`` turns the
pose back into a world-space Camera for the Engine. Nothing here touches a window or GL, so
every motion is tested without one.
"""

from __future__ import annotations

import math

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.camera import Camera

#: Pitch limits (radians below the horizon) of the orbit: never flip over the zenith.
MIN_PITCH, MAX_PITCH = math.radians(2.0), math.radians(89.5)
#: Fly-mode pitch limit (radians above or below the horizon).
FLY_PITCH = math.radians(89.0)


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n == 0.0 or not math.isfinite(n):
        raise InvalidParameterError(f"Cannot normalise the vector {tuple(v)}.")
    return v / n


def view_basis(eye: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(forward, right, up) unit vectors (3,) of a view, with the +z up hint (+y when looking
    straight down or up, as FrameState does)."""
    f = _unit(np.asarray(target, dtype=np.float64) - np.asarray(eye, dtype=np.float64))
    hint = np.array([0.0, 0.0, 1.0])
    if np.linalg.norm(np.cross(f, hint)) <= 1e-9:
        hint = np.array([0.0, 1.0, 0.0])
    r = _unit(np.cross(f, hint))
    return f, r, np.cross(r, f)


def cursor_ray(
    eye: np.ndarray,
    target: np.ndarray,
    fov: float,
    viewport: tuple[int, int],
    pixel: tuple[float, float],
) -> np.ndarray:
    """(3,) unit direction, display coordinates, of the ray through ``pixel`` (x right,
    y up from the bottom-left corner, as GL window coordinates) of a ``viewport`` (w, h)."""
    w, h = viewport
    f, r, u = view_basis(eye, target)
    t = math.tan(math.radians(fov) / 2.0)
    nx = 2.0 * pixel[0] / w - 1.0
    ny = 2.0 * pixel[1] / h - 1.0
    return _unit(f + nx * t * (w / h) * r + ny * t * u)


def pick_terrain(
    terrain,
    origin: np.ndarray,
    scale: np.ndarray,
    eye: np.ndarray,
    direction: np.ndarray,
    max_distance: float,
    samples: int = 512,
    refine: int = 24,
) -> np.ndarray | None:
    """First point (3,) display coordinates where the ray eye + t·direction meets h_T, or None.

    The ray is sampled at ``samples`` points up to ``max_distance`` (display units), all at
    once through the terrain's vectorized h_T, and the first crossing is refined by bisection.
    """
    origin = np.asarray(origin, dtype=np.float64)
    scale = np.asarray(scale, dtype=np.float64)

    def above(t: np.ndarray) -> np.ndarray:
        # Height of the ray over the terrain (world z units); NaN off the domain.
        p = eye[None, :] + t[:, None] * direction[None, :]
        world = p / scale + origin
        return world[:, 2] - np.asarray(terrain.height_at(world[:, 0], world[:, 1]))

    ts = np.linspace(0.0, max_distance, samples)
    d = above(ts)
    below = np.flatnonzero(d <= 0.0)
    if len(below) == 0:
        return None
    k = int(below[0])
    if k == 0:
        return eye.copy()
    lo, hi = ts[k - 1], ts[k]
    # A previous sample off the domain (NaN) still brackets the entry point well enough.
    for _ in range(refine):
        mid = 0.5 * (lo + hi)
        if above(np.array([mid]))[0] <= 0.0:
            hi = mid
        else:
            lo = mid
    return eye + hi * direction


class OrbitController:
    """Orbit around a target (drag), pan along the ground, zoom towards a picked point.

    eye, target: (3,) display coordinates. The pose is kept as target, distance, yaw (angle
    of the eye around the target, counter-clockwise from −y) and pitch (angle of the eye
    above the target's horizontal plane).
    """

    def __init__(
        self, eye: np.ndarray, target: np.ndarray, radians_per_pixel: float = 0.005
    ) -> None:
        self.radians_per_pixel = float(radians_per_pixel)
        self.set_pose(eye, target)

    def set_pose(self, eye: np.ndarray, target: np.ndarray) -> None:
        """Take over a pose (e.g. when leaving fly mode)."""
        eye = np.asarray(eye, dtype=np.float64)
        target = np.asarray(target, dtype=np.float64)
        offset = eye - target
        self.distance = float(np.linalg.norm(offset))
        if self.distance == 0.0:
            raise InvalidParameterError("eye and target must differ.")
        self.target = target.copy()
        self.pitch = math.asin(max(-1.0, min(1.0, offset[2] / self.distance)))
        self.yaw = math.atan2(offset[0], -offset[1])

    @property
    def eye(self) -> np.ndarray:
        """(3,) display coordinates of the eye."""
        c = math.cos(self.pitch)
        offset = np.array([c * math.sin(self.yaw), -c * math.cos(self.yaw), math.sin(self.pitch)])
        return self.target + self.distance * offset

    def orbit(self, dx: float, dy: float) -> None:
        """Rotate by a drag of (dx, dy) pixels (x right, y down): around z and up or down."""
        self.yaw -= dx * self.radians_per_pixel
        self.pitch = min(MAX_PITCH, max(MIN_PITCH, self.pitch + dy * self.radians_per_pixel))

    def pan(self, dx: float, dy: float, viewport_height: int, fov: float) -> None:
        """Slide eye and target along the ground by a drag of (dx, dy) pixels (x right, y
        down), so the ground at the target follows the cursor."""
        per_px = 2.0 * self.distance * math.tan(math.radians(fov) / 2.0) / viewport_height
        forward = np.array([-math.sin(self.yaw), math.cos(self.yaw), 0.0])
        right = np.array([math.cos(self.yaw), math.sin(self.yaw), 0.0])
        self.target = self.target - dx * per_px * right + dy * per_px * forward

    def zoom_to(self, point: np.ndarray, factor: float, min_distance: float = 1e-3) -> None:
        """Scale the view about ``point`` (3,) display: eye and target move towards it by
        ``factor`` (< 1 closer). The view direction is kept, so ``point`` stays under the
        cursor; the distance never falls under ``min_distance``."""
        if not (math.isfinite(factor) and factor > 0):
            raise InvalidParameterError(f"zoom factor must be > 0, got {factor!r}.")
        factor = max(factor, min_distance / self.distance)
        point = np.asarray(point, dtype=np.float64)
        eye = point + (self.eye - point) * factor
        target = point + (self.target - point) * factor
        # Keep yaw and pitch exactly (set_pose would round-trip them through asin/atan2).
        self.target = target
        self.distance = float(np.linalg.norm(eye - target))

    def camera(self, origin: np.ndarray, scale: np.ndarray, fov: float) -> Camera:
        """The world-space Camera of this pose."""
        return to_camera(self.eye, self.target, origin, scale, fov)


class FlyController:
    """First-person flight: look with the mouse, move with WASD (Q/E down/up).

    eye: (3,) display coordinates; yaw: heading counter-clockwise from +y; pitch: above the
    horizon. ``look_distance`` places the target (for the frame state and leaving fly mode).
    """

    def __init__(
        self,
        eye: np.ndarray,
        target: np.ndarray,
        radians_per_pixel: float = 0.003,
    ) -> None:
        self.radians_per_pixel = float(radians_per_pixel)
        self.set_pose(eye, target)

    def set_pose(self, eye: np.ndarray, target: np.ndarray) -> None:
        eye = np.asarray(eye, dtype=np.float64)
        d = np.asarray(target, dtype=np.float64) - eye
        self.look_distance = float(np.linalg.norm(d))
        if self.look_distance == 0.0:
            raise InvalidParameterError("eye and target must differ.")
        self.eye = eye.copy()
        self.pitch = max(-FLY_PITCH, min(FLY_PITCH, math.asin(d[2] / self.look_distance)))
        self.yaw = math.atan2(-d[0], d[1])

    @property
    def forward(self) -> np.ndarray:
        """(3,) unit view direction."""
        c = math.cos(self.pitch)
        return np.array([-c * math.sin(self.yaw), c * math.cos(self.yaw), math.sin(self.pitch)])

    @property
    def target(self) -> np.ndarray:
        return self.eye + self.look_distance * self.forward

    def look(self, dx: float, dy: float) -> None:
        """Turn by a mouse motion of (dx, dy) pixels (x right, y down)."""
        self.yaw -= dx * self.radians_per_pixel
        self.pitch = max(-FLY_PITCH, min(FLY_PITCH, self.pitch - dy * self.radians_per_pixel))

    def move(self, forward: float, right: float, up: float, distance: float) -> None:
        """Move ``distance`` display units along the unit mix of view direction, its right
        and world up (each of forward, right, up in [−1, 1], e.g. from held keys)."""
        f = self.forward
        r = np.array([math.cos(self.yaw), math.sin(self.yaw), 0.0])
        step = forward * f + right * r + up * np.array([0.0, 0.0, 1.0])
        n = float(np.linalg.norm(step))
        if n > 0.0:
            self.eye = self.eye + distance * step / n

    def camera(self, origin: np.ndarray, scale: np.ndarray, fov: float) -> Camera:
        return to_camera(self.eye, self.target, origin, scale, fov)


def to_display(point: np.ndarray, origin: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """World (…, 3) → display coordinates (…, 3)."""
    return (np.asarray(point, dtype=np.float64) - origin) * scale


def to_world(point: np.ndarray, origin: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Display (…, 3) → world coordinates (…, 3)."""
    return np.asarray(point, dtype=np.float64) / scale + origin


def to_camera(
    eye: np.ndarray, target: np.ndarray, origin: np.ndarray, scale: np.ndarray, fov: float
) -> Camera:
    """A world-space Camera from a display-space eye and target."""
    return Camera.look_at(
        tuple(to_world(eye, origin, scale)), tuple(to_world(target, origin, scale)), fov=fov
    )
