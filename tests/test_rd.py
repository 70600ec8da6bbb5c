"""Rate–distortion on the binary triangle tree: domains, conformity, embedding, optimality."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file
from helpers import brute_force_error

from approxtree.cli import main
from approxtree.errors import InvalidParameterError
from approxtree.kernels import bintree_rd as kr
from approxtree.rd import BinTree, decimate, lattice_heights, rd_curves, refine, uniform


def _heights(k: int, seed: int = 0) -> np.ndarray:
    """A rough random-walk surface on the (2^k + 1)² lattice."""
    rng = np.random.default_rng(seed)
    s = (1 << k) + 1
    return rng.normal(size=(s, s)).cumsum(0).cumsum(1) + 5.0 * rng.normal(size=(s, s))


def _closure(u: int, mate: np.ndarray, internal: np.ndarray) -> set[int]:
    """Split closure of u under parent and mate links, by definition (asserts conformity)."""
    out = {u}
    stack = [u]
    while stack:
        x = stack.pop()
        for y in (x >> 1, int(mate[x])):
            if y >= 2 and y not in out:
                assert internal[y], "the mesh is not conforming"
                out.add(y)
                stack.append(y)
    return out


def _check_conforming(vx: np.ndarray, vy: np.ndarray, tv: np.ndarray, s: int) -> None:
    """Every interior edge is shared by exactly two triangles (a T-junction breaks this)."""
    edges: dict[tuple[int, int], int] = {}
    for tri in tv:
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            key = (min(a, b), max(a, b))
            edges[key] = edges.get(key, 0) + 1
    area = 0
    for tri in tv:
        (ax, ay), (bx, by), (cx, cy) = ((vx[i], vy[i]) for i in tri)
        area += (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    assert area == 2 * s * s
    for (a, b), n in edges.items():
        border = (vx[a] == vx[b] and vx[a] in (0, s)) or (vy[a] == vy[b] and vy[a] in (0, s))
        assert n == (1 if border else 2)


def test_mates_share_the_hypotenuse():
    """Every node's mate is symmetric and has the same hypotenuse endpoints."""
    k = 3
    tree = BinTree(_heights(k))
    for u in range(2, 1 << (2 * k + 2)):
        m = int(tree.mate[u])
        a = tree.corners(u)
        if m == 0:
            # On the border: both hypotenuse endpoints on one side of the square.
            s = 1 << k
            lx, ly, rx, ry = a[2:]
            assert (lx == rx and lx in (0, s)) or (ly == ry and ly in (0, s))
            continue
        b = tree.corners(m)
        assert tree.mate[m] == u
        assert {a[2:4], a[4:6]} == {b[2:4], b[4:6]}


def test_distortion_is_exact_against_matplotlib():
    """Sum of d over a uniform level equals the squared errors from matplotlib's interpolator."""
    from matplotlib.tri import LinearTriInterpolator, Triangulation

    h = _heights(4, 1)
    seq = uniform(BinTree(h))
    for j in (0, 3, 6):
        vx, vy, tv = seq.mesh(j)
        tri = Triangulation(vx.astype(float), vy.astype(float), tv)
        z = h[vy, vx]
        yy, xx = np.mgrid[0 : h.shape[0], 0 : h.shape[1]]
        interp = LinearTriInterpolator(tri, z)(xx.ravel().astype(float), yy.ravel().astype(float))
        sse = float(np.sum((h.ravel() - np.ma.filled(interp, np.nan)) ** 2))
        assert seq.distortions[j] == pytest.approx(sse, rel=1e-9)
        assert seq.errors(j)[0] == pytest.approx(sse, rel=1e-9)


