"""The zarr v3 tree store: round trips of every strategy and terrain kind, lazy patch reads,
checksums on every chunk, zip and fsspec URLs, atomic writes, the convert and info commands."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import uuid
from pathlib import Path

import numpy as np
import pytest
from atree_writer import write_atree
from click.testing import CliRunner

import approxtree as at
from approxtree import ApproximationTree, GridRefinement, PointQuadtree, load_tree
from approxtree.cli import main
from approxtree.datasets import case_study_terrain, fractal_terrain
from approxtree.errors import StoreError
from approxtree.patches import GeometryPatch
from approxtree.patches.records import record_at
from approxtree.tree.tree_store import NODE_ARRAYS, TreeStoreSource
from approxtree.tree.zarr_store import StoreReader, ZarrHeightSource

NODE_FIELDS = NODE_ARRAYS
base_records_many = GeometryPatch.records_many.__func__


def same_tree(a: ApproximationTree, b: ApproximationTree) -> None:
    """Identical node arrays, terrain records and patch meshes (every node)."""
    for name in NODE_FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert getattr(a, name).dtype == getattr(b, name).dtype, name
    assert a.strategy_names == b.strategy_names and a.params == b.params
    ta, tb = a.terrain.to_record(), b.terrain.to_record()
    # A loaded grid reads its heights windowed from the store; that is how, not what, it holds.
    ka, kb = ({k: v for k, v in t[0].items() if k != "windowed"} for t in (ta, tb))
    assert type(a.terrain) is type(b.terrain) and ka == kb
    for name in ta[1]:
        np.testing.assert_array_equal(ta[1][name], tb[1][name], err_msg=name)
        assert np.asarray(ta[1][name]).dtype == np.asarray(tb[1][name]).dtype, name
    for i in range(len(a)):
        pa, pb = a.patch(i), b.patch(i)
        assert type(pa) is type(pb), i
        np.testing.assert_array_equal(pa.vertices, pb.vertices, err_msg=str(i))
        np.testing.assert_array_equal(pa.triangles, pb.triangles, err_msg=str(i))
        np.testing.assert_array_equal(
            [pa.error, *pa.z_range, pa.data_count], [pb.error, *pb.z_range, pb.data_count]
        )


@pytest.fixture(scope="module")
def grid() -> at.Grid:
    """A 65 × 65 fractal with a nodata hole (holes are stored as NaN)."""
    g = fractal_terrain(65, seed=3)
    h = np.array(g.heights)
    h[5:9, 40:50] = np.nan
    return at.Grid(h, g.transform, g.crs, g.nodata)


@pytest.mark.parametrize("policy", ["grid", "tin", "rtin", "nonregular", "auto"])
def test_round_trip_every_strategy(grid, policy, tmp_path):
    """save → load of a store gives identical node arrays, terrain and patch meshes."""
    tree = ApproximationTree.build(grid, epsilon=0.3, max_points=25, policy=policy)
    if policy == "auto":
        assert len(tree.strategy_names) > 1  # a hybrid tree mixes strategies
    path = tmp_path / "t.zarr"
    nbytes = tree.save(path)
    assert (path / "zarr.json").is_file() and nbytes > 0
    back = load_tree(path)
    assert isinstance(back._source, TreeStoreSource)
    same_tree(tree, back)


def test_records_many_equals_to_record(grid):
    """Each strategy's batched records hold exactly every patch's to_record, raveled."""
    tree = ApproximationTree.build(grid, epsilon=0.3, max_points=25, policy="auto")
    for s in range(len(tree.strategy_names)):
        patches = [tree.patch(i) for i in np.flatnonzero(tree.strategies == s)]
        batch = type(patches[0]).records_many(patches)
        # Every strategy gathers its attributes (no fallback to per-patch to_record).
        assert type(patches[0]).records_many.__func__ is not base_records_many
        for k, p in enumerate(patches):
            expected = p.to_record()
            got = record_at(batch, k)
            assert expected.keys() == got.keys()
            for field in expected:
                np.testing.assert_array_equal(got[field], expected[field].reshape(-1))
                assert got[field].dtype == expected[field].dtype


def test_grid_records_many_fixed_width():
    g = fractal_terrain(33, seed=1)
    tree = ApproximationTree.build(g, epsilon=0.1, max_points=9, policy="grid")
    patches = [tree.patch(i) for i in range(len(tree))]
    batch = type(patches[0]).records_many(patches)
    for k, p in enumerate(patches):
        for field, value in p.to_record().items():
            np.testing.assert_array_equal(record_at(batch, k)[field], value)


def test_point_set_terrain_round_trip(tmp_path):
    rng = np.random.default_rng(5)
    xyz = np.column_stack([rng.uniform(0, 50, (600, 2)), rng.normal(0, 3, 600)])
    tree = ApproximationTree.build(at.TINPointSet(xyz), epsilon=0.2, max_points=16, policy="tin")
    tree.save(tmp_path / "p.zarr")
    back = load_tree(tmp_path / "p.zarr")
    assert back.terrain.kind == "tinpointset"
    same_tree(tree, back)


def test_grid_refinement_round_trip(tmp_path):
    g, tins = case_study_terrain(seed=4, rows=41, cols=61, microstructures=40)
    tree = ApproximationTree.build(GridRefinement(g, tins), epsilon=1.0, max_points=49)
    tree.save(tmp_path / "r.zarr")
    back = load_tree(tmp_path / "r.zarr")
    assert isinstance(back.terrain, GridRefinement)
    assert len(back.terrain.microstructures) == len(tins)
    same_tree(tree, back)


def test_point_quadtree_round_trip(tmp_path):
    from approxtree.render.lod_cut import lod_mesh

    rng = np.random.default_rng(7)
    xy = np.concatenate([rng.uniform(0, 100, (400, 2)), rng.uniform(0, 20, (600, 2))])
    z = np.sin(xy[:, 0] / 9.0) * 5
    q = PointQuadtree(at.TINPointSet(np.column_stack([xy, z])), max_points=20)
    path = tmp_path / "q.zarr"
    q.save(path)
    assert (path / "quadtree" / "orders" / "zarr.json").is_file()
    write_atree(q, tmp_path / "q.atree")
    res = CliRunner().invoke(main, ["convert", str(tmp_path / "q.atree"), str(tmp_path / "c.zip")])
    assert res.exit_code == 0, res.output
    trees = (load_tree(path), PointQuadtree.load(path), load_tree(tmp_path / "c.zip"))
    for back in trees:
        assert isinstance(back, PointQuadtree)
        assert back.children == q.children and back.errors == q.errors
        for leaf in q.leaves:
            np.testing.assert_array_equal(back.orders[leaf][0], q.orders[leaf][0])
        eye = (q.x0 - 10, q.y0 - 10, 30.0)
        a, b = lod_mesh(q, eye, 60.0, 640, 2.0), lod_mesh(back, eye, 60.0, 640, 2.0)
        np.testing.assert_array_equal(a.triangles, b.triangles)


def test_lazy_patch_reads_only_that_node(grid, tmp_path):
    """Loading reads no patch object; patch(i) builds node i's patch only."""
    tree = ApproximationTree.build(grid, epsilon=0.3, max_points=25, policy="tin")
    tree.save(tmp_path / "t.zarr")
    back = ApproximationTree.load(tmp_path / "t.zarr", verify=False)
    assert all(p is None for p in back._patches)
    i = len(back) - 1
    p = back.patch(i)
    assert [k for k, q in enumerate(back._patches) if q is not None] == [i]
    np.testing.assert_array_equal(p.triangles, tree.patch(i).triangles)


