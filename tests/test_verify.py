"""``approxtree verify`` on tree stores: every claim of the stores ``build`` writes holds on every
kind of file in ../shared/data, and a store tampered with in any of the ways a disk, a copy or a
hand can damage it fails (exit 1) naming the part; bad input is one Error line (exit 2)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr
from atree_writer import write_atree
from click.testing import CliRunner
from conftest import data_file
from zarr.storage import LocalStore

import approxtree as at
from approxtree.cli import main

#: name → (data file, window (r0, r1, c0, c1) or None, epsilon, max_points, policy).
STORES = {
    "nc": ("nc/elev_ned_30m.tif", (100, 219, 100, 259), 1.0, 289, "auto"),
    "srtm_voids": ("srtm/N22W160v2.3a.hgt.zip", (984, 1103, 427, 546), 20.0, 289, "auto"),
    "helens_nodata": ("edge/SainteHelens.dem", (0, 140, 0, 120), 5.0, 289, "auto"),
    "hugo_nodata": ("edge/hugo_site.asc", None, 0.5, 81, "auto"),
    "nz_sea": ("edge/nz_elev.tif", (60, 179, 600, 719), 20.0, 289, "auto"),
    # The whole float32 raster as `approxtree build` makes it: its grid patches' corner
    # differences rounded in float32 claimed 3 errors up to 1.5e-5 m short of the true ones.
    "nz_whole_grid": ("edge/nz_elev.tif", None, 1.0, 33 * 33, "type"),
    "lux_degrees": ("roads/lux_elev.tif", None, 10.0, 81, "auto"),
    "crater_scape": ("scape/crater.stm", (0, 150, 0, 120), 5.0, 289, "auto"),
    "dtm": ("edge/dtm.tif", (0, 120, 0, 120), 0.2, 289, "nonregular"),
    "jacksboro": ("edge/jacksboro_fault_dem.npz", (0, 120, 0, 140), 5.0, 289, "rtin"),
    "tin_tile": ("tin/9_533_383.terrain", None, 1.0, 16, "type"),
}


#: Reader options of the files that need them (the npz's cells are in degrees).
OPTIONS = {"jacksboro": {"crs": "EPSG:4326"}}


def _terrain(data_dir: Path, name: str):
    relative, window, *_ = STORES[name]
    terrain = at.open_terrain(str(data_file(data_dir, relative)), **OPTIONS.get(name, {}))
    return terrain if window is None else terrain.window(*window)


def _store(tmp_path: Path, data_dir: Path, name: str, suffix: str = ".zarr") -> tuple[Path, object]:
    terrain = _terrain(data_dir, name)
    _, _, epsilon, max_points, policy = STORES[name]
    tree = at.ApproximationTree.build(
        terrain, epsilon=epsilon, max_points=max_points, policy=policy
    )
    path = tmp_path / f"{name}{suffix}"
    tree.save(path)
    return path, terrain


def _failed(report) -> dict[str, list]:
    return {c.name: c.offenders for c in report.checks.values() if not c.ok}


@pytest.mark.parametrize("name", sorted(STORES))
def test_verify_passes_on_the_stores_build_writes(data_dir, tmp_path, name):
    """Every claim of a built store holds on each kind of data file: node errors recomputed at
    every data point, leaves within ε, boxes, partition, chunks, checksums, terrain."""
    path, terrain = _store(tmp_path, data_dir, name)
    report = at.verify(path, terrain)
    assert report.kind == "tree-store"
    assert report.ok, _failed(report)
    assert report.checks["errors"].items == report.figures["nodes"] > 1
    # The root's error is the true max over the data points (measured, not just bounded).
    assert report.figures["worst_measured_over_claimed"] == pytest.approx(1.0, abs=1e-9)
    assert not report.not_checked


def test_verify_passes_on_a_point_cloud_store_and_a_zip_store(data_dir, tmp_path):
    """A tree over the LAZ's scattered points, saved as a .zarr.zip, passes against the LAZ."""
    laz = data_file(data_dir, "lidar/autzen_trim.laz")
    tree = at.ApproximationTree.build(at.open_terrain(str(laz)), epsilon=5.0, max_points=289)
    path = tmp_path / "laz.zarr.zip"
    tree.save(path)
    report = at.verify(path, str(laz))
    assert report.ok, _failed(report)
    assert report.figures["terrain_kind"] == "tinpointset"
    assert report.figures["data_points"] == 109993


@pytest.fixture
def nc_store(data_dir, tmp_path) -> tuple[Path, str]:
    """A small NC store (grid policy) built by the CLI from a GeoTIFF crop, and that crop."""
    import rasterio
    from affine import Affine
    from rasterio.windows import Window

    src = data_file(data_dir, "nc/elev_ned_30m.tif")
    crop = tmp_path / "crop.tif"
    with rasterio.open(src) as ds:
        profile = ds.profile | {"width": 150, "height": 130}
        data = ds.read(1, window=Window(200, 100, 150, 130))
        t = ds.transform
        transform = Affine(t.a, 0.0, t.c + 200 * t.a, 0.0, t.e, t.f + 100 * t.e)
    with rasterio.open(crop, "w", **(profile | {"transform": transform})) as out:
        out.write(data, 1)
    store = tmp_path / "crop.zarr"
    result = CliRunner().invoke(
        main, ["build", str(crop), "--out", str(store), "--epsilon", "0.5", "--max-points", "81"]
    )
    assert result.exit_code == 0, result.output
    return store, str(crop)


def _verify_cli(*args: str):
    return CliRunner().invoke(main, ["verify", *args])


