"""Block tasks write a windowed terrain's heights into the store (zarr regions): every chunk
once, the very store the client's copy writes, and still all or nothing."""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from click.testing import CliRunner

from approxtree import ApproximationTree, Grid
from approxtree.datasets import write_fractal_terrain
from approxtree.errors import StoreError
from approxtree.io import open_terrain
from approxtree.tree.blocks import plan_blocks
from approxtree.tree.store_regions import HeightRegions, height_regions
from approxtree.tree.tree_store import save_tree


def _files(folder: Path) -> dict[str, str]:
    """{relative path: sha256} of every file below ``folder``."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def dem(tmp_path_factory) -> Path:
    """A 1100 × 1300 fractal GeoTIFF with holes: 3 × 3 height chunks, partial at the edges."""
    path = tmp_path_factory.mktemp("regions") / "dem.tif"
    return write_fractal_terrain(path, 1100, 1300, seed=4, holes=0.1, wavelength=512, block=512)


@pytest.fixture(scope="module")
def copied(dem, tmp_path_factory) -> Path:
    """The store of the client's copy: a windowed build in process, then ``tree.save``."""
    out = tmp_path_factory.mktemp("copy") / "copy.zarr"
    tree = ApproximationTree.build(open_terrain(dem, windowed=True), 1.0, 17 * 17, 4)
    tree.save(out)
    return out


@pytest.mark.parametrize(
    ("shape", "fanout", "block_size"),
    [((1100, 1300), 4, 256), ((1100, 1300), 2, 200), ((513, 1025), 4, 64), ((2049, 700), 4, 512)],
)
def test_owned_chunks_tile_the_heights_once(shape, fanout, block_size):
    """The chunks the blocks own cover every chunk of the heights exactly once, whole."""
    g = Grid(np.zeros(shape, dtype=np.float32), Affine(1.0, 0, 0, 0, -1.0, 0))
    plan = plan_blocks(g, fanout, block_size)
    regions = HeightRegions("unused", shape, "<f4", None)
    count = np.zeros((-(-shape[0] // 512), -(-shape[1] // 512)), dtype=np.int64)
    for node in plan.blocks:
        r0, r1, c0, c1 = regions.owned(plan.index[node])
        if r0 >= r1 or c0 >= c1:
            continue  # no chunk starts in this block
        assert r0 % 512 == 0 and c0 % 512 == 0
        assert r1 in (shape[0], *range(0, shape[0], 512)) and c1 in (
            shape[1],
            *range(0, shape[1], 512),
        )
        for i, j in itertools.product(
            range(r0 // 512, -(-r1 // 512)), range(c0 // 512, -(-c1 // 512))
        ):
            count[i, j] += 1
    assert (count == 1).all()


def test_cli_workers_store_equals_the_client_copy_byte_for_byte(dem, copied, tmp_path):
    """`build --workers 2` (tasks write the heights) writes every file of the copy's store."""
    from approxtree.cli import main

    out = tmp_path / "tasks.zarr"
    args = ["build", str(dem), "--out", str(out), "--windowed", "on", "--workers", "2"]
    args += ["--epsilon", "1", "--max-points", str(17 * 17), "--block-size", "256", "--json"]
    r = CliRunner().invoke(main, args, catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert json.loads(r.output.splitlines()[-1])["nodes"] > 100
    assert _files(out) == _files(copied)
    # Nothing is left beside the store: no scratch folder, no temp.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tasks.zarr"]


@pytest.mark.parametrize("name", ["t.zarr", "t.zarr.zip"])
def test_in_process_regions_with_an_overview_equal_the_copy(dem, tmp_path, monkeypatch, name):
    """In-process regions with an overview (steps −3, 3) give the copy's store, zip or not."""
    import approxtree.geometry.grid as grid_module

    monkeypatch.setattr(grid_module, "OVERVIEW_SIDE", 500)
    g = open_terrain(dem, windowed=True)
    copy = tmp_path / "copy" / name
    copy.parent.mkdir()
    ApproximationTree.build(g, 1.0, 17 * 17, 4, block_size=256).save(copy)
    out = tmp_path / "tasks" / name
    out.parent.mkdir()
    g = open_terrain(dem, windowed=True)
    with height_regions(out, g) as regions:
        tree = ApproximationTree.build(g, 1.0, 17 * 17, 4, block_size=256, regions=regions)
        assert regions.complete and regions.steps == (-3, 3)
        save_tree(tree, out, regions=regions)
    assert [p.name for p in out.parent.iterdir()] == [name]
    if name.endswith(".zarr"):
        assert "terrain/overview/zarr.json" in _files(out)
        assert _files(out) == _files(copy)
        return
    a, b = ApproximationTree.load(out), ApproximationTree.load(copy)
    np.testing.assert_array_equal(a.errors, b.errors)
    for i in (0, 1, len(a) - 1):
        np.testing.assert_array_equal(a.patch(i).to_record()["z"], b.patch(i).to_record()["z"])
    za = np.asarray(a.terrain.heights[0:1100, 0:1300])
    zb = np.asarray(b.terrain.heights[0:1100, 0:1300])
    np.testing.assert_array_equal(za, zb)
    np.testing.assert_array_equal(a.terrain.strided_heights(-3, 3), zb[::-3, ::3])


def test_failed_block_leaves_no_store_and_no_scratch(dem, tmp_path, monkeypatch):
    """A block failing after others wrote their chunks: no store, no scratch folder."""
    real = HeightRegions.write
    calls = [0]

    def failing(self, heights, index):
        calls[0] += 1
        if calls[0] == 3:
            raise OSError("disk gone")
        return real(self, heights, index)

    monkeypatch.setattr(HeightRegions, "write", failing)
    out = tmp_path / "t.zarr"
    g = open_terrain(dem, windowed=True)
    with pytest.raises(OSError, match="disk gone"), height_regions(out, g) as regions:
        tree = ApproximationTree.build(g, 1.0, 17 * 17, 4, block_size=256, regions=regions)
        save_tree(tree, out, regions=regions)
    assert list(tmp_path.iterdir()) == []


_KILLED = textwrap.dedent(
    """
    import sys
    from approxtree import ApproximationTree
    from approxtree.io import open_terrain
    from approxtree.tree.store_regions import HeightRegions, height_regions
    from approxtree.tree.tree_store import save_tree

    real = HeightRegions.write
    calls = [0]

    def slow(self, heights, index):
        calls[0] += 1
        if calls[0] == 3:  # some chunks written: tell the parent, then wait to die
            print("writing", flush=True)
            sys.stdin.readline()
        return real(self, heights, index)

    HeightRegions.write = slow
    g = open_terrain(sys.argv[2], windowed=True)
    with height_regions(sys.argv[1], g) as regions:
        tree = ApproximationTree.build(g, 1.0, 289, 4, block_size=256, regions=regions)
        save_tree(tree, sys.argv[1], regions=regions)
    """
)


def test_killed_build_leaves_no_store_and_the_next_write_removes_its_scratch(dem, copied, tmp_path):
    """SIGKILL mid-regions: no store, only a temp-named scratch the next write removes."""
    target = tmp_path / "t.zarr"
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED, str(target), str(dem)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert proc.stdout.readline().strip() == "writing"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not target.exists()
    with pytest.raises(StoreError):
        ApproximationTree.load(target)
    temps = [p.name for p in tmp_path.iterdir()]
    assert temps and all(n.startswith(".t.zarr.") and n.endswith(".tmp") for n in temps)
    ApproximationTree.load(copied).save(target)
    assert [p.name for p in tmp_path.iterdir()] == ["t.zarr"]
