"""The per-tile kernels (skirts, normals, meshopt vertex rows, lattice, region) against numpy.

The 3D Tiles writer and the renderer's loads call these once per node; they replaced numpy
code of the same results, which is recomputed here on random meshes (including holes, so
vertices without triangles, and duplicated wall bottoms) and compared exactly, or to the
last bits where a sum's order differs.
"""

from __future__ import annotations

import numpy as np
import pytest

from approxtree.io.gltf import face_normals, vertex_normals
from approxtree.kernels import mesh_normals
from approxtree.patches.skirts import add_skirts, border_edges
from approxtree.tiles.lattice import fit_lattice
from approxtree.tiles.tile_content import merge_bottoms, region, skirt_tops


def _grid_mesh(rows: int, cols: int, rng: np.random.Generator, holes: int = 0):
    """(vertices (rows·cols, 3), CCW triangles) of a jittered grid, ``holes`` cells dropped."""
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    z = rng.normal(0.0, 5.0, (rows, cols))
    verts = np.column_stack([x.ravel() * 30.0, y.ravel() * 30.0, z.ravel()])
    tris = []
    for r in range(rows - 1):
        for c in range(cols - 1):
            a, b, d, e = r * cols + c, r * cols + c + 1, (r + 1) * cols + c, (r + 1) * cols + c + 1
            tris += [(a, b, e), (a, e, d)]
    t = np.array(tris, dtype=np.int64)
    if holes:
        t = np.delete(t, rng.choice(len(t), holes, replace=False), axis=0)
    return verts, t


def _numpy_border_edges(t: np.ndarray) -> np.ndarray:
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    n = int(t.max()) + 1
    key = np.minimum(directed[:, 0], directed[:, 1]) * n + np.maximum(
        directed[:, 0], directed[:, 1]
    )
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return directed[counts[inverse] == 1]


@pytest.mark.parametrize("holes", [0, 7, 40])
def test_border_edges_match_numpy_unique(holes):
    """The hash-table border edges equal numpy's unique-count ones, in the same order."""
    rng = np.random.default_rng(holes)
    _, t = _grid_mesh(9, 12, rng, holes)
    np.testing.assert_array_equal(border_edges(t), _numpy_border_edges(t))


def _numpy_skirts(v, t, depth, domain, base, rect):
    """add_skirts as numpy wrote it before its kernel."""

    def on(edges, r):
        tol = 1e-9 * max(r[2] - r[0], r[3] - r[1], 1e-300)
        a, b = v[edges[:, 0]], v[edges[:, 1]]
        out = np.zeros(len(edges), dtype=bool)
        for axis, bound in ((0, r[0]), (0, r[2]), (1, r[1]), (1, r[3])):
            out |= (np.abs(a[:, axis] - bound) <= tol) & (np.abs(b[:, axis] - bound) <= tol)
        return out

    edges = _numpy_border_edges(t)
    if rect is not None:
        edges = edges[on(edges, rect)]
    outer = on(edges, domain) if domain is not None else np.zeros(len(edges), dtype=bool)
    if domain is not None and not np.isfinite(base):
        edges, outer = edges[~outer], outer[~outer]
    k = len(edges)
    low = np.concatenate([v[edges[:, 0]], v[edges[:, 1]]])
    outer2 = np.concatenate([outer, outer])
    low[:, 2] = np.where(outer2, base, np.maximum(low[:, 2] - depth, base))
    a, b = edges[:, 0], edges[:, 1]
    a2 = len(v) + np.arange(k)
    walls = np.concatenate([np.column_stack([a2, a2 + k, b]), np.column_stack([a2, b, a])])
    flags = np.concatenate([np.zeros(len(v), np.float32), np.ones(2 * k, np.float32)])
    return np.concatenate([v, low]), np.concatenate([t, walls]), flags


@pytest.mark.parametrize(
    "rect, domain, base",
    [
        (None, None, -np.inf),
        ((0.0, 0.0, 330.0, 240.0), (0.0, 0.0, 330.0, 240.0), -50.0),
        ((0.0, 0.0, 330.0, 240.0), (0.0, 0.0, 330.0, 500.0), -np.inf),
        ((30.0, 30.0, 330.0, 240.0), None, -20.0),
    ],
)
def test_add_skirts_matches_numpy(rect, domain, base):
    """Walls from the kernel equal numpy's: same vertices, triangles and flags, in order."""
    rng = np.random.default_rng(3)
    v, t = _grid_mesh(9, 12, rng, holes=9)
    got = add_skirts(v, t, 4.5, domain, base, rect)
    want = _numpy_skirts(v, t, 4.5, domain, base, rect)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)


def test_merge_bottoms_matches_lexsort_grouping():
    """Coincident wall bottoms merge into the first of each (top, height) group, as the
    lexsort version merged them, and the mesh keeps its shape."""
    rng = np.random.default_rng(5)
    v, t = _grid_mesh(8, 8, rng, holes=5)
    surface = len(t)
    verts, tris, _ = add_skirts(v, t, 3.0, (0.0, 0.0, 210.0, 210.0), -40.0, None)
    tops = skirt_tops(tris[surface:])
    mv, mt, mtops = merge_bottoms(verts, tris, surface, tops)
    # numpy: sort by (top, height); the first of each run of equals owns it.
    top = len(verts) - len(tops)
    z = verts[top:, 2]
    order = np.lexsort((z, tops))
    same = np.zeros(len(tops), dtype=bool)
    same[1:] = (tops[order][1:] == tops[order][:-1]) & (z[order][1:] == z[order][:-1])
    first = order[~same]
    keep = np.sort(first)
    assert len(mv) == top + len(keep) < len(verts)
    np.testing.assert_array_equal(mv[top:], verts[top + keep])
    np.testing.assert_array_equal(mtops, tops[keep])
    np.testing.assert_array_equal(mv[mt], verts[tris])


