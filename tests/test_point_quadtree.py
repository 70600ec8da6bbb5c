"""Point quadtree over scattered points (seed 003): δ per leaf, restricted balance, recorded
insertion orders replayed at render time, the LOD mesh, and the Autzen figures."""

from __future__ import annotations

import numpy as np
import pytest
from atree_writer import write_atree
from conftest import data_file
from matplotlib.tri import LinearTriInterpolator, Triangulation

import approxtree as at
from approxtree import InvalidParameterError
from approxtree.render.lod_cut import LodSelector, leaf_mesh, lod_mesh, node_mesh, node_meshes
from approxtree.tree.point_quadtree import MAX_DEPTH, PointQuadtree


def areas(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(m,) signed areas of triangles t (m, 3) over vertices v (n, 2+)."""
    a, b, c = v[t[:, 0], :2], v[t[:, 1], :2], v[t[:, 2], :2]
    return 0.5 * (
        (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    )


def max_crack(v: np.ndarray, t: np.ndarray) -> float:
    """Largest height difference between triangles at the midpoints of every triangle edge
    (brute force over all triangles holding the point): 0 for a crack-free mesh."""
    t = t[np.abs(areas(v, t)) > 1e-12]
    q = np.concatenate([(v[t[:, a], :2] + v[t[:, b], :2]) / 2 for a, b in ((0, 1), (1, 2), (2, 0))])
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    det = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
    worst = 0.0
    for x, y in q:
        l1 = ((b[:, 1] - c[:, 1]) * (x - c[:, 0]) + (c[:, 0] - b[:, 0]) * (y - c[:, 1])) / det
        l2 = ((c[:, 1] - a[:, 1]) * (x - c[:, 0]) + (a[:, 0] - c[:, 0]) * (y - c[:, 1])) / det
        l3 = 1 - l1 - l2
        inside = (l1 >= -1e-9) & (l2 >= -1e-9) & (l3 >= -1e-9)
        h = (l1 * a[:, 2] + l2 * b[:, 2] + l3 * c[:, 2])[inside]
        worst = max(worst, float(h.max() - h.min()))
    return worst


def mesh_error(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray) -> float:
    """max |z − mesh| at points, by matplotlib's interpolator (independent of our kernels)."""
    if len(points) == 0:
        return 0.0
    # Patches of a cut repeat their shared vertices: merge them (their heights must agree).
    xy, first, inverse = np.unique(vertices[:, :2], axis=0, return_index=True, return_inverse=True)
    z = vertices[first, 2]
    np.testing.assert_allclose(vertices[:, 2], z[inverse.ravel()], atol=1e-9)
    t = inverse.ravel()[triangles]
    keep = np.abs(areas(xy, t)) > 1e-12
    tri = Triangulation(xy[:, 0], xy[:, 1], t[keep])
    h = LinearTriInterpolator(tri, z)(points[:, 0], points[:, 1])
    return float(np.max(np.abs(points[:, 2] - np.ma.filled(h, np.inf))))


@pytest.fixture(scope="module")
def quadtree() -> PointQuadtree:
    """2,000 clustered points (dense in one corner, so leaf levels vary), δ = 20."""
    rng = np.random.default_rng(7)
    xy = np.concatenate([rng.uniform(0, 100, (800, 2)), rng.uniform(0, 20, (1200, 2))])
    z = np.sin(xy[:, 0] / 9.0) * 5 + np.cos(xy[:, 1] / 7.0) * 3
    return PointQuadtree(at.TINPointSet(np.column_stack([xy, z])), max_points=20)


def test_leaves_hold_at_most_delta_points_and_partition_them(quadtree):
    """Every point lies in exactly one leaf; no leaf holds more than δ points."""
    counts = [np.subtract(*quadtree.point_range(leaf)[::-1]) for leaf in quadtree.leaves]
    assert sum(counts) == len(quadtree.points)
    assert max(counts) <= 20
    assert len({leaf[0] for leaf in quadtree.leaves}) >= 3


def test_quadtree_is_restricted(quadtree):
    """Edge-neighbouring leaves differ by at most one level."""
    leaves = set(quadtree.leaves)
    for level, i, j in leaves:
        for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            ni, nj = i + di, j + dj
            if not (0 <= ni < 1 << level and 0 <= nj < 1 << level):
                continue
            nb = (level, ni, nj)
            if nb in quadtree.children:
                # A same-level neighbour may be split once, never twice along our edge.
                if quadtree.children[nb]:
                    for a in (0, 1):
                        for b in (0, 1):
                            kid = (level + 1, 2 * ni + a, 2 * nj + b)
                            assert not quadtree.children[kid] or not _touches(kid, (level, i, j))
            else:
                # A coarser neighbour is at most one level up.
                assert (level - 1, ni // 2, nj // 2) in leaves


def _touches(a, b) -> bool:
    """True when squares a and b (level, i, j) share part of an edge."""
    (la, ia, ja), (lb, ib, jb) = a, b
    s = 1 << MAX_DEPTH
    ax0, ay0, aw = ia * (s >> la), ja * (s >> la), s >> la
    bx0, by0, bw = ib * (s >> lb), jb * (s >> lb), s >> lb
    ox = min(ax0 + aw, bx0 + bw) - max(ax0, bx0)
    oy = min(ay0 + aw, by0 + bw) - max(ay0, by0)
    return (ox == 0 and oy > 0) or (oy == 0 and ox > 0)


def test_replay_reproduces_coarse_fan_and_full_resolution(quadtree):
    """Replaying 0 insertions gives the initial fan; all of them interpolate every data point;
    the recorded error after every step equals the replayed mesh's measured error."""
    for leaf in quadtree.leaves[:: max(1, len(quadtree.leaves) // 25)]:
        lo, hi = quadtree.point_range(leaf)
        pts = quadtree.points[lo:hi]
        order, errors = quadtree.orders[leaf]
        assert sorted(order.tolist()) == list(range(hi - lo))
        v0, t0 = leaf_mesh(quadtree, leaf, 0)
        base = len(v0) - len(pts)
        assert len(t0) == base - 1 and (t0 == 0).any(axis=1).all()
        assert errors[0] == pytest.approx(mesh_error(v0, t0, pts), abs=1e-9)
        for k in range(1, hi - lo + 1):
            v, t = leaf_mesh(quadtree, leaf, k)
            assert errors[k] == pytest.approx(mesh_error(v, t, pts), abs=1e-9)
        assert errors[-1] == 0.0
        used = np.unique(t)
        assert set(range(base, base + len(pts))) <= set(used.tolist())


def test_lod_mesh_covers_the_square_and_follows_the_tolerance(quadtree):
    """The LOD mesh tiles the root square; a huge C draws the root fan, C = 0 every point."""
    s = quadtree.size
    eye = (quadtree.x0 - 10, quadtree.y0 - 10, 30.0)
    for c in (1e9, 10.0, 1.0, 0.0):
        m = lod_mesh(quadtree, eye, 60.0, 640, c)
        v, t = m.vertices, m.triangles
        area = areas(v, t)
        assert (area >= -1e-9).all() and area.sum() == pytest.approx(s * s, rel=1e-9)
        assert max_crack(v, t) < 1e-9
        if c == 1e9:
            assert m.nodes == 1 and len(t) == 4
        if c == 0.0:
            assert m.points_inserted == len(quadtree.points)
            assert mesh_error(v, t, quadtree.points) == pytest.approx(0.0, abs=1e-9)


def test_bad_delta():
    """δ < 1 is a clear error."""
    pts = at.TINPointSet(np.random.default_rng(0).uniform(0, 9, (30, 3)))
    with pytest.raises(InvalidParameterError, match="δ"):
        PointQuadtree(pts, max_points=0)


def test_autzen_ground_figures(data_dir):
    """Autzen ground points (26,107): table 1 figures are consistent and the LOD mesh is small."""
    terrain = at.open_terrain(data_file(data_dir, "lidar/autzen_trim.laz"), ground_only=True)
    q = PointQuadtree(terrain, max_points=50)
    n_p = len(terrain.vertices)
    assert n_p == 26_107 - terrain.duplicates_merged
    n_c = q.interpolation_point_count()
    assert 0 < n_c < 0.2 * n_p
    d = terrain.domain
    eye = (d.center[0], d.ymin - 0.1 * d.height, terrain.z_range[1] + 100.0)
    m = lod_mesh(q, eye, 60.0, 640, 10.0)
    assert 0 < len(m.triangles) < 0.1 * len(terrain.triangles)


def test_kd_tree_a25_2_over_scattered_points(quadtree):
    """A(25, 2) over a point set (core paper, figure 3): two children per inner node, at most
    25 points per patch, exact errors, leaves within ε."""
    from helpers import brute_force_error

    terrain = quadtree.terrain
    tree = at.ApproximationTree.build(terrain, 0.5, 25, fanout=2, policy="tin", progress=False)
    inner = tree.child_count > 0
    assert (tree.child_count[inner] == 2).all() and inner.sum() >= 10
    assert tree.errors[tree.leaves].max() <= 0.5
    for i in range(0, len(tree), max(1, len(tree) // 20)):
        node = tree.node(i)
        assert node.patch.point_count <= 25
        expected = brute_force_error(terrain, node.rect, node.patch.vertices, node.patch.triangles)
        assert node.error == pytest.approx(expected, abs=1e-9)


def test_save_load_round_trip(quadtree, tmp_path):
    """save → load through a tree store, and load of a legacy .atree tree file, give the same
    nodes, errors, boxes, orders and LOD mesh; foreign and old .npz files are StoreErrors that
    say what to do."""
    path = tmp_path / "q.zarr.zip"
    assert quadtree.save(path) == path.stat().st_size
    legacy = tmp_path / "q.atree"
    write_atree(quadtree, legacy)
    assert legacy.read_bytes()[:5] == b"ATREE"
    for back in (PointQuadtree.load(path), PointQuadtree.load(legacy)):
        assert back.children == quadtree.children and back.errors == quadtree.errors
        np.testing.assert_array_equal(back.bboxes, quadtree.bboxes)
        for leaf in quadtree.leaves:
            np.testing.assert_array_equal(back.orders[leaf][0], quadtree.orders[leaf][0])
            np.testing.assert_array_equal(back.orders[leaf][1], quadtree.orders[leaf][1])
        eye = (quadtree.x0 - 10, quadtree.y0 - 10, 30.0)
        a, b = lod_mesh(quadtree, eye, 60.0, 640, 2.0), lod_mesh(back, eye, 60.0, 640, 2.0)
        np.testing.assert_array_equal(a.triangles, b.triangles)
        np.testing.assert_array_equal(a.vertices, b.vertices)
    old = tmp_path / "old.npz"
    np.savez(old, x=np.zeros(3))
    with pytest.raises(at.StoreError, match=r"earlier version.*--kind point-quadtree"):
        PointQuadtree.load(old)
    (tmp_path / "junk.atree").write_bytes(b"not a tree file at all")
    with pytest.raises(at.StoreError, match="not an approxtree tree file"):
        PointQuadtree.load(tmp_path / "junk.atree")


def test_node_error_bounds_every_fan_the_node_is_drawn_as(quadtree):
    """δ of an internal node is the largest measured error over the 16 fans it can be drawn
    as (each side's midpoint present or not), so a coarse node drawn beside finer neighbours
    never shows more error than δ; the bound is reached by one of them."""
    import itertools

    internal = [n for n, inner in quadtree.children.items() if inner]
    selector = LodSelector(quadtree)
    for node in internal[:: max(1, len(internal) // 30)]:
        lo, hi = quadtree.point_range(node)
        pts = quadtree.points[lo:hi]
        measured = []
        for mids in itertools.product((False, True), repeat=4):
            v = quadtree.boundary(node, list(mids))
            t = np.array([[0, a, a + 1 if a + 1 < len(v) else 1] for a in range(1, len(v))])
            measured.append(mesh_error(v, t, pts))
            assert selector.fan_error(node, mids) == pytest.approx(measured[-1], abs=1e-9)
        assert quadtree.errors[node] == pytest.approx(max(measured), abs=1e-9)


def reference_node_mesh(q: PointQuadtree, node, midpoints, keep, inserted):
    """The per-node Python mesh of a drawn node (``node_mesh`` before the batch kernel)."""
    if inserted >= 0:
        v, t = leaf_mesh(q, node, int(inserted), keep=list(keep))
    else:
        v = q.boundary(node, list(midpoints))
        b = len(v)
        t = np.array([[0, a, a + 1 if a + 1 < b else 1] for a in range(1, b)])
    fill = []
    pos = 0  # ring index after the centre: SW, [S], SE, [E], NE, [N], NW, [W]
    for side in (2, 1, 3, 0):
        pos += 1
        if midpoints[side]:
            pos += 1
            if not keep[side]:
                fill.append((pos - 1, pos + 1 if side != 0 else 1, pos))
    if fill:
        t = np.concatenate([t, np.array(fill, dtype=t.dtype)])
    return v, t


def test_batch_meshes_equal_the_per_node_meshes(quadtree):
    """``node_meshes`` builds every drawn node's mesh of a cut in one call, equal vertex for
    vertex and triangle for triangle to the per-node Python meshes; cuts at several eyes
    and tolerances cover fans with midpoints, replayed leaves and flat midpoints."""
    seen = {"fan midpoint": 0, "replayed leaf": 0, "flat midpoint": 0, "bare leaf": 0}
    s = quadtree.size
    for ex, ey, ez in ((-10, -10, 30), (0.15 * s, 0.15 * s, 5), (0.6 * s, 0.2 * s, 2)):
        eye = (quadtree.x0 + ex, quadtree.y0 + ey, ez)
        for c in (8.0, 1.0, 0.2):
            cut = LodSelector(quadtree).cut(eye, 640 / np.radians(60), c)
            verts, vstart, tris, tstart = node_meshes(
                quadtree, cut.rows, cut.midpoints, cut.keep, cut.inserted
            )
            assert len(vstart) == len(tstart) == len(cut.rows) + 1
            assert vstart[-1] == len(verts) and tstart[-1] == len(tris)
            for m, row in enumerate(cut.rows.tolist()):
                node = quadtree.node_keys[row]
                args = (tuple(cut.midpoints[m]), tuple(cut.keep[m]), int(cut.inserted[m]))
                v, t = reference_node_mesh(quadtree, node, *args)
                np.testing.assert_array_equal(verts[vstart[m] : vstart[m + 1]], v)
                np.testing.assert_array_equal(tris[tstart[m] : tstart[m + 1]], t)
                # The single-node form is the same batch of one.
                v1, t1 = node_mesh(quadtree, node, *args)
                np.testing.assert_array_equal(v1, v)
                np.testing.assert_array_equal(t1, t)
                leaf = cut.inserted[m] >= 0
                seen["fan midpoint"] += bool(not leaf and cut.midpoints[m].any())
                seen["replayed leaf"] += bool(cut.inserted[m] > 0)
                seen["bare leaf"] += bool(cut.inserted[m] == 0)
                seen["flat midpoint"] += bool((cut.midpoints[m] & ~cut.keep[m]).any())
    assert min(seen.values()) > 0, seen


def reference_restrict(q: PointQuadtree) -> None:
    """The restriction of the build as a Python work list (before the array pass)."""

    def split(node):
        level, i, j = node
        q.children[node] = True
        for b in (0, 1):
            for a in (0, 1):
                q.children.setdefault((level + 1, 2 * i + a, 2 * j + b), False)

    def ensure(node):
        if node in q.children:
            return []
        level, i, j = node
        parent = (level - 1, i // 2, j // 2)
        done = ensure(parent)
        split(parent)
        return [*done, parent]

    work = [n for n, internal in q.children.items() if internal]
    while work:
        level, i, j = work.pop()
        for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            ni, nj = i + di, j + dj
            if 0 <= ni < (1 << level) and 0 <= nj < (1 << level):
                work.extend(ensure((level, ni, nj)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_array_restriction_equals_the_work_list(seed, monkeypatch):
    """The array pass that restricts the built quadtree splits exactly the nodes the Python
    work list split (clustered clouds, so the restriction has splits to make)."""
    rng = np.random.default_rng(seed)
    xy = np.concatenate([rng.uniform(0, 100, (300, 2)), 50 + rng.normal(0, 0.05, (400, 2))])
    pts = at.TINPointSet(np.column_stack([xy, rng.normal(0, 1, len(xy))]))
    q = PointQuadtree(pts, max_points=5)
    monkeypatch.setattr(PointQuadtree, "_restrict", reference_restrict)
    ref = PointQuadtree(pts, max_points=5)
    monkeypatch.undo()
    monkeypatch.setattr(PointQuadtree, "_restrict", lambda self: None)
    bare = PointQuadtree(pts, max_points=5)
    assert sum(bare.children.values()) < sum(ref.children.values())  # splits were needed
    assert q.children == ref.children
    np.testing.assert_array_equal(q.node_errors, ref.node_errors)
