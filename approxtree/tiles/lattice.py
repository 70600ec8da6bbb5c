"""A tile's positions on a lattice, and a bound of what that moves its surface's heights.

Compressed 3D Tiles content (io/gltf_compact.py) stores positions as integers q (n, 3) on a
lattice of the tile's own axes: ``rotation`` (east, north, up at the tile's centre for terrain
on the ellipsoid; the local frame's axes otherwise), ``origin`` + q · ``step`` metres, with
``step`` a power of two (the encoders then decode q · step exactly). Rounding to the lattice
moves each vertex by d with |d_k| <= step / 2 along every axis.

How much does that change the surface's height at a point p (what ``approxtree verify``
measures, heights along each place's vertical)? Take the triangle T' (moved vertices) over p
and the original T: with barycentric weights w' of p in T' (all in [0, 1]) and the vertices'
moves split into vertical b_i and horizontal a_i,

    h_T'(p) − h_T(p) = Σ w'_i b_i − ∇h_T · Σ w'_i a_i,

exactly (the plane of T is affine), so |h_T' − h_T| <= max |b| + S · max |a| with S the
steepest surface triangle's slope. Verticals differ across the tile by at most ``tilt`` θ
(the largest angle between a vertex's vertical and the lattice's up), so
|b| <= step/2 · (1 + √2 θ), |a| <= √3 · step/2, and slopes seen from a tilted vertical are
at most tan(atan S + θ): the bound is ``step · k`` with k = (1 + √2 θ + √3 tan(atan S + θ)) / 2.

``fit_lattice`` picks the coarsest power-of-two step whose bound is within a budget (at most
``max_bits`` per axis), so a tile's claim grows by a known, small amount.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from approxtree.tiles.earth import WGS84_A, WGS84_B

#: glTF's y-up axes from z-up ones: (x, y, z) → (x, z, −y).
Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: Fewest bits per axis a lattice is given (coarser saves nothing worth having).
MIN_BITS = 8


@dataclass(frozen=True)
class Lattice:
    """Positions of one tile on a lattice (see the module docstring).

    q: (n, 3) int64 lattice coordinates; origin: (3,) metres (lattice axes) of q = 0; step:
    metres per unit (a power of two); bits: bits per axis (q < 2**bits); rotation: (3, 3)
    columns = the lattice's axes in the tileset frame; bound: metres the stored surface's
    heights may differ from the original's anywhere; moved: largest vertex displacement (m).
    """

    q: np.ndarray
    origin: np.ndarray
    step: float
    bits: int
    rotation: np.ndarray
    bound: float
    moved: float

    def positions(self) -> np.ndarray:
        """(n, 3) float64 stored positions in the tileset frame, relative to the tile's centre."""
        return (self.origin + self.q * self.step) @ self.rotation.T

    def local(self, vectors: np.ndarray) -> np.ndarray:
        """(n, 3) tileset-frame vectors (n, 3) in the lattice's axes."""
        return np.asarray(vectors, dtype=np.float64) @ self.rotation

    def placement(self, offset: np.ndarray | None = None) -> np.ndarray:
        """(4, 4) float64: lattice metres → glTF scene (y-up), positions relative to the tile's
        centre, plus ``offset`` (3,) (tileset frame) when given."""
        m = np.eye(4)
        m[:3, :3] = Y_UP @ self.rotation
        t = self.rotation @ self.origin
        if offset is not None:
            t = t + offset
        m[:3, 3] = Y_UP @ t
        return m


def local_axes(center: np.ndarray, georeferenced: bool) -> np.ndarray:
    """(3, 3) columns east, north, up at ``center`` (ECEF) on the WGS84 ellipsoid, or the
    identity for a local frame (already east, north, up)."""
    if not georeferenced:
        return np.eye(3)
    up = np.asarray(center, dtype=np.float64) / np.array([WGS84_A**2, WGS84_A**2, WGS84_B**2])
    up /= np.linalg.norm(up)
    east = np.array([-up[1], up[0], 0.0])
    norm = np.linalg.norm(east)
    east = east / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
    return np.column_stack([east, np.cross(up, east), up])


def tilt(geo: np.ndarray | None, up: np.ndarray) -> float:
    """Largest angle (radians) between the verticals at (n, 3) lon, lat (degrees), height
    points and ``up`` (3,) unit; 0 without points (a local frame: one vertical)."""
    if geo is None or not len(geo):
        return 0.0
    lam, phi = np.radians(geo[:, 0]), np.radians(geo[:, 1])
    normals = np.column_stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)])
    return float(np.arccos(np.clip((normals @ up).min(), -1.0, 1.0)))


def steepest_slope(faces: np.ndarray, rotation: np.ndarray) -> float:
    """Largest |gradient| of triangles given by their normals ``faces`` (m, 3) (tileset frame,
    ``io.gltf.face_normals``) seen in the lattice's axes ``rotation`` (z up); inf for a
    vertical or overturned triangle."""
    if not len(faces):
        return 0.0
    n = np.asarray(faces, dtype=np.float64) @ rotation
    flat = np.hypot(n[:, 0], n[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        slopes = np.where(n[:, 2] > 0, flat / n[:, 2], np.inf)
    return float(slopes.max())


def bound_factor(slope: float, theta: float) -> float:
    """k of the module docstring: the height bound per metre of step."""
    angle = math.atan(slope) + theta
    steep = math.tan(angle) if angle < math.pi / 2 else math.inf
    return 0.5 * (1.0 + math.sqrt(2.0) * theta + math.sqrt(3.0) * steep)


def fit_lattice(
    rel: np.ndarray,
    rotation: np.ndarray,
    faces: np.ndarray,
    theta: float,
    budget: float,
    limit: float,
    max_bits: int,
) -> Lattice | None:
    """The lattice of ``rel`` (n, 3) positions relative to the tile's centre (tileset frame)
    in the axes ``rotation`` (3, 3): the coarsest step whose bound is within ``budget`` metres,
    at most ``max_bits`` bits per axis; when that cap leaves a bound over ``limit`` (a sliver
    steep enough to make the quantization matter), None: store the tile's positions as float32.

    faces: (m, 3) normals of the surface's triangles (skirts left out: vertical walls hold no
    point) in the tileset frame; theta: ``tilt`` of the tile.
    """
    local = np.asarray(rel, dtype=np.float64) @ rotation
    origin = local.min(axis=0)
    extent = max(float((local.max(axis=0) - origin).max()), 1e-9)
    k = bound_factor(steepest_slope(faces, rotation), theta)
    if not math.isfinite(k):
        return None
    # The coarsest power of two within the budget, then refined until it fits the bits.
    step = 2.0 ** math.floor(math.log2(budget / k)) if budget > 0 else 0.0
    finest = 2.0 ** math.ceil(math.log2(extent / (2**max_bits - 1)))
    step = max(step, finest)
    bound = step * k
    if bound > budget and bound > limit:
        return None
    q = np.rint((local - origin) / step).astype(np.int64)
    top = int(q.max())
    bits = max(MIN_BITS, top.bit_length())
    moved = float(np.linalg.norm(origin + q * step - local, axis=1).max())
    return Lattice(q, origin, step, bits, rotation, bound, moved)
