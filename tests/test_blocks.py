"""Blocked builds (in process and on dask) give the serial build's tree, node for node."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from affine import Affine
from click.testing import CliRunner
from conftest import data_file

from approxtree import ApproximationTree, ApproxTreeError, Grid, InvalidParameterError
from approxtree.tree.blocks import make_tasks, plan_blocks
from approxtree.tree.policy import StrategyPolicy


def assert_same_tree(a: ApproximationTree, b: ApproximationTree) -> None:
    """Same nodes, rectangles, errors, boxes, links and patches (records and meshes)."""
    assert len(a) == len(b)
    for key in ("rects", "errors", "bboxes", "levels", "parents", "child_start", "child_count"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
    kinds_a = [a.strategy_names[i] for i in a.strategies]
    kinds_b = [b.strategy_names[i] for i in b.strategies]
    assert kinds_a == kinds_b
    for i in range(len(a)):
        pa, pb = a.patch(i), b.patch(i)
        assert (pa.error, pa.data_count) == (pb.error, pb.data_count)
        ra, rb = pa.to_record(), pb.to_record()
        assert ra.keys() == rb.keys()
        for key in ra:
            np.testing.assert_array_equal(ra[key], rb[key], err_msg=f"node {i} {key}")
    # Meshes of a sample of nodes (leaves and upper nodes) are rebuilt from the full grid.
    for i in np.linspace(0, len(a) - 1, 25).astype(int):
        np.testing.assert_array_equal(a.patch(i).vertices, b.patch(i).vertices)
        np.testing.assert_array_equal(a.patch(i).triangles, b.patch(i).triangles)


def _terrain() -> Grid:
    """Rough terrain with nodata covering whole blocks, a partial hole and a flat field."""
    rng = np.random.default_rng(11)
    z = np.cumsum(np.cumsum(rng.normal(size=(257, 300)), 0), 1).astype(np.float32) * 0.02
    z[:129, :150] = np.nan  # a level-1 node without data: unsplit, its 4 blocks unused
    z[128:193, 149:225] = np.nan  # a level-2 block without data under a split node
    z[150:170, 30:60] = np.nan
    z[192:, 224:] = 5.0  # a flat block
    return Grid(z, Affine(1.5, 0, 431000.0, 0, -1.5, 5100000.0))


@pytest.mark.parametrize(
    ("fanout", "policy"),
    [
        (4, "type"),
        (2, "type"),
        (4, "level:grid@0-1,tin"),
        (4, "level:grid@0-1,rtin"),
        (2, "level:grid@0-3,nonregular"),
    ],
)
def test_block_build_in_process_equals_serial(fanout, policy):
    g = _terrain()
    serial = ApproximationTree.build(g, 0.5, 9 * 9, fanout, policy, progress=False)
    blocked = ApproximationTree.build(g, 0.5, 9 * 9, fanout, policy, False, block_size=80)
    plan = plan_blocks(g, fanout, 80)
    assert plan.block_level == (2 if fanout == 4 else 4)
    # Some blocks lie under an unsplit upper node and are left out.
    assert np.count_nonzero(serial.levels == plan.block_level) < len(plan.blocks)
    assert_same_tree(blocked, serial)


def test_block_level_as_deep_as_the_grid_allows():
    # Blocks of 1 cell per side: plan leaves that cannot be cut stop above the block level.
    z = np.random.default_rng(2).normal(size=(2, 10)).astype(np.float32)
    g = Grid(z)
    plan = plan_blocks(g, 4, 1)
    assert {plan.levels[b] for b in plan.blocks} == {plan.block_level - 1, plan.block_level}
    serial = ApproximationTree.build(g, 0.0, 4, 4, progress=False)
    assert_same_tree(ApproximationTree.build(g, 0.0, 4, 4, block_size=1), serial)


def test_policy_with_other_upper_strategies_is_refused():
    g = _terrain()
    with pytest.raises(InvalidParameterError, match="grid patches"):
        ApproximationTree.build(g, 0.5, 81, 4, "level:grid@0,tin", block_size=80)
    with pytest.raises(InvalidParameterError, match="report"):
        ApproximationTree.build(g, 0.5, 81, 4, block_size=80, report="r.html")
    with pytest.raises(InvalidParameterError, match="block_size"):
        ApproximationTree.build(g, 0.5, 81, 4, block_size=0)


@pytest.fixture(scope="module")
def cluster():
    """One LocalCluster of 2 processes for the module (starting one costs seconds)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as c:
        yield c


def test_dask_build_equals_serial_on_a_real_dem_with_nodata(data_dir, cluster):
    from approxtree.io import open_terrain

    g = open_terrain(data_file(data_dir, "edge/SainteHelens.dem"))
    assert g.nodata_count > 0
    serial = ApproximationTree.build(g, 2.0, 17 * 17, 4, progress=False)
    plan = plan_blocks(g, 4, 64)
    assert plan.block_level >= 3 and len(plan.blocks) >= 64
    dask = ApproximationTree.build(
        g, 2.0, 17 * 17, 4, progress=False, scheduler=cluster.scheduler_address, block_size=64
    )
    assert_same_tree(dask, serial)


def test_dask_build_equals_serial_kd_tree_and_tin_below(cluster):
    g = _terrain()
    for fanout, policy in ((2, "type"), (4, "level:grid@0-1,tin")):
        serial = ApproximationTree.build(g, 0.5, 9 * 9, fanout, policy, progress=False)
        dask = ApproximationTree.build(
            g, 0.5, 9 * 9, fanout, policy, False, scheduler=cluster.scheduler_address,
            block_size=80,
        )  # fmt: skip
        assert_same_tree(dask, serial)