@pytest.mark.parametrize("make", [decimate, refine])
def test_sequences_are_conforming_embedded_and_measured(make):
    """Every mesh is conforming, refines the previous one, and its distortion is exact."""
    k = 4
    h = _heights(k, 2)
    seq = make(BinTree(h))
    s = 1 << k
    assert seq.rates[0] == 2 and seq.rates[-1] == 2 * s * s
    assert np.all(np.diff(seq.rates) > 0)
    assert seq.distortions[-1] == pytest.approx(0.0, abs=1e-6)
    prev = None
    for j in range(len(seq)):
        leaves = seq.leaves(j)
        assert len(leaves) == seq.rates[j]
        vx, vy, tv = seq.mesh(j)
        _check_conforming(vx, vy, tv, s)
        sse, _ = seq.errors(j)
        assert seq.distortions[j] == pytest.approx(sse, rel=1e-9, abs=1e-6)
        if prev is not None:
            # Embedded: each triangle lies in (or is) a triangle of the coarser mesh.
            coarse = set(prev.tolist())
            for u in leaves:
                x = int(u)
                while x not in coarse:
                    x >>= 1
                    assert x >= 2
        prev = leaves


def test_max_error_matches_brute_force():
    """The measured max error of a sequence mesh equals the matplotlib re-computation."""
    from approxtree.geometry import Grid

    h = _heights(4, 3)
    seq = decimate(BinTree(h))
    grid = Grid(h)
    j = seq.index_at_rate(60)
    vx, vy, tv = seq.mesh(j)
    verts = np.column_stack([grid.x_coords[vx], grid.y_coords[vy], h[vy, vx]])
    _, emax = seq.errors(j)
    assert emax == pytest.approx(brute_force_error(grid, grid.domain, verts, tv), rel=1e-9)


@pytest.mark.parametrize(("k", "seed"), [(2, 0), (2, 1), (3, 0), (3, 5)])
def test_decimation_prunes_the_smallest_lambda(k, seed):
    """Each G-BFOS step prunes P(t) = {u : t in closure(u)} of a t with the smallest λ."""
    tree = BinTree(_heights(k, seed))
    seq = decimate(tree)
    nodes_all = range(2, 1 << (2 * k + 1))
    for j in range(len(seq) - 2, -1, -1):
        internal = seq.birth < j + 1
        nodes = [u for u in nodes_all if internal[u]]
        closures = {u: _closure(u, tree.mate, internal) for u in nodes}
        lam = {}
        for t in nodes:
            p = frozenset(u for u in nodes if t in closures[u])
            lam[t] = (sum(tree.gain[u] for u in p) / len(p), p)
        pruned = frozenset(u for u in nodes if seq.birth[u] == j)
        chosen = [t for t, v in lam.items() if v[1] == pruned]
        assert chosen, "the pruned set is no merging domain"
        assert lam[chosen[0]][0] <= min(v[0] for v in lam.values()) + 1e-9


def test_refinement_splits_a_splitting_domain_of_the_best_leaf():
    """Each refinement step splits the splitting domain of a leaf of largest priority."""
    k = 3
    tree = BinTree(_heights(k, 4))
    seq = refine(tree)
    slopes = kr.subtree_slopes(tree.d, k)
    buf = np.empty(64, dtype=np.int64)
    nsplit = 1 << (2 * k + 1)
    for j in range(len(seq) - 1):
        internal = seq.birth < j
        internal[1] = True
        leaves = [int(u) for u in seq.leaves(j) if u < nsplit]
        split = {u for u in range(2, nsplit) if seq.birth[u] == j}
        pri = {}
        for t in leaves:
            closure = _closure_split(t, tree.mate, internal)
            n, g = kr._split_domain(t, tree.mate, seq.birth, j, tree.gain, buf)
            assert set(buf[:n].tolist()) == closure
            pri[t] = (kr._priority(t, n, g, slopes), closure)
        best = max(v[0] for v in pri.values())
        assert any(v[1] == split and v[0] >= best - 1e-9 for v in pri.values())


def _closure_split(t: int, mate: np.ndarray, internal: np.ndarray) -> set[int]:
    """Nodes that must split with leaf t: its split closure minus the internal nodes."""
    out = {t}
    stack = [t]
    while stack:
        x = stack.pop()
        for y in (x >> 1, int(mate[x])):
            if y >= 2 and y not in out and not internal[y]:
                out.add(y)
                stack.append(y)
    return out


