"""FrameState: everything one frame needs, computed once and frozen.

Coordinates on the way to the screen::

    world (x, y, z, map units) ──(− origin) × scale──▶ display (metres) ──view──▶ eye ──proj──▶ clip

*Display scale.* For projected CRSs (and terrains without a CRS) the scale is (1, 1, 1): x, y
and z share units. For a geographic CRS (x, y in degrees, z in metres) the scale converts
degrees to metres on a sphere of the mean Earth radius at the latitude of the domain's centre:
``(R·π/180·cos φ0, R·π/180, 1)``. Everything measured in pixels (α, γ, the error-bound test)
therefore refers to the displayed geometry. The scale is diagonal and positive, so bounding
boxes stay axis-parallel and the nearest point of a box can be found in world units.

*Near/far.* Unless the camera's projection gives them, far is 1 % beyond the farthest corner of
the tree's root box, and near is half the distance from the eye to that box, but at least
far / 10⁴ (24-bit depth keeps about four decimal digits of resolution over that ratio).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pyrr

from approxtree.errors import InvalidParameterError
from approxtree.geometry.base import GeometryData
from approxtree.render.camera import Camera, Projection

#: Mean Earth radius (IUGG), metres: the sphere behind the geographic display scale.
EARTH_RADIUS = 6_371_008.8
#: Largest viewport side accepted (pixels); GL limits may be lower and are checked by the Engine.
MAX_VIEWPORT = 16384
#: Smallest near/far ratio chosen automatically.
NEAR_FAR_RATIO = 1e-4

_GEOGRAPHIC_CODES = {"EPSG:4326", "EPSG:4258", "EPSG:4269", "EPSG:4979", "OGC:CRS84"}


def is_geographic(crs: str | None) -> bool:
    """True when ``crs`` has x, y in degrees (longitude, latitude)."""
    if not crs:
        return False
    code = crs.strip().upper()
    if code in _GEOGRAPHIC_CODES:
        return True
    try:
        from rasterio.crs import CRS

        return bool(CRS.from_user_input(crs).is_geographic)
    except Exception:
        # Unknown to rasterio: fall back on the WKT keywords.
        return code.startswith(("GEOGCS", "GEOGCRS")) and "PROJCS" not in code


def display_scale(terrain: GeometryData) -> np.ndarray:
    """(3,) float64 factors from world units to displayed metres (see the module docstring)."""
    if is_geographic(terrain.crs):
        lat = math.radians(terrain.domain.center[1])
        m_per_deg = EARTH_RADIUS * math.pi / 180.0
        return np.array([m_per_deg * math.cos(lat), m_per_deg, 1.0])
    return np.ones(3)


def check_viewport(size: tuple[int, int]) -> tuple[int, int]:
    """(width, height) as ints in [1, MAX_VIEWPORT], or InvalidParameterError."""
    try:
        w, h = (int(v) for v in size)
        ok = all(float(v) == int(v) for v in size)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(
            f"size must be (width, height) in pixels, got {size!r}."
        ) from exc
    if not ok or not (1 <= w <= MAX_VIEWPORT and 1 <= h <= MAX_VIEWPORT):
        raise InvalidParameterError(
            f"size must be whole pixels between 1 and {MAX_VIEWPORT} per side, got {size!r}."
        )
    return w, h


def _frustum_planes(m: np.ndarray) -> np.ndarray:
    """(6, 4) planes (a, b, c, d), inside where a·x + b·y + c·z + d >= 0, of a clip matrix.

    m: (4, 4) column-vector matrix to clip space; rows combined as in Gribb & Hartmann.
    """
    r = m
    planes = np.array(
        [r[3] + r[0], r[3] - r[0], r[3] + r[1], r[3] - r[1], r[3] + r[2], r[3] - r[2]]
    )
    # Unit normals make the plane distance meaningful (not needed for the test, but cheap).
    return planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)


@dataclass(frozen=True, eq=False)
class FrameState:
    """The frozen view of one frame. Matrices act on column vectors (GL convention).

    viewport: (width, height) pixels. eye: (3,) world. origin: (3,) world local origin of the
    GPU buffers. scale: (3,) display scale. view, projection: (4, 4) float64 in display units.
    world_to_clip: (4, 4) float64, world → clip (scale and origin folded in).
    local_to_clip: (4, 4) float64, (world − origin) → clip, the matrix the shaders get.
    planes: (6, 4) frustum planes in world coordinates. focal_px: pixels per unit of
    tan(angle): (height / 2) / tan(fov / 2). near, far: display units.
    """

    viewport: tuple[int, int]
    eye: np.ndarray
    origin: np.ndarray
    scale: np.ndarray
    view: np.ndarray
    projection: np.ndarray
    world_to_clip: np.ndarray
    local_to_clip: np.ndarray
    planes: np.ndarray
    focal_px: float
    near: float
    far: float
    fov: float

    @classmethod
    def from_camera(
        cls,
        camera: Camera,
        size: tuple[int, int],
        bounds: np.ndarray,
        origin: np.ndarray,
        scale: np.ndarray,
    ) -> FrameState:
        """The frame of ``camera`` over a viewport ``size`` = (w, h).

        bounds: (6,) world box (xmin, ymin, zmin, xmax, ymax, zmax) that near/far must hold.
        origin: (3,) world local origin; scale: (3,) display scale.
        """
        w, h = check_viewport(size)
        origin = np.asarray(origin, dtype=np.float64)
        scale = np.asarray(scale, dtype=np.float64)
        eye_d = (camera.eye - origin) * scale
        target_d = (camera.target - origin) * scale
        forward = target_d - eye_d
        up = camera.up * scale
        # Looking along the up hint leaves the view's roll undefined: take +y (north) instead.
        if np.linalg.norm(np.cross(forward, up)) <= 1e-9 * np.linalg.norm(forward) * np.linalg.norm(
            up
        ):
            up = np.array([0.0, 1.0, 0.0])
        near, far = cls._near_far(camera, eye_d, bounds, origin, scale)
        view = pyrr.matrix44.create_look_at(eye_d, target_d, up).T.astype(np.float64)
        proj = pyrr.matrix44.create_perspective_projection(camera.fov, w / h, near, far).T
        proj = proj.astype(np.float64)
        s = np.diag([*scale, 1.0])
        t = np.eye(4)
        t[:3, 3] = -origin
        local_to_clip = proj @ view @ s
        world_to_clip = local_to_clip @ t
        for a in (view, proj, local_to_clip, world_to_clip, origin, scale):
            a.setflags(write=False)
        eye = camera.eye.copy()
        eye.setflags(write=False)
        return cls(
            viewport=(w, h),
            eye=eye,
            origin=origin,
            scale=scale,
            view=view,
            projection=proj,
            world_to_clip=world_to_clip,
            local_to_clip=local_to_clip,
            planes=_frustum_planes(world_to_clip),
            focal_px=0.5 * h / math.tan(math.radians(camera.fov) / 2.0),
            near=near,
            far=far,
            fov=camera.fov,
        )

    @staticmethod
    def _near_far(
        camera: Camera, eye_d: np.ndarray, bounds: np.ndarray, origin: np.ndarray, scale: np.ndarray
    ) -> tuple[float, float]:
        """(near, far) in display units: the projection's, or fitted to ``bounds``."""
        b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        b = np.where(np.isfinite(b), b, origin)
        lo, hi = (b[0] - origin) * scale, (b[1] - origin) * scale
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        far_fit = 1.01 * float(np.linalg.norm(corners - eye_d, axis=1).max())
        far_fit = max(far_fit, 1e-6)
        inside = np.clip(eye_d, lo, hi)
        near_fit = max(0.5 * float(np.linalg.norm(eye_d - inside)), far_fit * NEAR_FAR_RATIO)
        p = camera.projection
        far = p.far if p.far is not None else far_fit
        near = p.near if p.near is not None else min(near_fit, 0.5 * far)
        if near >= far:
            raise InvalidParameterError(f"near ({near}) must be smaller than far ({far}).")
        return near, far

    # -- projections ------------------------------------------------------------------------

    @property
    def lens(self) -> np.ndarray:
        """(7,) float64 for the α kernels: focal length in pixels, the display scale (3),
        tan_x, tan_y (the viewport's half-width and half-height in tangents of the angle off
        the view axis) and near (display units)."""
        p = self.projection
        return np.array(
            [self.focal_px, *self.scale, 1.0 / p[0, 0], 1.0 / p[1, 1], self.near],
            dtype=np.float64,
        )

    def world_to_pixels(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points: (..., 3) → ((..., 2) pixel coordinates, (...,) clip w).

        Pixel x grows right, y grows up (GL window coordinates), pixel centres at k + 0.5.
        Points with w <= 0 lie behind the eye; their pixel coordinates are meaningless.
        """
        p = np.asarray(points, dtype=np.float64)
        m = self.world_to_clip
        clip = p @ m[:3, :3].T + m[:3, 3]
        wv = p @ m[3, :3] + m[3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            ndc = clip[..., :2] / wv[..., None]
        px = (ndc * 0.5 + 0.5) * np.array(self.viewport, dtype=np.float64)
        return px, wv


def overview_camera(
    bounds: np.ndarray, scale: np.ndarray, fov: float = 45.0, elevation: float = 40.0
) -> Camera:
    """An oblique view from the south of the whole box ``bounds`` (6,) world, ``fov`` degrees.

    The eye looks at the box centre from ``elevation`` degrees above the horizon, far enough
    that the box's bounding sphere (in display units) fits the vertical field of view.
    """
    # The field of view is validated before the distance divides by its sine.
    Projection(fov)
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    b = np.where(np.isfinite(b), b, 0.0)
    centre = b.mean(axis=0)
    radius = 0.5 * float(np.linalg.norm((b[1] - b[0]) * scale))
    dist = max(radius, 1e-6) / math.sin(math.radians(fov) / 2.0) * 1.02
    el = math.radians(elevation)
    offset_d = dist * np.array([0.0, -math.cos(el), math.sin(el)])
    return Camera.look_at(centre + offset_d / scale, centre, fov=fov)


#: Elevation angles (degrees) tried by ``framing_camera`` when none is given.
FRAMING_ELEVATIONS = (20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0)
#: Steeper angles tried, in order, when none of FRAMING_ELEVATIONS covers FRAMING_COVERAGE
#: (a terrain much wider than the frame, seen obliquely, leaves sky above and below it).
FRAMING_STEEPER = (55.0, 60.0, 65.0, 70.0, 75.0, 80.0)
#: The fraction of the frame a fitted view's box top should cover.
FRAMING_COVERAGE = 0.62


def framing_camera(
    bounds: np.ndarray,
    scale: np.ndarray,
    size: tuple[int, int] = (1280, 720),
    fov: float = 45.0,
    elevation: float | None = None,
    azimuth: float = 180.0,
    margin: float = 0.02,
) -> Camera:
    """An oblique view that fits the box ``bounds`` (6,) world to a ``size`` = (w, h) frame.

    The eye looks from ``azimuth`` (degrees clockwise from north; 180: from the south, north
    up) at ``elevation`` degrees above the horizon. Unlike ``overview_camera`` (bounding sphere
    in the vertical field of view), the eight corners of the box (display units, exaggeration
    included) are projected: the distance is the smallest that keeps them inside the frame
    less ``margin`` (a fraction of each half-side), and the target is shifted so their
    projection is centred. Without ``elevation`` the angle among FRAMING_ELEVATIONS whose
    fitted box top covers the most of the frame is taken, unless it covers less than
    FRAMING_COVERAGE: then the first of FRAMING_STEEPER that covers it (or the steepest).
    """
    Projection(fov)
    w, h = check_viewport(size)
    b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    b = np.where(np.isfinite(b), b, 0.0)
    scale = np.asarray(scale, dtype=np.float64)
    centre = b.mean(axis=0)
    lo, hi = (b[0] - centre) * scale, (b[1] - centre) * scale
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    tan_y = math.tan(math.radians(fov) / 2.0)
    tan_x = tan_y * w / h
    angles = FRAMING_ELEVATIONS if elevation is None else (float(elevation),)
    # The first elevation that covers the most (a later one must cover more by over 1e-9).
    best = _fit(corners, hi[2], angles[0], azimuth, tan_x, tan_y, margin)
    for el in angles[1:]:
        fit = _fit(corners, hi[2], el, azimuth, tan_x, tan_y, margin)
        if fit[2] > best[2] + 1e-9:
            best = fit
    # Too little of the frame covered: look down more steeply until enough is.
    for el in FRAMING_STEEPER if elevation is None else ():
        if best[2] >= FRAMING_COVERAGE:
            break
        fit = _fit(corners, hi[2], el, azimuth, tan_x, tan_y, margin)
        if fit[2] > best[2] + 1e-9:
            best = fit
    eye_d, target_d, _ = best
    return Camera.look_at(centre + eye_d / scale, centre + target_d / scale, fov=fov)


def _fit(
    corners: np.ndarray,
    top: float,
    elevation: float,
    azimuth: float,
    tan_x: float,
    tan_y: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """(eye, target, covered fraction of the frame by the box's top face) in display units
    relative to the box centre, for one elevation (see ``framing_camera``)."""
    el, az = math.radians(elevation), math.radians(azimuth)
    # u: from the target towards the eye; basis of the view (right, up, forward).
    u = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    f = -u
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    up = np.cross(r, f)
    radius = float(np.linalg.norm(corners, axis=1).max()) or 1e-6
    limit = 1.0 - margin
    target = np.zeros(3)

    def extents(dist: float, target: np.ndarray) -> np.ndarray:
        q = corners - (target + dist * u)
        d = q @ f
        if (d <= 1e-9 * radius).any():
            # A corner behind the eye: the box cannot fit (every extent is out of the frame).
            return np.array([-np.inf, np.inf, -np.inf, np.inf])
        x, y = (q @ r) / (d * tan_x), (q @ up) / (d * tan_y)
        return np.array([x.min(), x.max(), y.min(), y.max()])

    dist = radius / math.sin(min(math.atan(tan_x), math.atan(tan_y))) * 1.02
    for _ in range(4):
        # Smallest distance with every corner inside the frame (the extent shrinks with it).
        near, far = radius * 1e-3, dist * 4.0
        for _ in range(60):
            # A shifted target can leave corners out at the first guess: back off until all fit.
            e = extents(far, target)
            if max(-e[0], e[1], -e[2], e[3]) <= limit:
                break
            near, far = far, far * 2.0
        for _ in range(50):
            mid = 0.5 * (near + far)
            e = extents(mid, target)
            if max(-e[0], e[1], -e[2], e[3]) <= limit:
                far = mid
            else:
                near = mid
        dist = far
        # Centre the projection: move the target across the view by the offset it shows.
        e = extents(dist, target)
        if not np.isfinite(e).all():
            break
        cx, cy = 0.5 * (e[0] + e[1]), 0.5 * (e[2] + e[3])
        target = target + dist * (cx * tan_x * r + cy * tan_y * up)
    # Fraction of the frame covered by the box's top face (shoelace over its projection).
    top_face = np.array([c for c in corners if c[2] == top][:4])
    top_face = top_face[[0, 1, 3, 2]]
    q = top_face - (target + dist * u)
    d = q @ f
    x, y = (q @ r) / (d * tan_x), (q @ up) / (d * tan_y)
    area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    return target + dist * u, target, area / 4.0