def test_subtree_patches_are_contiguous(tmp_path):
    """The patch slots of every level-L subtree form one contiguous run."""
    tree = ApproximationTree.build(fractal_terrain(129, seed=2), epsilon=0.05, max_points=16)
    tree.save(tmp_path / "t.zarr")
    reader = StoreReader(tmp_path / "t.zarr")
    level = reader.meta["ancestor_level"]
    assert 0 < level < tree.levels.max()
    slot = reader.read("nodes/patch_slot")
    for root in np.flatnonzero(tree.levels == level)[:20]:
        members, frontier = [root], [root]
        while frontier:
            kids = [
                c for n in frontier for c in tree.child_start[n] + np.arange(tree.child_count[n])
            ]
            members += kids
            frontier = kids
        s = np.sort(slot[members])
        assert (np.diff(s) == 1).all()


def test_height_source_reads_windows(grid, tmp_path):
    """ZarrHeightSource.read is half-open and matches the grid's heights (NaN nodata)."""
    ApproximationTree.build(grid, epsilon=1.0, max_points=25).save(tmp_path / "t.zarr")
    src = ZarrHeightSource(str(tmp_path / "t.zarr"))
    assert src.shape == grid.heights.shape
    np.testing.assert_array_equal(src.read(3, 10, 38, 52), grid.heights[3:10, 38:52])
    import pickle

    again = pickle.loads(pickle.dumps(src))
    assert again._reader is None and len(pickle.dumps(src)) < 1000
    np.testing.assert_array_equal(again.read(0, 2, 0, 2), grid.heights[:2, :2])