def test_domains_match_their_definitions():
    """Merging domain roots and splitting domains agree with the closure definitions."""
    k = 3
    tree = BinTree(_heights(k))
    nsplit = 1 << (2 * k + 1)
    full = np.zeros(1 << (2 * k + 2), dtype=bool)
    full[1:nsplit] = True
    closures = {u: _closure(u, tree.mate, full) for u in range(2, nsplit)}
    for u in (2, 5, 9, 22, 45, 100):
        p = {v for v in range(2, nsplit) if u in closures[v]}
        roots = {v for v in p if (v >> 1) not in p} - {u}
        assert set(tree.merging_domain(u).tolist()) == roots
        parent = closures[u >> 1] if u >= 4 else set()
        assert set(tree.splitting_domain(u).tolist()) == closures[u] - parent - {u}
    # A level-2 triangle merges with many subtrees, a deepest splittable one with its mate.
    assert len(tree.merging_domain(4)) > 10
    deep = max(u for u in range(nsplit // 2, nsplit) if tree.mate[u])
    assert list(tree.merging_domain(deep)) == [tree.mate[deep]]


def test_lattice_window_errors():
    """Wrong sizes and nodata windows raise InvalidParameterError saying what to do."""
    h = _heights(4)
    assert lattice_heights(h).shape == (17, 17)
    assert lattice_heights(np.pad(h, 3), 9).shape == (9, 9)
    with pytest.raises(InvalidParameterError, match="2\\^k \\+ 1"):
        lattice_heights(h, 10)
    with pytest.raises(InvalidParameterError, match="does not fit"):
        lattice_heights(h, 33)
    holes = h.copy()
    holes[8, 8] = np.nan
    with pytest.raises(InvalidParameterError, match="nodata"):
        lattice_heights(holes)
    with pytest.raises(InvalidParameterError, match="2\\^k"):
        BinTree(h[:16, :16])


RD_DEMS = ["scape/crater.stm", "scape/ashby.stm", "scape/ozark.stm", "nc/elev_ned_30m.tif"]


@pytest.mark.parametrize("relative", RD_DEMS)
def test_table_order_on_real_dems(data_dir, relative):
    """At the table rates decimation's L2 <= refinement's <= the uniform grid's (257² DEMs)."""
    from approxtree.io import open_terrain

    h = lattice_heights(open_terrain(data_file(data_dir, relative)), 257)
    res = rd_curves(h, (512, 1024, 2048, 4096), ("decimation", "refinement", "uniform"))
    rows = {m: res["methods"][m]["rows"] for m in res["methods"]}
    for i, rate in enumerate(res["rates"]):
        dec, ref, uni = (rows[m][i] for m in ("decimation", "refinement", "uniform"))
        assert max(dec["triangles"], ref["triangles"], uni["triangles"]) <= rate
        assert dec["covered"] == 257 * 257
        assert dec["sse"] <= ref["sse"] * (1 + 1e-9)
        assert ref["sse"] <= uni["sse"] * (1 + 1e-9)


def test_cli_rd_json(data_dir, tmp_path):
    """approxtree rd prints every method's figures at every rate and writes the plot."""
    dem = data_file(data_dir, "scape/ozark.stm")
    png = tmp_path / "rd.png"
    out = CliRunner().invoke(
        main, ["rd", str(dem), "--rates", "64,256", "--size", "129", "--plot", str(png), "--json"]
    )
    assert out.exit_code == 0, out.output
    fig = json.loads(out.output)
    assert fig["size"] == 129 and fig["rates"] == [64, 256]
    assert set(fig["methods"]) == {"decimation", "refinement", "uniform", "tin", "rtin"}
    for data in fig["methods"].values():
        assert data["seconds"] >= 0
        for row, rate in zip(data["rows"], (64, 256), strict=True):
            assert row["triangles"] <= rate
            assert row["max_error"] >= 0 and row["snr_db"] > 0
    assert png.stat().st_size > 1000
    bad = CliRunner().invoke(main, ["rd", str(dem), "--size", "100"])
    assert bad.exit_code == 2 and "2^k + 1" in bad.output
