"""``approxtree verify`` on 3D Tiles folders: every content present and parsed, each tile
within its geometricError at the source's data points (positions through ECEF and back),
volumes nested, external tilesets followed; a deleted or edited tile fails (exit 1) naming it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import data_file
from test_verify_mesh import crop, move_glb_vertex

from approxtree.cli import main


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


#: name → (data file, crop (row, col, rows, cols) or None, epsilon).
SOURCES = {
    "nc": ("nc/elev_ned_30m.tif", (100, 100, 120, 160), 1.0),
    "srtm": ("srtm/N44W072.hgt", (700, 600, 100, 120), 10.0),
    "helens": ("edge/SainteHelens.dem", None, 20.0),
    "crater": ("scape/crater.stm", None, 20.0),
    "laz": ("lidar/autzen_trim.laz", None, 10.0),
    # Steep slivers (trees) near border vertices: one slack for every tile (the terrain's
    # extent) let a sliver's plane count 3e-3 ft outside itself, 13.4 ft off.
    "laz_fine": ("lidar/autzen_trim.laz", None, 1.0),
    "hugo": ("edge/hugo_site.asc", None, 1.0),
}


@pytest.fixture(scope="module")
def tilesets(data_dir, tmp_path_factory):
    """name → (source file, tileset folder), each written by build then tiles on first use."""
    made: dict[str, tuple[Path, Path]] = {}

    def get(name: str) -> tuple[Path, Path]:
        if name not in made:
            relative, window, epsilon = SOURCES[name]
            folder = tmp_path_factory.mktemp(name)
            source = data_file(data_dir, relative)
            if window is not None:
                source = crop(source, folder / "crop.tif", *window)
            store, tiles = folder / "t.zarr", folder / "tiles"
            built = run("build", source, "--out", store, "--epsilon", epsilon, "--max-points", 289)
            assert built.exit_code == 0, built.output
            # Float32 positions (a vertex is edited in place below); compressed tilesets are
            # verified by test_verify_compact_tiles.
            written = run(
                "tiles", store, "--out", tiles, "--format", "3dtiles", "--compression", "none"
            )
            assert written.exit_code == 0, written.output
            made[name] = (source, tiles)
        return made[name]

    return get


def _copy(tiles: Path, tmp_path: Path) -> Path:
    out = tmp_path / "copy"
    shutil.copytree(tiles, out)
    return out


@pytest.mark.parametrize("name", sorted(set(SOURCES) - {"hugo"}))
def test_verify_passes_on_every_3dtiles_writer_output(tilesets, name):
    """Each tile's geometricError holds at the data points under it for projected, degree,
    NAD27 (a datum shift), local-frame and point-cloud terrain; full-resolution leaves claim
    their float32 positions' rounding (they claimed 0 for 2e-5..9e-5 m before)."""
    source, tiles = tilesets(name)
    result = run("verify", tiles, "--source", source, "--json")
    doc = json.loads(result.output)
    assert result.exit_code == 0, doc
    checks = {c["name"]: c for c in doc["checks"]}
    assert set(checks) == {"content", "volumes", "monotone", "errors"}
    assert checks["errors"]["items"] == checks["content"]["items"] > 1
    assert doc["figures"]["data_points_measured"] > 10000


def test_a_deleted_tile_fails_naming_it(tilesets, tmp_path):
    """A GLB deleted from the folder: exit 1, the content check names the tile and its uri."""
    source, tiles = tilesets("nc")
    out = _copy(tiles, tmp_path)
    victim = sorted(out.glob("2/*.glb"))[0]
    victim.unlink()
    result = run("verify", out, "--source", source)
    assert result.exit_code == 1
    assert "content  root/" in result.output
    assert f"→ 2/{victim.name}  a file  missing" in result.output


def test_a_moved_tile_vertex_fails_naming_the_tile(tilesets, tmp_path):
    """A vertex of a leaf's GLB moved 20 m (glTF's y: up-ish in ECEF) breaks its claim (and
    leaves its bounding volume)."""
    source, tiles = tilesets("nc")
    out = _copy(tiles, tmp_path)
    victim = sorted(out.glob("3/*.glb"))[0]
    move_glb_vertex(victim, 10, 1, 20.0)
    result = run("verify", out, "--source", source, "--json")
    assert result.exit_code == 1
    failed = {c["name"]: c for c in json.loads(result.output)["checks"] if not c["ok"]}
    assert set(failed) == {"errors", "volumes"}
    (offender,) = failed["errors"]["offenders"]
    assert offender["address"].endswith(f"({victim.name})")


def test_external_tilesets_are_followed(tilesets, tmp_path):
    """A subtree moved into an external tileset (content uri sub.json) is walked and checked:
    it passes, and a GLB only the external tileset references is missed when deleted."""
    source, tiles = tilesets("nc")
    out = _copy(tiles, tmp_path)
    doc = json.loads((out / "tileset.json").read_text())
    child = doc["root"]["children"][0]
    sub = {"asset": doc["asset"], "geometricError": child["geometricError"], "root": child}
    (out / "sub.json").write_text(json.dumps(sub))
    doc["root"]["children"][0] = {
        "boundingVolume": child["boundingVolume"],
        "geometricError": child["geometricError"],
        "content": {"uri": "sub.json"},
    }
    (out / "tileset.json").write_text(json.dumps(doc))
    assert run("verify", out, "--source", source).exit_code == 0
    (out / child["children"][0]["content"]["uri"]).unlink()
    result = run("verify", out, "--source", source)
    assert result.exit_code == 1 and "sub.json:root/0" in result.output


def test_empty_tiles_sit_inside_their_parents_volume(tilesets):
    """Tiles of nodata-only nodes (hugo_site.asc's corners, a local frame without a CRS) get an
    empty volume at their parent's centre: at the parent's corner their 1 mm box reached out of
    the parent's volume and verify failed 4 of them."""
    source, tiles = tilesets("hugo")
    result = run("verify", tiles, "--source", source, "--json")
    doc = json.loads(result.output)
    assert result.exit_code == 0, doc
    checks = {c["name"]: c for c in doc["checks"]}
    # Some tiles have no content: more volumes than contents were checked.
    assert checks["volumes"]["items"] > checks["content"]["items"] > 1