def test_heights_written_block_by_block(tmp_path):
    """The heights go in as 512 × 512-chunk windows, never as one whole-array read."""
    g = fractal_terrain(700, 600, seed=1)
    seen = []

    class Lazy:
        shape, dtype, ndim = g.heights.shape, g.heights.dtype, 2

        def __getitem__(self, key):
            rows, cols = key
            seen.append((rows.stop - rows.start, cols.stop - cols.start))
            return g.heights[key]

    from approxtree.tree.zarr_store import HEIGHT_CHUNK, write_array, writing

    with writing(tmp_path / "h.zarr", {"tree_kind": "test"}) as root:
        write_array(root, "heights", Lazy(), chunks=(HEIGHT_CHUNK, HEIGHT_CHUNK))
    assert max(r for r, _ in seen) <= HEIGHT_CHUNK and len(seen) >= 2
    np.testing.assert_array_equal(StoreReader(tmp_path / "h.zarr").read("heights"), g.heights)


def chunk_files(store: Path) -> list[Path]:
    return sorted(p for p in store.rglob("*") if p.is_file() and p.name != "zarr.json")


def test_flipped_byte_in_every_chunk_is_a_store_error(tmp_path):
    """For each chunk file in turn: one flipped byte → StoreError when loaded (verify) or read."""
    terrain = fractal_terrain(33, seed=1)
    tree = ApproximationTree.build(terrain, epsilon=0.3, max_points=16, policy="auto")
    good = tmp_path / "good.zarr"
    tree.save(good)
    files = chunk_files(good)
    assert len(files) >= 20
    for f in files:
        data = bytearray(f.read_bytes())
        data[len(data) // 2] ^= 0x10
        f.write_bytes(bytes(data))
        with pytest.raises(StoreError, match="corrupted") as info:
            # verify=True reads every chunk but the terrain heights', which stay in the store
            # (read windowed) and are checked as each window is read.
            loaded = load_tree(good)
            np.asarray(loaded.terrain.heights[:, :])
        assert str(good) in str(info.value) and "Rebuild" in str(info.value)
        data[len(data) // 2] ^= 0x10
        f.write_bytes(bytes(data))
    same_tree(tree, load_tree(good))


def test_missing_or_corrupt_metadata_or_chunk(tmp_path):
    tree = ApproximationTree.build(fractal_terrain(33, seed=1), epsilon=0.3, max_points=16)
    path = tmp_path / "t.zarr"
    tree.save(path)
    meta = path / "nodes" / "errors" / "zarr.json"
    text = meta.read_text()
    # A change that still parses (a different fill value) is caught by the metadata checksum.
    meta.write_text(text.replace('"fill_value": 0.0', '"fill_value": 1.0'))
    with pytest.raises(StoreError, match="checksum"):
        load_tree(path)
    meta.write_text("{not json")
    with pytest.raises(StoreError, match="nodes/errors"):
        load_tree(path)
    meta.unlink()
    with pytest.raises(StoreError):
        load_tree(path)
    meta.write_text(text)
    next(iter((path / "patches").rglob("c/0"))).unlink()
    with pytest.raises(StoreError, match="chunks"):
        load_tree(path)
    (path / "zarr.json").unlink()
    with pytest.raises(StoreError, match=str(path)):
        load_tree(path)


def test_zip_and_memory_round_trips(grid, tmp_path):
    tree = ApproximationTree.build(grid, epsilon=0.3, max_points=25, policy="auto")
    tree.save(tmp_path / "t.zarr.zip")
    assert (tmp_path / "t.zarr.zip").is_file()
    same_tree(tree, load_tree(tmp_path / "t.zarr.zip"))
    url = f"memory://approxtree-test-{uuid.uuid4().hex}/t.zarr"
    tree.save(url)
    same_tree(tree, load_tree(url))


def test_memory_store_without_commit_does_not_open():
    """A URL store whose root attributes were never committed is refused."""
    import zarr
    from zarr.storage import FsspecStore

    url = f"memory://approxtree-test-{uuid.uuid4().hex}/half.zarr"
    zarr.open_group(FsspecStore.from_url(url), mode="w").create_group("nodes")
    with pytest.raises(StoreError, match="not a complete"):
        load_tree(url)


_WRITER = textwrap.dedent(
    """
    import os, sys
    from approxtree import ApproximationTree
    from approxtree.datasets import fractal_terrain
    import approxtree.tree.zarr_store as zs

    tree = ApproximationTree.build(fractal_terrain(65, seed=int(sys.argv[2])), epsilon=0.3,
                                   max_points=16, policy="tin")
    real = zs.write_array
    count = [0]

    def slow(*args, **kwargs):
        count[0] += 1
        if count[0] == 8:  # halfway through the store: tell the parent, then wait to die
            print("writing", flush=True)
            sys.stdin.readline()
        return real(*args, **kwargs)

    zs.write_array = slow
    import approxtree.tree.tree_store as ts
    ts.write_array = slow
    tree.save(sys.argv[1])
    """
)


@pytest.mark.parametrize("name", ["t.zarr", "t.zarr.zip"])
def test_killed_write_leaves_nothing_that_opens(name, tmp_path):
    """SIGKILL mid-write: no new store opens, an old one is intact, and the next write
    removes the dead writer's temp."""
    target = tmp_path / name

    def killed_write(seed: int) -> None:
        proc = subprocess.Popen(
            [sys.executable, "-c", _WRITER, str(target), str(seed)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert proc.stdout.readline().strip() == "writing"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()

    killed_write(1)
    assert not target.exists()
    with pytest.raises(StoreError):
        load_tree(target)
    temps = [p for p in tmp_path.iterdir() if p.name.startswith(f".{name}.")]
    assert temps and all(p.name.endswith(".tmp") for p in temps)
    old = ApproximationTree.build(fractal_terrain(33, seed=9), epsilon=0.3, max_points=16)
    old.save(target)
    assert not any(p.name.startswith(f".{name}.") for p in tmp_path.iterdir())
    killed_write(2)
    same_tree(old, load_tree(target))


def test_convert_cli_atree_to_store_zip_and_back(grid, tmp_path):
    tree = ApproximationTree.build(grid, epsilon=0.3, max_points=25, policy="auto")
    write_atree(tree, tmp_path / "old.atree")
    runner = CliRunner()
    steps = [("old.atree", "new.zarr"), ("new.zarr", "new.zarr.zip"), ("new.zarr.zip", "back.zarr")]
    for src, dst in steps:
        res = runner.invoke(main, ["convert", str(tmp_path / src), str(tmp_path / dst), "--json"])
        assert res.exit_code == 0, res.output
        figures = json.loads(res.output)
        assert figures["nodes"] == len(tree) and figures["bytes"] > 0
        same_tree(tree, load_tree(tmp_path / dst))
    res = runner.invoke(main, ["convert", str(tmp_path / "grid.npy"), str(tmp_path / "x.zarr")])
    assert res.exit_code == 2 and "not a saved tree" in res.output


def test_unreadable_atree_version_names_convert(grid, tmp_path):
    path = tmp_path / "v9.atree"
    write_atree(ApproximationTree.build(grid, epsilon=1.0, max_points=25), path)
    data = bytearray(path.read_bytes())
    data[8] = 9  # format version 9
    path.write_bytes(bytes(data))
    with pytest.raises(StoreError, match="approxtree convert"):
        load_tree(path)


def test_info_on_a_store(grid, tmp_path):
    tree = ApproximationTree.build(grid, epsilon=0.3, max_points=25, policy="auto")
    tree.save(tmp_path / "t.zarr")
    res = CliRunner().invoke(main, ["info", str(tmp_path / "t.zarr"), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["format_version"] == 1 and info["nodes"] == len(tree)
    assert info["levels"] == int(tree.levels.max()) + 1
    assert info["strategies"] == tree.strategy_counts
    assert info["chunks"]["terrain/heights"]["chunks"] == [512, 512]
    assert 0 < info["bytes_stored"] < info["bytes_raw"]
    res = CliRunner().invoke(main, ["info", str(tmp_path / "t.zarr")])
    assert res.exit_code == 0 and "terrain/heights: 65×65 in 512×512 chunks (1)" in res.output


def test_build_defaults_to_a_store_and_render_reads_it(grid, tmp_path, monkeypatch):
    np.save(tmp_path / "dem.npy", np.asarray(grid.heights))
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["build", "dem.npy", "--epsilon", "1", "--json"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "dem.zarr" / "zarr.json").is_file()
    assert isinstance(load_tree("dem.zarr"), ApproximationTree)
    # Rebuilding over an existing store replaces it.
    res = CliRunner().invoke(main, ["build", "dem.npy", "--epsilon", "2", "--out", "dem.zarr"])
    assert res.exit_code == 0, res.output
    assert load_tree("dem.zarr").epsilon == 2.0


def test_render_and_bake_read_a_store(grid, tmp_path):
    """render draws the same image from a store as from the .atree; bake takes a store."""
    from PIL import Image

    pytest.importorskip("moderngl")
    tree = ApproximationTree.build(grid, epsilon=0.3, max_points=25, policy="auto")
    write_atree(tree, tmp_path / "t.atree")
    tree.save(tmp_path / "t.zarr")
    assert (tmp_path / "t.zarr" / "zarr.json").is_file()
    images = []
    for name in ("t.atree", "t.zarr"):
        png = tmp_path / f"{name}.png"
        args = ["render", str(tmp_path / name), "--out", str(png), "--size", "160x120"]
        res = CliRunner().invoke(main, args)
        if res.exit_code == 2 and "context" in res.output.lower():
            pytest.skip(f"no OpenGL context: {res.output.strip()}")
        assert res.exit_code == 0, res.output
        images.append(np.asarray(Image.open(png)))
    assert images[0].any()
    np.testing.assert_array_equal(images[0], images[1])
    out = tmp_path / "tex"
    res = CliRunner().invoke(main, ["bake", str(tmp_path / "t.zarr"), "--out", str(out), "--no-gl"])
    assert res.exit_code == 0, res.output
    assert (out / "pyramid.json").is_file()


def test_store_to_store_copy_follows_the_storage_order(grid, tmp_path, monkeypatch):
    """Re-saving a loaded store under another subtree level reorders its records right."""
    import approxtree.tree.tree_store as ts

    tree = ApproximationTree.build(grid, epsilon=0.3, max_points=25, policy="auto")
    tree.save(tmp_path / "a.zarr")
    loaded = load_tree(tmp_path / "a.zarr")
    monkeypatch.setattr(ts, "SUBTREE_ROOTS", 4)
    loaded.save(tmp_path / "b.zarr")
    assert StoreReader(tmp_path / "b.zarr").meta["ancestor_level"] == 1
    assert StoreReader(tmp_path / "a.zarr").meta["ancestor_level"] > 1
    same_tree(tree, load_tree(tmp_path / "b.zarr"))


def test_coarse_grid_patches_carry_their_lattice(tmp_path, monkeypatch):
    """A coarse grid patch's lattice touches a terrain chunk per vertex; its record carries the
    lattice heights, so drawing it reads nothing of the stored terrain — and the mesh is the
    same as the one read from the terrain."""
    from approxtree.patches.grid import LATTICE_STORED_STEP

    terrain = fractal_terrain(513, seed=4)
    h = np.array(terrain.heights)
    h[100:140, 300:420] = np.nan
    terrain = at.Grid(h, terrain.transform, terrain.crs)
    tree = ApproximationTree.build(terrain, epsilon=0.05, max_points=9)
    coarse = [i for i in range(len(tree)) if max(tree.patch(i).steps) >= LATTICE_STORED_STEP]
    assert len(coarse) >= 5
    path = tmp_path / "t.zarr"
    tree.save(path)
    back = load_tree(path)

    def no_reads(*args, **kwargs):
        raise AssertionError("a coarse patch read the stored terrain")

    monkeypatch.setattr(ZarrHeightSource, "read", no_reads)
    for i in coarse:
        np.testing.assert_array_equal(back.read_patch(i).vertices, tree.patch(i).vertices)
        np.testing.assert_array_equal(back.read_patch(i).triangles, tree.patch(i).triangles)
    monkeypatch.undo()
    same_tree(tree, back)


def test_windowed_save_reads_the_band_once(tmp_path):
    """The save of a blocked build over a windowed grid copies the band once, picking the
    coarse patches' lattices as it streams past: no statistics scan (the build's root gave the
    band's figures), no second pass for the lattices. The store equals the in-memory build's."""
    from approxtree.geometry.windowed import ArraySource, WindowedHeights

    z = np.asarray(fractal_terrain(513, seed=8).heights)
    source = ArraySource(z)
    g = at.Grid(WindowedHeights(source, cache_bytes=1 << 18, block_shape=(64, 64)))
    tree = ApproximationTree.build(g, epsilon=0.05, max_points=9, block_size=128)
    assert any(max(tree.patch(i).steps) >= 16 for i in range(len(tree)))
    before = source.cells_read
    tree.save(tmp_path / "w.zarr")
    assert source.cells_read - before == z.size
    ref = ApproximationTree.build(at.Grid(z), epsilon=0.05, max_points=9)
    same_tree(ref, load_tree(tmp_path / "w.zarr"))


def test_stored_overview_feeds_the_normal_map(tmp_path, monkeypatch):
    """A grid larger than the overview keeps ``heights[::rs, ::cs]`` beside its heights; the
    Engine's normal map reads it instead of every terrain chunk, and draws the same pixels."""
    from affine import Affine

    import approxtree.geometry.grid as grid_module
    from approxtree.render import Engine
    from approxtree.render import normal_map as normal_map_module

    monkeypatch.setattr(grid_module, "OVERVIEW_SIDE", 64)
    monkeypatch.setattr(normal_map_module, "NORMAL_MAP_MAX", 64)
    base = fractal_terrain(300, seed=2)
    z = np.array(base.heights)
    z[10:20, 5:50] = np.nan
    for t in (base.transform, Affine(2.0, 0, 100, 0, 3.0, 50), Affine(-2.0, 0, 900, 0, -3.0, 950)):
        grid = at.Grid(z, t)
        rs, cs = grid.overview_steps()
        assert max(abs(rs), abs(cs)) == 5
        tree = ApproximationTree.build(grid, epsilon=5.0)
        path = tmp_path / f"t{t.a:g}{t.e:g}.zarr"
        tree.save(path)
        back = load_tree(path)
        np.testing.assert_array_equal(back.terrain.strided_heights(rs, cs), z[::rs, ::cs])
        with Engine(tree) as e:
            want = np.array(e.normal_map.read())
        monkeypatch.setattr(ZarrHeightSource, "read", _no_terrain_reads)
        with Engine(back) as e:
            np.testing.assert_array_equal(np.array(e.normal_map.read()), want)
        monkeypatch.undo()
        monkeypatch.setattr(grid_module, "OVERVIEW_SIDE", 64)
        monkeypatch.setattr(normal_map_module, "NORMAL_MAP_MAX", 64)


def _no_terrain_reads(*args, **kwargs):
    raise AssertionError("the normal map read the stored terrain")


def test_saving_a_grid_build_writes_records_from_its_arrays(tmp_path):
    """A built grid tree's records come straight from its level arrays, equal to the records
    of its patch objects; saving makes objects only for the coarse patches whose records carry
    their lattice, and the store loads back node for node."""
    from approxtree.patches.grid import LATTICE_STORED_STEP, GridPatch

    h = np.array(fractal_terrain(300, seed=11).heights)
    h[40:90, 200:260] = np.nan
    terrain = at.Grid(h, fractal_terrain(300, seed=11).transform)
    tree = ApproximationTree.build(terrain, epsilon=0.1, max_points=9)
    table = tree._patches
    steps = table.arrays.index[table.row, 4:]
    coarse = int((steps.max(axis=1) >= LATTICE_STORED_STEP).sum())
    assert table.held == 0 and coarse >= 5
    tree.save(tmp_path / "t.zarr")
    assert table.held == coarse
    back = load_tree(tmp_path / "t.zarr")
    nodes = np.random.default_rng(1).permutation(len(tree))[: len(tree) // 2]
    batch = table.records(nodes)
    ref = GridPatch.records_many([tree.patch(int(i)) for i in nodes])
    assert batch.keys() == ref.keys()
    for name, (flat, offsets) in ref.items():
        np.testing.assert_array_equal(batch[name][0], flat, err_msg=name)
        np.testing.assert_array_equal(batch[name][1], offsets, err_msg=name)
        assert batch[name][0].dtype == flat.dtype, name
    same_tree(tree, back)


def test_two_saves_of_a_tree_are_byte_identical(tmp_path):
    """Every file of a store, the root zarr.json included (its metadata checksums are listed
    by path), is the same byte for byte when the same tree is saved twice."""
    tree = ApproximationTree.build(fractal_terrain(130, seed=12), epsilon=0.5, max_points=25)
    stores = [tmp_path / "a.zarr", tmp_path / "b.zarr"]
    for path in stores:
        tree.save(path)
    files = [sorted(p.relative_to(s) for p in s.rglob("*") if p.is_file()) for s in stores]
    assert files[0] == files[1] and Path("zarr.json") in files[0]
    for name in files[0]:
        assert (stores[0] / name).read_bytes() == (stores[1] / name).read_bytes(), name
    sums = json.loads((stores[0] / "zarr.json").read_text())["attributes"]["metadata_crc32c"]
    assert list(sums) == sorted(sums)
