"""``approxtree verify`` on quantized-mesh folders: every tile layer.json lists present and
decoded, each within its level's error at the DEM's data points (the leaf error on the deepest
level, the height quantization's half step allowed); a deleted or edited tile fails (exit 1)
naming it."""

from __future__ import annotations

import gzip
import json
import shutil
import struct
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import data_file
from test_verify_mesh import crop

from approxtree.cli import main


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _copy(tiles: Path, tmp_path: Path) -> Path:
    out = tmp_path / "copy"
    shutil.copytree(tiles, out)
    return out


@pytest.fixture(scope="module")
def terrain_tiles(data_dir, tmp_path_factory) -> tuple[Path, Path]:
    """A 60 × 60 cell SRTM crop around Mt Washington and its quantized-mesh tiles (32 samples)."""
    folder = tmp_path_factory.mktemp("qm")
    source = crop(data_file(data_dir, "srtm/N44W072.hgt"), folder / "crop.tif", 760, 640, 60, 60)
    out = folder / "tiles"
    made = run("tiles", source, "--out", out, "--format", "quantized-mesh", "--samples", 32)
    assert made.exit_code == 0, made.output
    return source, out


def test_verify_passes_on_quantized_mesh_tiles(terrain_tiles):
    """Every tile is within its level's error (the leaf error on the deepest level) at the
    DEM's data points, the height quantization's half step allowed."""
    source, out = terrain_tiles
    result = run("verify", out, "--source", source, "--json")
    assert result.exit_code == 0, result.output


def test_quantized_mesh_tiles_all_present_and_decoding(terrain_tiles):
    """Every tile layer.json lists exists and decodes; the error check covers every tile."""
    source, out = terrain_tiles
    doc = json.loads(run("verify", out, "--source", source, "--json").output)
    checks = {c["name"]: c for c in doc["checks"]}
    assert checks["tiles"]["ok"] and checks["tiles"]["items"] == doc["figures"]["tiles"] > 10
    assert checks["errors"]["items"] == checks["tiles"]["items"]
    assert doc["figures"]["unlisted_tiles"] == 0


def test_a_deleted_terrain_tile_fails_naming_it(terrain_tiles, tmp_path):
    """A .terrain file layer.json lists, deleted: exit 1 naming its z/x/y."""
    source, tiles = terrain_tiles
    out = _copy(tiles, tmp_path)
    victim = sorted(out.glob("5/*/*.terrain"))[0]
    victim.unlink()
    address = f"5/{victim.parent.name}/{victim.stem}"
    result = run("verify", out, "--source", source)
    assert result.exit_code == 1 and f"tiles  {address}  a tile  missing" in result.output


def test_raised_terrain_tile_fails_naming_it(terrain_tiles, tmp_path):
    """A deepest-level tile whose header lifts every height by 500 m (its minimumHeight and
    maximumHeight edited) is the worst offender of the error check; a tile of garbage fails
    to decode."""
    source, tiles = terrain_tiles
    out = _copy(tiles, tmp_path)
    import rasterio

    # The deepest tile under the crop's centre (tiles at its border hold no point measured).
    deepest = max(int(p.name) for p in out.iterdir() if p.name.isdigit())
    with rasterio.open(source) as ds:
        b = ds.bounds
    size = 180.0 / 2**deepest
    x, y = int(((b.left + b.right) / 2 + 180) // size), int(((b.bottom + b.top) / 2 + 90) // size)
    victim = out / str(deepest) / str(x) / f"{y}.terrain"
    raw = bytearray(gzip.decompress(victim.read_bytes()))
    lo, hi = struct.unpack_from("<ff", raw, 24)
    struct.pack_into("<ff", raw, 24, lo + 500.0, hi + 500.0)
    victim.write_bytes(gzip.compress(bytes(raw)))
    address = f"{deepest}/{victim.parent.name}/{victim.stem}"
    result = run("verify", out, "--source", source, "--json")
    assert result.exit_code == 1
    errors = next(c for c in json.loads(result.output)["checks"] if c["name"] == "errors")
    # The worst offender, whatever else fails: 500 m above the data.
    assert errors["offenders"][0]["address"].startswith(f"tile {address} at (")
    assert errors["offenders"][0]["measured"] > 400
    victim.write_bytes(b"\x1f\x8b garbage")
    result = run("verify", out, "--source", source)
    assert f"tiles  {address}  decodes" in result.output
