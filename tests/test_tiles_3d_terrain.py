"""``approxtree tiles --format 3dtiles-terrain``: Cesium terrain as implicit 3D Tiles, the layout
CesiumJS's Cesium3DTilesTerrainProvider reads (checked against its source, CesiumJS 1.140):
a root with the two hemispheres as implicit quadtrees of Cesium's geographic tiling, tile
metadata with the semantics it reads, meshopt GLBs with CESIUM_tile_edges; every tile within
its level's error at the DEM's data points (verify, decoding with meshoptimizer).
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file
from tiles3d_checks import validate_gltf

import approxtree as at
from approxtree.cli import main
from approxtree.tiles.terrain3d import write_3dtiles_terrain
from approxtree.verify.implicit_read import implicit_tiles

#: Semantics Cesium3DTilesTerrainProvider reads from each tile's metadata.
PROVIDER_SEMANTICS = {
    "TILE_MINIMUM_HEIGHT",
    "TILE_MAXIMUM_HEIGHT",
    "TILE_BOUNDING_SPHERE",
    "TILE_HORIZON_OCCLUSION_POINT",
}


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def nc_terrain(data_dir, tmp_path_factory):
    """The NC DEM's 3D Tiles terrain (152 samples, leaf error 1 m) and its figures."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    out = tmp_path_factory.mktemp("terrain3d") / "tiles"
    figures = write_3dtiles_terrain(at.open_terrain(str(dem)), out)
    return dem, out, figures


def test_terrain_tiles_hold_their_errors(nc_terrain):
    """verify passes: subtrees parse, every listed GLB decodes, volumes nest, errors are
    monotone, and each tile's TIN (decoded with meshoptimizer, taken to longitude/latitude)
    is within its declared error (<= its level's) at the DEM's data points."""
    dem, out, figures = nc_terrain
    assert figures["worst_error_ratio"] <= 1.0
    result = run("verify", out, "--source", dem, "--json")
    doc = json.loads(result.output)
    assert result.exit_code == 0, doc
    checks = {c["name"]: c for c in doc["checks"]}
    assert set(checks) == {"content", "implicit", "volumes", "monotone", "errors"}
    assert checks["errors"]["items"] == figures["tiles"] and doc["figures"]["data_points_measured"]


def test_layout_is_what_the_provider_reads(nc_terrain):
    """tileset.json: a root whose two children are the hemispheres' implicit quadtrees (level
    0 of the geographic tiling), a schema with the semantics the provider reads; every tile
    from level 0 down is available with content and metadata; claims halve per level."""
    _, out, figures = nc_terrain
    doc = json.loads((out / "tileset.json").read_text())
    children = doc["root"]["children"]
    assert len(children) == 2
    semantics = {p["semantic"] for p in doc["schema"]["classes"]["tile"]["properties"].values()}
    assert PROVIDER_SEMANTICS <= semantics
    found = []
    for k, child in enumerate(children):
        w, s, e, n = child["boundingVolume"]["region"][:4]
        assert (w, s, e, n) == pytest.approx(
            (-math.pi + k * math.pi, -math.pi / 2, k * math.pi, math.pi / 2)
        )
        assert child["implicitTiling"]["subdivisionScheme"] == "QUADTREE"
        tiles = implicit_tiles(child, out, doc["schema"])
        assert tiles[0].level == 0 and all(t.content is not None for t in tiles)
        for t in tiles:
            assert PROVIDER_SEMANTICS <= set(t.metadata)
            assert t.declared_error <= t.error
        found.extend(tiles)
    assert len(found) == figures["tiles"]


