"""``approxtree verify`` on mesh files of ``approxtree mesh --out``: the max error each GLB, PLY
and OBJ records holds at the source's data points for every kind of data (coordinates as the
file stores them: GLB's float32 positions, PLY's doubles, OBJ's decimals), and a moved vertex
or a claim too small fails (exit 1) naming where."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import rasterio
import trimesh
from affine import Affine
from click.testing import CliRunner
from conftest import data_file
from rasterio.windows import Window

from approxtree.cli import main


def crop(src: Path, out: Path, row: int, col: int, rows: int, cols: int) -> Path:
    """A GeoTIFF of a window of ``src`` (same CRS, cells and values)."""
    with rasterio.open(src) as ds:
        data = ds.read(1, window=Window(col, row, cols, rows))
        t = ds.transform
        profile = {
            "driver": "GTiff",
            "width": cols,
            "height": rows,
            "count": 1,
            "dtype": data.dtype,
            "crs": ds.crs,
            "nodata": ds.nodata,
            "transform": Affine(t.a, 0.0, t.c + col * t.a, 0.0, t.e, t.f + row * t.e),
        }
    with rasterio.open(out, "w", **profile) as f:
        f.write(data, 1)
    return out


@pytest.fixture(scope="module")
def sources(data_dir, tmp_path_factory) -> dict[str, Path]:
    """name → source file: NC (projected), SRTM (degrees), Crater Lake (SCAPE, no CRS), the
    LAZ (scattered points), Mount St Helens (nodata inside)."""
    folder = tmp_path_factory.mktemp("sources")
    nc, srtm = data_file(data_dir, "nc/elev_ned_30m.tif"), data_file(data_dir, "srtm/N44W072.hgt")
    return {
        "nc": crop(nc, folder / "nc.tif", 100, 100, 120, 160),
        "srtm": crop(srtm, folder / "srtm.tif", 700, 600, 150, 150),
        "crater": data_file(data_dir, "scape/crater.stm"),
        "laz": data_file(data_dir, "lidar/autzen_trim.laz"),
        "helens": data_file(data_dir, "edge/SainteHelens.dem"),
    }


def run(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args])


#: (source, mesh options): strategies and goals the checks cover.
CASES = [
    ("nc", ["--max-error", "1"]),
    ("srtm", ["--max-error", "2"]),
    ("srtm", ["--max-error", "2", "--strategy", "grid"]),
    ("crater", ["--max-error", "5", "--strategy", "rtin"]),
    ("laz", ["--max-error", "3"]),
    ("helens", ["--max-points", "3000"]),
]


@pytest.mark.parametrize("kind", ["glb", "ply", "obj"])
@pytest.mark.parametrize(("name", "options"), CASES)
def test_verify_passes_on_every_mesh_file(sources, tmp_path, name, options, kind):
    """The max error the file records is the true max at the data points under the mesh, as
    the file stores it (GLB float32 positions claimed 2.0 for 2.0002 m on the SRTM crop and
    0 for 4e-4 m with the grid strategy; float32 PLY was 59 ft off on the LAZ, 8-decimal OBJ
    3e-4 m in degrees)."""
    out = tmp_path / f"mesh.{kind}"
    made = run("mesh", sources[name], *options, "--out", out, "--json")
    assert made.exit_code == 0, made.output
    result = run("verify", out, "--source", sources[name], "--json")
    doc = json.loads(result.output)
    assert result.exit_code == 0, doc
    figures = doc["figures"]
    assert figures["format"] == kind and doc["not_checked"] == []
    # Within verify's slack (1e-9 relative: index arithmetic in degrees).
    assert figures["measured_max_error"] <= figures["claimed_max_error"] * (1 + 1e-9) + 1e-9
    assert figures["claimed_source"] == Path(sources[name]).name
    assert figures["data_points"] > 10000


def test_a_glb_with_skirts_passes(sources, tmp_path):
    """Skirts (vertical walls down from the border) hold no data point: a GLB with them passes."""
    out = tmp_path / "skirts.glb"
    made = run("mesh", sources["helens"], "--max-error", "5", "--skirts", "--out", out)
    assert made.exit_code == 0, made.output
    assert run("verify", out, "--source", sources["helens"]).exit_code == 0


def move_glb_vertex(path: Path, vertex: int, axis: int, delta: float) -> None:
    """Add ``delta`` to component ``axis`` of one POSITION of a GLB, in place (a hand edit)."""
    import pygltflib

    data = bytearray(path.read_bytes())
    gltf = pygltflib.GLTF2.load_from_bytes(bytes(data))
    (json_length,) = struct.unpack_from("<I", data, 12)
    bin_start = 12 + 8 + json_length + 8
    accessor = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION]
    view = gltf.bufferViews[accessor.bufferView]
    at = bin_start + (view.byteOffset or 0) + (accessor.byteOffset or 0) + 12 * vertex + 4 * axis
    (value,) = struct.unpack_from("<f", data, at)
    struct.pack_into("<f", data, at, value + delta)
    path.write_bytes(bytes(data))


def test_a_moved_glb_vertex_fails_naming_where(sources, tmp_path):
    """A GLB vertex raised 10 m (its z under the root rotation) fails: exit 1, the mesh's
    worst point named with the claim and the error measured."""
    out = tmp_path / "moved.glb"
    assert run("mesh", sources["nc"], "--max-error", "1", "--out", out).exit_code == 0
    move_glb_vertex(out, 100, 2, 10.0)
    result = run("verify", out, "--source", sources["nc"], "--json")
    assert result.exit_code == 1
    (offender,) = json.loads(result.output)["checks"][-1]["offenders"]
    assert offender["address"].startswith("mesh at (")
    assert offender["measured"] > 5.0 > 1.0 >= offender["claimed"]


def test_a_moved_ply_vertex_fails(sources, tmp_path):
    """A PLY vertex lowered 5 m fails against the claim in its header comment."""
    out = tmp_path / "moved.ply"
    assert run("mesh", sources["nc"], "--max-error", "1", "--out", out).exit_code == 0
    data = out.read_bytes()
    body = data.index(b"end_header\n") + len(b"end_header\n")
    verts = np.frombuffer(data, dtype="<f8", count=30, offset=body).copy().reshape(-1, 3)
    verts[5, 2] -= 5.0
    out.write_bytes(data[:body] + verts.tobytes() + data[body + verts.nbytes :])
    result = run("verify", out, "--source", sources["nc"])
    assert result.exit_code == 1 and "errors  mesh at (" in result.output


def test_a_mesh_without_claims_takes_max_error(sources, tmp_path):
    """An OBJ written by another program records no claim: verify says so (exit 0), checks
    --max-error when given, and fails when it is below the true error."""
    out = tmp_path / "mesh.ply"
    assert run("mesh", sources["nc"], "--max-error", "1", "--out", out).exit_code == 0
    plain = tmp_path / "plain.obj"
    trimesh.load(out, process=False).export(plain)
    none = run("verify", plain, "--source", sources["nc"], "--json")
    assert none.exit_code == 0
    assert any("--max-error" in line for line in json.loads(none.output)["not_checked"])
    assert run("verify", plain, "--source", sources["nc"], "--max-error", "1").exit_code == 0
    small = run("verify", plain, "--source", sources["nc"], "--max-error", "0.5")
    assert small.exit_code == 1 and "errors  mesh at (" in small.output
