"""``approxtree mesh``: figures for every strategy, PLY / OBJ / GLB files that trimesh reads back
in world coordinates (GLB through its recorded origin), and clear errors for bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
import trimesh
from affine import Affine
from click.testing import CliRunner
from test_strategies import check_mesh

import approxtree as at
from approxtree.cli import main
from approxtree.datasets import fractal_heights
from approxtree.patches.approximate import approximate

STRATEGIES = ["grid", "nonregular", "tin", "rtin"]


@pytest.fixture(scope="module")
def dem(tmp_path_factory) -> str:
    """A 90 × 110 fractal GeoTIFF placed at UTM-like coordinates (30 m cells)."""
    path = tmp_path_factory.mktemp("mesh") / "dem.tif"
    z = fractal_heights(90, 110, seed=21, relief=300.0)
    profile = dict(
        driver="GTiff",
        width=110,
        height=90,
        count=1,
        dtype="float32",
        crs="EPSG:32119",
        transform=Affine(30.0, 0.0, 630000.0, 0.0, -30.0, 228500.0),
    )
    with rasterio.open(path, "w", **profile) as f:
        f.write(z, 1)
    return str(path)


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def load(path: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """Vertices, faces and scene metadata of a mesh file, as trimesh reads it."""
    loaded = trimesh.load(path, process=False)
    if isinstance(loaded, trimesh.Scene):
        (geometry,) = loaded.geometry.values()
        return np.asarray(geometry.vertices), np.asarray(geometry.faces), loaded.metadata
    return np.asarray(loaded.vertices), np.asarray(loaded.faces), {}


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_json_figures_match_approximate_and_mesh_is_valid(dem, strategy):
    """--json reports the figures of approximate(); the max error is within the goal and the
    mesh of every strategy is valid."""
    result = run("mesh", dem, "--strategy", strategy, "--max-error", "40", "--json")
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    assert set(figures) == {
        "strategy",
        "vertices",
        "triangles",
        "max_error",
        "rms_error",
        "seconds",
    }
    terrain = at.open_terrain(dem)
    mesh = approximate(terrain, strategy, max_error=40.0)
    assert figures["strategy"] == strategy
    assert figures["vertices"] == len(mesh.vertices) < terrain.point_count
    assert figures["triangles"] == len(mesh.triangles)
    assert figures["max_error"] == pytest.approx(mesh.max_error) and mesh.max_error <= 40.0
    assert 0 < figures["rms_error"] <= figures["max_error"]
    check_mesh(mesh.vertices, mesh.triangles, terrain.domain)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".glb"])
@pytest.mark.parametrize("strategy", ["nonregular", "tin"])
def test_written_mesh_reloads_in_world_coordinates(dem, tmp_path, strategy, suffix):
    """trimesh reloads the file with the same vertex and face counts and world coordinates
    (GLB: float32 positions plus the origin recorded in the scene extras and the figures)."""
    out = tmp_path / f"mesh{suffix}"
    result = run("mesh", dem, "--strategy", strategy, "--max-points", "400", "--out", str(out))
    assert result.exit_code == 0, result.output
    mesh = approximate(at.open_terrain(dem), strategy, max_points=400)
    vertices, faces, meta = load(str(out))
    assert len(vertices) == len(mesh.vertices) and len(faces) == len(mesh.triangles)
    np.testing.assert_array_equal(faces, mesh.triangles)
    if suffix == ".glb":
        figures = run(
            "mesh", dem, "--strategy", strategy, "--max-points", "400", "--out", str(out), "--json"
        )
        origin = json.loads(figures.output)["origin"]
        assert meta["origin"] == pytest.approx(origin)
        assert np.abs(vertices).max() < 5000  # local, not UTM-sized, coordinates
        np.testing.assert_allclose(vertices + origin, mesh.vertices, atol=1e-3)
    else:
        np.testing.assert_allclose(vertices, mesh.vertices, rtol=0, atol=1e-6)
    assert not list(tmp_path.glob(".*.tmp"))  # the atomic write left no temp file


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "exactly one goal"),
        (["--max-error", "1", "--max-points", "100"], "exactly one goal"),
        (["--max-error", "-1"], "max_error"),
        (["--max-points", "3"], "max_points"),
        (["--max-error", "1", "--out", "{tmp}/mesh.stl"], "unknown extension '.stl'"),
        (["--max-error", "1", "--out", "{tmp}/missing/mesh.ply"], "does not exist"),
        (["--max-error", "1", "--strategy", "grid", "--data-dependent"], "tin strategy only"),
    ],
)
def test_bad_input_exits_2_with_a_clear_message(dem, tmp_path, args, message):
    """Bad goals, extensions and folders exit with code 2 and a one-line message, no file."""
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    result = run("mesh", dem, *args)
    assert result.exit_code == 2
    assert message in result.output and "Traceback" not in result.output
    assert not list(tmp_path.iterdir())


def test_unknown_strategy_is_a_usage_error(dem):
    """An unknown --strategy exits 2 naming the choices."""
    result = run("mesh", dem, "--strategy", "quadric", "--max-error", "1")
    assert result.exit_code == 2 and "nonregular" in result.output


def test_glb_is_y_up_with_normals(dem, tmp_path):
    """GLB follows glTF: z-up positions under a root node rotating z-up to y-up, so trimesh's
    scene (node matrix applied) is y-up (height on +y, north on −z); unit vertex normals point
    up (+z in the stored frame); trimesh keeps the faces and the origin."""
    from tiles3d_checks import read_glb

    from approxtree.io.gltf import Y_UP_MATRIX, z_up

    out = tmp_path / "m.glb"
    assert run("mesh", dem, "--max-points", "300", "--out", str(out)).exit_code == 0
    mesh = approximate(at.open_terrain(dem), "tin", max_points=300)
    glb = read_glb(out)
    assert glb["matrix"] == Y_UP_MATRIX
    origin = np.array(glb["extras"]["origin"])
    world = trimesh.load(str(out), process=False).to_geometry().vertices
    np.testing.assert_allclose(z_up(world) + origin, mesh.vertices, atol=1e-3)
    assert np.ptp(world[:, 1]) == pytest.approx(np.ptp(mesh.vertices[:, 2]), abs=1e-3)
    n = glb["normals"]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert (n[:, 2] > 0).all()


def test_glb_with_skirts_and_texture(dem, tmp_path):
    """--skirts adds walls below the border (the surface vertices first, unchanged);
    --textures embeds the terrain's texture patch (PNG, identical texels) with texture
    coordinates that map each vertex back to its x, y; a .ply with --textures exits 2."""
    import io

    from PIL import Image
    from tiles3d_checks import read_glb

    from approxtree.textures.bake import bake
    from approxtree.textures.patch import TexturePatch
    from approxtree.textures.pyramid import TexturePyramid

    terrain = at.open_terrain(dem)
    bake(terrain, tmp_path / "tex", max_texture_size=64, gl=False)
    out = tmp_path / "m.glb"
    args = ["mesh", dem, "--max-points", "300", "--out", str(out), "--textures"]
    result = run(*args, str(tmp_path / "tex"), "--skirts", "--json")
    assert result.exit_code == 0, result.output
    mesh = approximate(terrain, "tin", max_points=300)
    glb = read_glb(out)
    origin = np.array(json.loads(result.output)["origin"])
    p = glb["positions"].astype(np.float64) + origin
    n = len(mesh.vertices)
    np.testing.assert_allclose(p[:n], mesh.vertices, atol=1e-3)
    assert len(p) > n and (p[n:, 2] < mesh.vertices[:, 2].min()).all()
    np.testing.assert_array_equal(glb["triangles"][: len(mesh.triangles)], mesh.triangles)
    patch = TexturePatch.for_rect(TexturePyramid(tmp_path / "tex"), terrain.domain)
    image = np.asarray(Image.open(io.BytesIO(glb["image"])).convert("RGBA"))
    np.testing.assert_array_equal(image, patch.texels())
    ext = patch.extent
    uv = glb["uvs"].astype(np.float64)
    np.testing.assert_allclose(ext.xmin + uv[:, 0] * ext.width, p[:, 0], atol=1e-2)
    np.testing.assert_allclose(ext.ymax - uv[:, 1] * ext.height, p[:, 1], atol=1e-2)
    bad = run(*args[:4], "--out", str(tmp_path / "m.ply"), "--textures", str(tmp_path / "tex"))
    assert bad.exit_code == 2 and "--textures needs a .glb" in bad.output


def test_glb_passes_the_khronos_validator(dem, tmp_path):
    """The Khronos glTF validator finds 0 errors in plain and textured, skirted GLB exports."""
    from tiles3d_checks import validate_gltf

    from approxtree.textures.bake import bake

    bake(at.open_terrain(dem), tmp_path / "tex", max_texture_size=64, gl=False)
    plain, full = tmp_path / "a.glb", tmp_path / "b.glb"
    assert run("mesh", dem, "--max-points", "300", "--out", str(plain)).exit_code == 0
    textured = ["--textures", str(tmp_path / "tex"), "--skirts"]
    assert run("mesh", dem, "--max-points", "300", "--out", str(full), *textured).exit_code == 0
    reports = validate_gltf([plain, full])
    assert [r["errors"] for r in reports] == [0, 0], reports
