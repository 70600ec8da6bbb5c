"""Face and vertex normals of a triangle mesh, and their octahedral bytes, in loops.

What every mesh writer (GLB, 3D Tiles content) computes per tile: the cross products of the
triangles, their area-weighted sums at the vertices (each face added to its corners in
triangle order, as numpy's per-axis ``bincount`` summed them), unit length, and meshopt's
OCTAHEDRAL filter at 8 bits or fewer.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def face_normals(positions, triangles):
    """(m, 3) float64 (b − a) × (c − a) of ``triangles`` (m, 3) int64 over ``positions``
    (n, 3) float64: normals of twice the triangles' areas."""
    m = triangles.shape[0]
    out = np.empty((m, 3), dtype=np.float64)
    for i in range(m):
        a, b, c = triangles[i, 0], triangles[i, 1], triangles[i, 2]
        ux = positions[b, 0] - positions[a, 0]
        uy = positions[b, 1] - positions[a, 1]
        uz = positions[b, 2] - positions[a, 2]
        vx = positions[c, 0] - positions[a, 0]
        vy = positions[c, 1] - positions[a, 1]
        vz = positions[c, 2] - positions[a, 2]
        out[i, 0] = uy * vz - uz * vy
        out[i, 1] = uz * vx - ux * vz
        out[i, 2] = ux * vy - uy * vx
    return out


@njit(cache=True)
def vertex_normals(count, triangles, faces):
    """(count, 3) float64 unit sums of ``faces`` (m, 3) at the corners of ``triangles``
    (m, 3) int64; (0, 0, 1) at a vertex no triangle uses (or whose sum is 0)."""
    out = np.zeros((count, 3), dtype=np.float64)
    for i in range(triangles.shape[0]):
        for c in range(3):
            v = triangles[i, c]
            out[v, 0] += faces[i, 0]
            out[v, 1] += faces[i, 1]
            out[v, 2] += faces[i, 2]
    for v in range(count):
        length = math.sqrt(out[v, 0] * out[v, 0] + out[v, 1] * out[v, 1] + out[v, 2] * out[v, 2])
        if length > 0:
            out[v, 0] /= length
            out[v, 1] /= length
            out[v, 2] /= length
        else:
            out[v, 0], out[v, 1], out[v, 2] = 0.0, 0.0, 1.0
    return out


@njit(cache=True, inline="always")
def _oct_bytes(x, y, z, out, i, one):
    """Row i of ``out`` (n, 4) int8: the unit vector (x, y, z) as meshopt's OCTAHEDRAL filter
    stores it at k bits (``one`` = 2^(k−1) − 1, 127 for 8 bits): octahedral x, y in ±one
    (rounded half away from zero, as meshopt_quantizeSnorm), then one, then 0."""
    length = abs(x) + abs(y) + abs(z)
    if length > 0:
        x, y, z = x / length, y / length, z / length
    if z >= 0:
        u, v = x, y
    else:
        u = (1.0 - abs(y)) * math.copysign(1.0, x)
        v = (1.0 - abs(x)) * math.copysign(1.0, y)
    u = min(max(u, -1.0), 1.0) * one
    v = min(max(v, -1.0), 1.0) * one
    out[i, 0] = np.int8(math.trunc(u + math.copysign(0.5, u)))
    out[i, 1] = np.int8(math.trunc(v + math.copysign(0.5, v)))
    out[i, 2] = one
    out[i, 3] = 0


@njit(cache=True)
def meshopt_vertices(lattice, normals, order, one=127):
    """(positions (n, 4) uint16, octahedral normals (n, 4) int8, low (3,), high (3,)) of a
    meshopt vertex buffer: vertex ``order[i]`` (n,) int64 of ``lattice`` (n, 3) int64
    (0 <= values < 2^16) and unit ``normals`` (n, 3) float64 as row i, positions padded to 8
    bytes (the codec wants strides of 4), low and high the lattice's bounds per axis; the
    normals' octahedral components in ±``one`` (127: 8 bits, 63: 7 bits)."""
    n = order.shape[0]
    pos = np.zeros((n, 4), dtype=np.uint16)
    octs = np.empty((n, 4), dtype=np.int8)
    low = np.zeros(3, dtype=np.int64)
    high = np.zeros(3, dtype=np.int64)
    for c in range(3):
        if n:
            low[c] = lattice[order[0], c]
            high[c] = lattice[order[0], c]
    for i in range(n):
        j = order[i]
        for c in range(3):
            value = lattice[j, c]
            pos[i, c] = value
            if value < low[c]:
                low[c] = value
            if value > high[c]:
                high[c] = value
        _oct_bytes(normals[j, 0], normals[j, 1], normals[j, 2], octs, i, one)
    return pos, octs, low, high


@njit(cache=True)
def surface_normals(points, triangles, surface, tops):
    """(faces (surface, 3), normals (n, 3)) of a patch with skirts: ``points`` (n, 3) float64,
    ``triangles`` (m, 3) int64 whose first ``surface`` are the patch's; the last k vertices
    are wall bottoms, each taking the normal of the patch vertex ``tops`` (k,) int64 it
    hangs from (walls do not tilt the border's shading)."""
    faces = face_normals(points, triangles[:surface])
    top = points.shape[0] - tops.shape[0]
    normals = np.empty((points.shape[0], 3), dtype=np.float64)
    own = vertex_normals(top, triangles[:surface], faces)
    for v in range(top):
        for c in range(3):
            normals[v, c] = own[v, c]
    for j in range(tops.shape[0]):
        for c in range(3):
            normals[top + j, c] = own[tops[j], c]
    return faces, normals
