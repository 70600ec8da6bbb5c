"""A tile's positions on a lattice, and a bound of what that moves its surface's heights.

Compressed 3D Tiles content (io/gltf_compact.py) stores positions as integers q (n, 3) on a
lattice of the tile's own axes: ``rotation`` (east, north, up at the tile's centre for terrain
on the ellipsoid; the local frame's axes otherwise), ``origin`` + q · ``step`` metres, with
``step`` a power of two (the encoders then decode q · step exactly). Rounding to the lattice
moves each vertex by d with |d_k| <= step / 2 along every axis.

How much does that change the surface's height at a point p (what ``approxtree verify``
measures: heights along the vertical n_p of each place)? Take the triangle T' (moved
vertices) over p and the original T: with barycentric weights w' of p in T' (all in
[0, 1]) and the vertices' moves split into vertical b_i and horizontal a_i (about n_p),

    h_T'(p) − h_T(p) = Σ w'_i b_i − ∇h_T · Σ w'_i a_i,

exactly (the plane of T is affine), so |h_T' − h_T| <= max |b| + |∇h_T| · max |a|. With φ
the largest angle between a vertex's vertical and the lattice's up, |b| <= step/2 ·
(cos φ + √2 sin φ) and |a| <= √3 · step/2; |∇h_T| = tan of the angle between T's normal and
n_p, at most the angle α between T's normal and the vertical at its first vertex plus the
largest angle θ between that vertical and its other vertices'. The bound is ``step · k``,

    k = (cos φ + √2 sin φ) / 2 + √3 / 2 · tan(α + θ),

with the largest φ, α and θ of the tile (for terrain in a local frame every vertical is the
lattice's up: φ = θ = 0, tan α = the steepest slope).

"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from approxtree.io.gltf import column_bounds
from approxtree.kernels import tile_bounds
from approxtree.kernels._jit import readonly
from approxtree.tiles.earth import WGS84_A, WGS84_B

#: glTF's y-up axes from z-up ones: (x, y, z) → (x, z, −y).
Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: Fewest bits per axis a lattice is given (coarser saves nothing worth having).
MIN_BITS = 8
#: The verticals ``bound_factor`` passes its kernel for a tile with one vertical.
_NO_NORMALS = np.zeros((0, 3))


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
    x, y, z = (float(v) for v in center)
    ux, uy, uz = x / WGS84_A**2, y / WGS84_A**2, z / WGS84_B**2
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / norm, uy / norm, uz / norm
    flat = math.hypot(ux, uy)
    ex, ey = (-uy / flat, ux / flat) if flat > 0 else (1.0, 0.0)
    # north = up × east (east has no z).
    north = (-uz * ey, uz * ex, ux * ey - uy * ex)
    return np.array([[ex, north[0], ux], [ey, north[1], uy], [0.0, north[2], uz]])


def verticals(geo: np.ndarray) -> np.ndarray:
    """(n, 3) unit ellipsoid normals (ECEF) at (n, 3) longitude, latitude (degrees), height."""
    lam, phi = np.radians(geo[:, 0]), np.radians(geo[:, 1])
    return np.column_stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)])


def bound_factor(
    faces: np.ndarray, triangles: np.ndarray, up: np.ndarray, normals: np.ndarray | None
) -> float:
    """k of the module docstring: the height bound per metre of step, inf when a triangle is
    vertical or overturned. faces: (m, 3) normals of the surface triangles (m, 3);
    up: (3,) the lattice's up; normals: (n, 3) the vertices' verticals, or None for one
    vertical, ``up``, everywhere.

    Angles are taken at each triangle's first vertex (α against its vertical, θ the largest
    angle from it to the others'), and the largest α and θ over the tile are added: at least
    the largest α_t + θ_t, with one arccos each."""
    if not len(faces):
        return 0.5
    up = readonly(np.asarray(up), np.float64)
    per_vertex = normals is not None
    cos_alpha, cos_theta, cos_phi = tile_bounds.lattice_cosines(
        readonly(faces, np.float64),
        readonly(np.asarray(triangles).reshape(-1, 3), np.int64),
        up,
        readonly(normals if normals is not None else _NO_NORMALS, np.float64),
        per_vertex,
    )
    alpha = math.acos(min(max(cos_alpha, -1.0), 1.0))
    theta = math.acos(min(max(cos_theta, -1.0), 1.0))
    phi = min(math.acos(min(max(cos_phi, -1.0), 1.0)), math.pi / 2)
    steep = alpha + theta
    if steep >= math.pi / 2:
        return math.inf
    return 0.5 * (math.cos(phi) + math.sqrt(2.0) * math.sin(phi)) + 0.5 * math.sqrt(3.0) * math.tan(
        steep
    )


def geographic_factor(geo: np.ndarray, triangles: np.ndarray) -> float:
    """The height bound per metre of step of a TIN linear in longitude and latitude (as
    quantized-mesh tiles are read): a move of r metres changes a vertex's height by at most r
    and its longitude, latitude by at most r over the metres per degree there, so heights
    under a triangle of gradient g (metres per degree) change by at most
    r · (1 + |g| scaled by the metres per degree); r = √3 · step / 2.

    geo: (n, 3) longitude, latitude (degrees), height; triangles: (m, 3)."""
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if not len(t):
        return 0.5 * math.sqrt(3.0)
    p = np.asarray(geo, dtype=np.float64)[t]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        g_lon, g_lat = -n[:, 0] / n[:, 2], -n[:, 1] / n[:, 2]
    # Fewest metres per degree over each triangle (the smallest radius of curvature).
    per_degree = math.radians(1.0) * WGS84_B**2 / WGS84_A
    coslat = np.cos(np.radians(np.abs(p[:, :, 1]).max(axis=1)))
    slope = np.hypot(g_lon / (per_degree * np.maximum(coslat, 1e-9)), g_lat / per_degree)
    worst = float(slope.max())
    return 0.5 * math.sqrt(3.0) * (1.0 + worst) if math.isfinite(worst) else math.inf


def fit_lattice(
    rel: np.ndarray,
    rotation: np.ndarray,
    k: float,
    budget: float,
    limit: float,
    max_bits: int,
) -> Lattice | None:
    """The lattice of ``rel`` (n, 3) positions relative to the tile's centre (tileset frame)
    in the axes ``rotation`` (3, 3): the coarsest step whose bound is within ``budget`` metres,
    at most ``max_bits`` bits per axis; when that cap leaves a bound over ``limit`` (a sliver
    steep enough to make the quantization matter), None: store the tile's positions as float32.

    k: the height bound per metre of step (``bound_factor`` of the surface's triangles,
    skirts left out since their walls claim nothing, or ``geographic_factor``).
    """
    local = np.asarray(rel, dtype=np.float64) @ rotation
    origin, top = column_bounds(local)
    extent = max(float((top - origin).max()), 1e-9)
    if not math.isfinite(k):
        return None
    # The coarsest power of two within the budget, then refined until it fits the bits.
    step = 2.0 ** math.floor(math.log2(budget / k)) if budget > 0 else 0.0
    finest = 2.0 ** math.ceil(math.log2(extent / (2**max_bits - 1)))
    step = max(step, finest)
    bound = step * k
    if bound > budget and bound > limit:
        return None
    q, top, moved = tile_bounds.round_to_lattice(readonly(local), readonly(origin), step)
    bits = max(MIN_BITS, int(top).bit_length())
    return Lattice(q, origin, step, bits, rotation, bound, moved)