def _edges(path: Path) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """(positions (n, 3) ECEF, the 4 CESIUM_tile_edges index lists, the node matrix), decoded
    with meshoptimizer as CesiumJS's terrain reader does (normalized shorts / 65535)."""
    import meshoptimizer

    data = path.read_bytes()
    (length,) = struct.unpack_from("<I", data, 12)
    doc = json.loads(data[20 : 20 + length])
    blob = data[20 + length + 8 :]

    def view(accessor: int, stride_type) -> np.ndarray:
        acc = doc["accessors"][accessor]
        ext = doc["bufferViews"][acc["bufferView"]]["extensions"]["EXT_meshopt_compression"]
        raw = np.frombuffer(blob, np.uint8, ext["byteLength"], ext.get("byteOffset", 0))
        if ext["mode"] == "ATTRIBUTES":
            out = meshoptimizer.decode_vertex_buffer(ext["count"], ext["byteStride"], raw)
        else:
            out = meshoptimizer.decode_index_sequence(ext["count"], ext["byteStride"], raw)
        return np.frombuffer(out.tobytes()[: ext["count"] * ext["byteStride"]], stride_type)

    prim = doc["meshes"][0]["primitives"][0]
    q = view(prim["attributes"]["POSITION"], "<u2").reshape(-1, 4)[:, :3] / 65535.0
    m = np.array(doc["nodes"][0]["matrix"]).reshape(4, 4).T
    sides = prim["extensions"]["CESIUM_tile_edges"]
    edges = [
        view(sides[name], "<u2").astype(np.int64) for name in ("left", "bottom", "right", "top")
    ]
    yup = q @ m[:3, :3].T + m[:3, 3]
    ecef = np.column_stack([yup[:, 0], -yup[:, 2], yup[:, 1]])
    return ecef, edges, m


def test_tile_edges_lie_on_the_tiles_sides(nc_terrain):
    """Each GLB's CESIUM_tile_edges (decoded with meshoptimizer) list exactly the vertices on
    its tile's west, south, east and north sides (within the lattice's step)."""
    from pyproj import Transformer

    from approxtree.io.quantized_mesh import tile_bounds

    _, out, _ = nc_terrain
    to_geo = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    checked = 0
    for path in sorted(out.glob("*/tiles/1[23]/*/*.glb")):
        hemisphere, _, level, x, y = path.relative_to(out).with_suffix("").parts
        level, x, y = int(level), int(x) + int(hemisphere) * 2 ** int(level), int(y)
        west, south, east, north = tile_bounds(level, x, y)
        ecef, edges, m = _edges(path)
        lon, lat, _ = to_geo.transform(*ecef.T)
        step = np.linalg.norm(m[:3, 0]) / 65535.0
        tol = 2 * step / 1e5  # degrees: two steps, at least 100 km per degree here
        for side, want, values in zip(
            edges, (west, south, east, north), (lon, lat, lon, lat), strict=True
        ):
            assert len(side) and np.abs(values[side] - want).max() <= tol
            assert np.count_nonzero(np.abs(values - want) <= tol / 4) <= len(side)
        checked += 1
    assert checked > 10


def test_validator_finds_only_the_scaled_node_matrix(nc_terrain):
    """The Khronos validator's one complaint is NODE_MATRIX_NON_TRS: the provider reads
    normalized shorts scaled by the node matrix (65535 · step), which the validator's float32
    determinant test cannot take apart; nothing else."""
    _, out, _ = nc_terrain
    reports = validate_gltf(sorted(out.rglob("*.glb")))
    codes = {m["code"] for r in reports for m in r["messages"] if m["severity"] == "error"}
    assert codes <= {"NODE_MATRIX_NON_TRS"} and all(r["warnings"] == 0 for r in reports)


def test_cli_refuses_a_minzoom_and_a_water_mask(data_dir, tmp_path):
    """--minzoom (the provider starts at level 0) and --water-mask (quantized-mesh only) do
    not apply: exit 2 saying which."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    args = ["tiles", dem, "--out", tmp_path / "t", "--format", "3dtiles-terrain"]
    result = run(*args, "--minzoom", "3")
    assert result.exit_code == 2 and "--minzoom" in result.output
    result = run(*args, "--water-mask", dem)
    assert result.exit_code == 2 and "--water-mask" in result.output