def test_failed_block_task_is_an_approxtree_error(cluster):
    from distributed import Client

    from approxtree.tree.distributed import dask_runner

    g = _terrain()
    plan = plan_blocks(g, 4, 80)
    tasks = make_tasks(g, plan, 0.5, 81, 4, StrategyPolicy("type"))
    tasks[3].index = None  # the task fails (a TypeError on the worker)
    with Client(cluster) as client, pytest.raises(ApproxTreeError, match="Block 3"):
        dask_runner(client=client, progress=False)(tasks)


def test_cli_build_with_two_workers(tmp_path):
    from approxtree.cli import main

    g = _terrain()
    z = np.where(np.isnan(g.heights), -9999.0, g.heights).astype(np.float32)
    path = tmp_path / "dem.asc"
    header = (
        f"ncols {z.shape[1]}\nnrows {z.shape[0]}\nxllcorner 431000\n"
        f"yllcorner {5100000 - 1.5 * z.shape[0]}\ncellsize 1.5\nNODATA_value -9999\n"
    )
    path.write_text(header + "\n".join(" ".join(f"{v:.6g}" for v in row) for row in z))
    out_serial, out_dask = tmp_path / "serial.zarr", tmp_path / "dask.zarr"
    args = [str(path), "--epsilon", "0.5", "--max-points", "81", "--json"]
    runner = CliRunner()
    r1 = runner.invoke(main, ["build", *args, "--out", str(out_serial)], catch_exceptions=False)
    r2 = runner.invoke(
        main,
        ["build", *args, "--out", str(out_dask), "--workers", "2", "--block-size", "80"],
        catch_exceptions=False,
    )
    assert r1.exit_code == 0 and r2.exit_code == 0, r1.output + r2.output
    f1, f2 = json.loads(r1.output.splitlines()[-1]), json.loads(r2.output.splitlines()[-1])
    assert f1["nodes"] == f2["nodes"] > 100
    assert_same_tree(ApproximationTree.load(out_dask), ApproximationTree.load(out_serial))


def test_cli_rejects_workers_with_scheduler(tmp_path):
    from approxtree.cli import main

    z = np.random.default_rng(0).normal(size=(20, 20))
    path = tmp_path / "dem.npy"
    np.save(path, z)
    r = CliRunner().invoke(
        main,
        ["build", str(path), "--out", str(tmp_path / "t.zarr"), "--workers", "2",
         "--scheduler", "tcp://127.0.0.1:1"],
    )  # fmt: skip
    assert r.exit_code == 2
    assert "Error:" in r.output and "not both" in r.output


def test_windowed_grid_tasks_read_their_own_windows():
    from approxtree.geometry.windowed import ArraySource, WindowedHeights

    g = _terrain()
    source = ArraySource(np.asarray(g.heights))
    w = Grid(WindowedHeights(source, cache_bytes=1 << 16, block_shape=(32, 32)), g.transform)
    plan = plan_blocks(w, 4, 80)
    tasks = make_tasks(w, plan, 0.5, 81, 4, StrategyPolicy("type"))
    assert all(t.grid is w and all(a.lattice is None for a in t.ancestors) for t in tasks)
    # Without workers a windowed grid builds block by block in this process.
    serial = ApproximationTree.build(g, 0.5, 81, 4, progress=False)
    assert_same_tree(ApproximationTree.build(w, 0.5, 81, 4, progress=False), serial)


@pytest.mark.parametrize("nodata", [0.0, 0.3])
@pytest.mark.parametrize("steps", [(1, 1), (3, 5), (7, 4), (40, 40)])
def test_patch_parts_reduce_to_the_patch_error(steps, nodata):
    from approxtree.kernels.grid_patch import grid_patch_errors
    from approxtree.tree.blocks import Ancestor, lattice_part, measure_ancestors

    rng = np.random.default_rng(sum(steps))
    z = rng.normal(size=(61, 75)).astype(np.float32)
    # Scattered nodata reaches every edge case of the kernel (and makes the error infinite).
    z[rng.random(z.shape) < nodata] = np.nan
    g = Grid(z)
    index = (3, 58, 2, 70, *steps)
    err, zmin, zmax, count = grid_patch_errors(g.heights, np.array([index[:4]]), np.array([steps]))
    # Parts tiling the patch, sharing border lines like the blocks of a blocked build.
    rows, cols = [3, 17, 18, 40, 58], [2, 9, 33, 34, 70]
    figures = []
    for r0, r1 in itertools.pairwise(rows):
        for c0, c1 in itertools.pairwise(cols):
            anc = Ancestor(0, index, *lattice_part(g.heights, index, (r0, r1, c0, c1)))
            figures.append(measure_ancestors(g.window(r0, r1, c0, c1), (r0, r1, c0, c1), [anc]))
    f = np.concatenate(figures)
    assert np.isinf(err[0]) == (nodata > 0 and steps != (1, 1))
    assert (err[0] > 0) == (steps != (1, 1))
    assert f[:, 0].max() == err[0]
    assert np.nanmin(f[:, 1]) == zmin[0] and np.nanmax(f[:, 2]) == zmax[0]
    assert f[:, 3].sum() == count[0]
