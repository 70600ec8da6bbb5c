"""Camera: a perspective camera in world coordinates, owning one Projection.

The camera only knows where it is and where it looks (world units of the terrain: x east,
y north, z up). How world units map to the displayed geometry (the display scale of
geographic CRSs) and which near/far planes fit the terrain are decided by FrameState, so one
camera can be reused across trees and viewports. Properties are read-only; ``update`` is the
single way to move the camera, and it validates like the constructor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from approxtree.errors import InvalidParameterError


def _finite_vector(name: str, value: object) -> np.ndarray:
    """A (3,) float64 vector, or InvalidParameterError naming what was wrong."""
    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(
            f"{name} must be three numbers x, y, z, got {value!r}."
        ) from exc
    if v.shape != (3,):
        raise InvalidParameterError(f"{name} must be three numbers x, y, z, got {value!r}.")
    if not np.all(np.isfinite(v)):
        raise InvalidParameterError(f"{name} must be finite, got {tuple(v.tolist())}.")
    return v


@dataclass(frozen=True)
class Projection:
    """Perspective projection: vertical field of view ``fov`` (degrees), optional near/far.

    near, far: distances in display units (metres for geographic terrains); None lets
    FrameState fit them to the tree's bounding box.
    """

    fov: float = 60.0
    near: float | None = None
    far: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.fov, int | float) and math.isfinite(self.fov)):
            raise InvalidParameterError(
                f"fov must be a finite number of degrees, got {self.fov!r}."
            )
        if not 0.0 < self.fov < 180.0:
            raise InvalidParameterError(f"fov must lie in (0, 180) degrees, got {self.fov}.")
        for name in ("near", "far"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise InvalidParameterError(f"{name} must be a finite distance > 0, got {v!r}.")
        if self.near is not None and self.far is not None and self.near >= self.far:
            raise InvalidParameterError(
                f"near must be smaller than far, got near={self.near}, far={self.far}."
            )


class Camera:
    """A perspective camera: eye and target in world coordinates, ``up`` +z by default.

    Build it with ``Camera.look_at(eye, target, fov)``; move it with ``update(...)``.
    """

    def __init__(
        self,
        eye: tuple[float, float, float],
        target: tuple[float, float, float],
        projection: Projection,
        up: tuple[float, float, float] = (0.0, 0.0, 1.0),
    ) -> None:
        self._set(eye, target, up, projection)

    @classmethod
    def look_at(
        cls,
        eye: tuple[float, float, float],
        target: tuple[float, float, float],
        fov: float = 60.0,
        near: float | None = None,
        far: float | None = None,
        up: tuple[float, float, float] = (0.0, 0.0, 1.0),
    ) -> Camera:
        """A camera at ``eye`` looking at ``target`` with a vertical field of view ``fov``."""
        return cls(eye, target, Projection(fov, near, far), up)

    def update(
        self,
        eye: tuple[float, float, float] | None = None,
        target: tuple[float, float, float] | None = None,
        fov: float | None = None,
        up: tuple[float, float, float] | None = None,
    ) -> Camera:
        """Move or re-aim the camera (only the given values change); returns self."""
        p = self._projection
        projection = p if fov is None else Projection(fov, p.near, p.far)
        self._set(
            self._eye if eye is None else eye,
            self._target if target is None else target,
            self._up if up is None else up,
            projection,
        )
        return self

    def _set(self, eye, target, up, projection: Projection) -> None:
        e = _finite_vector("eye", eye)
        t = _finite_vector("target", target)
        u = _finite_vector("up", up)
        if np.array_equal(e, t):
            raise InvalidParameterError(f"eye and target must differ, both are {tuple(e)}.")
        if not np.any(u):
            raise InvalidParameterError("up must not be the zero vector.")
        self._eye, self._target, self._up, self._projection = e, t, u, projection
        for a in (e, t, u):
            a.setflags(write=False)

    # -- read-only properties ----------------------------------------------------------------

    @property
    def eye(self) -> np.ndarray:
        """(3,) float64 camera position in world coordinates."""
        return self._eye

    @property
    def target(self) -> np.ndarray:
        """(3,) float64 point looked at, in world coordinates."""
        return self._target

    @property
    def up(self) -> np.ndarray:
        """(3,) float64 up direction hint (replaced by +y when looking straight along it)."""
        return self._up

    @property
    def projection(self) -> Projection:
        return self._projection

    @property
    def fov(self) -> float:
        """Vertical field of view in degrees."""
        return self._projection.fov

    def __repr__(self) -> str:
        return (
            f"Camera(eye={tuple(self._eye.tolist())}, target={tuple(self._target.tolist())}, "
            f"fov={self.fov:g})"
        )