def test_normals_match_numpy_cross_and_bincount():
    """Face normals equal numpy's cross products; vertex normals its bincount sums, unit
    length, (0, 0, 1) where no triangle touches; wall bottoms copy their tops'."""
    rng = np.random.default_rng(11)
    v, t = _grid_mesh(7, 9, rng, holes=12)
    a = v[t[:, 0]]
    np.testing.assert_array_equal(face_normals(v, t), np.cross(v[t[:, 1]] - a, v[t[:, 2]] - a))
    faces = np.cross(v[t[:, 1]] - a, v[t[:, 2]] - a)
    sums = np.stack(
        [np.bincount(t.ravel(), np.repeat(faces[:, k], 3), minlength=len(v)) for k in range(3)],
        axis=1,
    )
    length = np.linalg.norm(sums, axis=1)
    want = np.where(length[:, None] > 0, sums / np.maximum(length, 1e-300)[:, None], [0, 0, 1])
    np.testing.assert_allclose(vertex_normals(v, t), want, rtol=0, atol=1e-15)
    tops = np.array([0, 5, 5, 62], dtype=np.int64)
    points = np.concatenate([v, v[tops] - [0.0, 0.0, 10.0]])
    f, n = mesh_normals.surface_normals(points, t, len(t), tops)
    np.testing.assert_array_equal(f, face_normals(v, t))
    np.testing.assert_array_equal(n[len(v) :], n[tops])


@pytest.mark.parametrize("one", [127, 63])
def test_meshopt_vertices_match_numpy_quantization(one):
    """meshopt's vertex rows: the lattice in the given order as shorts, its bounds, and the
    normals' octahedral bytes (8 or 7 bits) as numpy rounds meshopt's filter (half away from
    zero)."""
    rng = np.random.default_rng(2)
    n = rng.normal(size=(500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n[:3] = [(0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)]
    q = rng.integers(3, 65536, (500, 3))
    order = rng.permutation(500)
    pos, got, low, high = mesh_normals.meshopt_vertices(q, n, order, one)
    np.testing.assert_array_equal(pos[:, :3], q[order])
    assert pos.dtype == np.uint16 and (pos[:, 3] == 0).all()
    np.testing.assert_array_equal(low, q.min(axis=0))
    np.testing.assert_array_equal(high, q.max(axis=0))
    s = n[order] / np.abs(n[order]).sum(axis=1, keepdims=True)
    x, y, z = s.T
    u = np.where(z >= 0, x, (1.0 - np.abs(y)) * np.copysign(1.0, x))
    w = np.where(z >= 0, y, (1.0 - np.abs(x)) * np.copysign(1.0, y))
    for k, c in enumerate((u, w)):
        c = np.clip(c, -1.0, 1.0) * one
        np.testing.assert_array_equal(got[:, k], np.trunc(c + np.copysign(0.5, c)))
    assert (got[:, 2] == one).all() and (got[:, 3] == 0).all()


def test_lattice_rounding_matches_numpy_rint():
    """Lattice coordinates are numpy's rint of the offsets in steps, their displacement the
    largest |origin + q · step − position|."""
    rng = np.random.default_rng(4)
    rel = rng.uniform(-500.0, 500.0, (300, 3))
    lattice = fit_lattice(rel, np.eye(3), 1.0, 0.05, 1.0, 16)
    local = rel
    origin = local.min(axis=0)
    q = np.rint((local - origin) / lattice.step).astype(np.int64)
    np.testing.assert_array_equal(lattice.q, q)
    moved = np.linalg.norm(origin + q * lattice.step - local, axis=1).max()
    assert lattice.moved == moved
    assert lattice.bits == max(8, int(q.max()).bit_length())


def test_region_matches_numpy_extent():
    """A region holds the vertices' longitude, latitude and height bounds padded by the
    sagitta of the longest surface edge, as the numpy version computed it."""
    rng = np.random.default_rng(9)
    v, t = _grid_mesh(6, 6, rng)
    geo = np.column_stack([-79.0 + v[:, 0] * 1e-5, 35.5 + v[:, 1] * 1e-5, 100.0 + v[:, 2]])
    points = v + np.array([6.3e6, 0.0, 0.0])
    low, high = region(geo, points, t, 0.25)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    d = points[e[:, 0]] - points[e[:, 1]]
    chord = float(np.sqrt(np.einsum("ij,ij->i", d, d).max()))
    radius = 6356752.314245179**2 / 6378137.0
    sag = chord * chord / (8.0 * radius) + 1e-2 + 0.25
    lat = np.radians(geo[:, 1])
    coslat = max(float(np.cos(np.abs(lat).max())), 1e-6)
    pad = np.array([sag / (radius * coslat), sag / radius, sag])
    want_low = np.array([np.radians(geo[:, 0].min()), lat.min(), geo[:, 2].min()]) - pad
    want_high = np.array([np.radians(geo[:, 0].max()), lat.max(), geo[:, 2].max() + 1e-2 + 0.25])
    want_high[:2] += pad[:2]
    np.testing.assert_array_equal(low, want_low)
    np.testing.assert_array_equal(high, want_high)