def test_cli_exit_0_and_json_on_a_good_store(nc_store):
    """verify --json of a good store: exit 0, ok, every check listed with what it covered."""
    store, crop = nc_store
    result = _verify_cli(str(store), "--source", crop, "--json")
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert doc["ok"] and doc["kind"] == "tree-store"
    names = {c["name"] for c in doc["checks"]}
    assert {"metadata", "chunks", "decode", "errors", "epsilon", "bboxes", "partition"} <= names
    text = _verify_cli(str(store), "--source", crop)
    assert text.exit_code == 0 and "every claim holds" in text.output


def _nodes(store: Path) -> zarr.Group:
    return zarr.open_group(LocalStore(str(store)), mode="r+")


def test_a_lowered_error_claim_fails_naming_the_node(nc_store):
    """An error claim rewritten lower (a valid chunk: its crc32c passes) is found by measuring:
    exit 1, the node named with its claim and the true error."""
    store, crop = nc_store
    errors = _nodes(store)["nodes/errors"]
    values = errors[...]
    i = int(np.argmax(values))
    values[i] *= 0.5
    errors[...] = values
    result = _verify_cli(str(store), "--source", crop, "--json")
    assert result.exit_code == 1
    doc = json.loads(result.output)
    (check,) = [c for c in doc["checks"] if not c["ok"]]
    assert check["name"] == "errors" and check["failures"] == 1
    offender = check["offenders"][0]
    assert offender["address"].startswith(f"node {i} ")
    assert offender["measured"] == pytest.approx(2 * offender["claimed"])


@pytest.mark.parametrize(
    "key", ["terrain/heights/c/0/0", "patches/grid/index/c/0/0", "nodes/errors/c/0"]
)
def test_a_deleted_chunk_fails_naming_it(nc_store, key):
    """A chunk file deleted (zarr would read the fill value silently) fails the chunks check
    with its key, and the measurement is not run on fill values."""
    store, crop = nc_store
    (store / key).unlink()
    result = _verify_cli(str(store), "--source", crop)
    assert result.exit_code == 1
    assert f"chunks  {key}  chunk  missing" in result.output
    report = at.verify(store, crop)
    assert not report.checks["chunks"].ok and "errors" not in report.checks


def test_flipped_bytes_in_a_chunk_fail_its_checksum(nc_store):
    """Bytes flipped inside a chunk fail its crc32c: the decode check names the chunk."""
    store, crop = nc_store
    chunk = store / "nodes/errors/c/0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF
    chunk.write_bytes(bytes(data))
    report = at.verify(store, crop)
    assert not report.ok
    assert [o.address for o in report.checks["decode"].offenders] == ["nodes/errors/c/0"]


def test_an_edited_zarr_json_fails_the_metadata_checksum(nc_store):
    """An array's zarr.json edited (its fill value) no longer matches metadata_crc32c."""
    store, crop = nc_store
    doc_path = store / "nodes/rects/zarr.json"
    doc = json.loads(doc_path.read_text())
    doc["fill_value"] = 1.0
    doc_path.write_text(json.dumps(doc))
    report = at.verify(store, crop)
    assert [o.address for o in report.checks["metadata"].offenders] == ["nodes/rects/zarr.json"]


def test_a_moved_child_rectangle_fails_the_partition(nc_store):
    """A child's rectangle shrunk (a valid chunk) leaves a gap in its parent and its own
    children outside it: partition fails naming both."""
    store, crop = nc_store
    rects = _nodes(store)["nodes/rects"]
    values = rects[...]
    values[1, 2] -= 30.0
    rects[...] = values
    report = at.verify(store, crop)
    assert sorted(o.address for o in report.checks["partition"].offenders) == ["node 0", "node 1"]


def test_another_source_fails_the_terrain_check(nc_store, data_dir):
    """Verifying against another DEM than the one built from fails the terrain check."""
    store, _ = nc_store
    report = at.verify(store, str(data_file(data_dir, "nc/elev_ned_30m.tif")))
    assert not report.checks["terrain"].ok


def test_without_a_source_only_the_store_itself_is_checked(nc_store):
    """No --source: chunks, checksums and structure are checked, errors listed as not checked."""
    store, _ = nc_store
    report = at.verify(store)
    assert report.ok and "errors" not in report.checks
    assert any("no source" in line for line in report.not_checked)


def test_bad_input_is_one_error_line(nc_store, tmp_path, data_dir):
    """A missing output, a file that is no output, a legacy .atree, another zarr store, an
    unreadable source: exit 2 with one Error line each, never a traceback."""
    store, crop = nc_store
    legacy = tmp_path / "t.atree"
    write_atree(at.load_tree(store), legacy)
    other = tmp_path / "other.zarr"
    zarr.open_group(LocalStore(str(other)), mode="w").attrs["x"] = 1
    broken = tmp_path / "broken.tif"
    broken.write_bytes(b"not a tiff")
    cases = [
        [str(tmp_path / "missing.zarr"), "--source", crop],
        [crop, "--source", crop],
        [str(legacy), "--source", crop],
        [str(other), "--source", crop],
        [str(store), "--source", str(broken)],
    ]
    for args in cases:
        result = _verify_cli(*args)
        assert result.exit_code == 2, (args, result.output)
        lines = [ln for ln in result.output.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("Error: "), (args, result.output)
    shutil.rmtree(other)


def test_small_windows_measure_what_one_window_does(nc_store, monkeypatch):
    """Nodes cut into many windows (64 lattice points a side here, 512 by default: a raster
    past 512 cells) are measured exactly as in one window (the 1201² SRTM tile's nodes came
    out uncovered when a node's triangles were kept for the next window)."""
    import approxtree.verify.measure as measure

    store, crop = nc_store
    whole = at.verify(store, crop)
    monkeypatch.setattr(measure, "TILE", 64)
    cut = at.verify(store, crop)
    assert whole.ok and cut.ok, _failed(cut)
    assert cut.figures == whole.figures
