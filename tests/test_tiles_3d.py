"""``approxtree tiles --format 3dtiles``: a 3D Tiles 1.1 tileset whose tiles are the tree's nodes.

Checked by recomputation on real DEMs (NC: projected CRS; SRTM: geographic; Mount St Helens:
projected with nodata; Crater Lake SCAPE: no CRS) and generated terrain: every GLB's vertices,
taken back from ECEF to the terrain's CRS, are the node's patch vertices (skirts below its
border); every volume holds its content and its children's; geometricError is the tree's
exact error, never above the parent's; tileset.json meets the 3D Tiles schema and every GLB
passes the Khronos glTF validator.
"""

from __future__ import annotations

import functools
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file
from PIL import Image
from pyproj import Transformer
from tiles3d_checks import ROOT, check_schema, read_glb, validate_gltf, walk

import approxtree as at
from approxtree.cli import main
from approxtree.io.gltf import z_up
from approxtree.tiles import EarthFrame, write_3dtiles
from approxtree.tiles.tileset3d import geometric_errors
from approxtree.tree.tree_store import save_tree

#: name → (data file or None for generated terrain, epsilon, max_points).
TERRAINS = {
    "nc": ("nc/elev_ned_30m.tif", 2.0, 1089),
    "srtm": ("srtm/N44W072.hgt", 50.0, 1089),
    "helens": ("edge/SainteHelens.dem", 10.0, 1089),
    "crater": ("scape/crater.stm", 10.0, 1089),
    "fractal": (None, 5.0, 289),
}


def _terrain(name: str, data_dir_factory):
    relative, _, _ = TERRAINS[name]
    if relative is None:
        from approxtree.datasets import fractal_terrain

        return fractal_terrain(129, seed=3, relief=300.0, cell_size=10.0)
    return at.open_terrain(str(data_file(data_dir_factory(), relative)))


@pytest.fixture(scope="module")
def built(request, tmp_path_factory):
    """name → (tree loaded lazily from its store, tileset folder, frame), built on first use."""
    cache: dict[str, tuple] = {}

    def get(name: str):
        if name not in cache:
            terrain = _terrain(name, lambda: request.getfixturevalue("data_dir"))
            _, epsilon, max_points = TERRAINS[name]
            folder = tmp_path_factory.mktemp(name)
            tree = at.ApproximationTree.build(terrain, epsilon=epsilon, max_points=max_points)
            save_tree(tree, folder / "tree.zarr")
            tree = at.load_tree(folder / "tree.zarr", verify=False)
            origin = (10.0, 45.0) if name == "fractal" else (0.0, 0.0)
            out = folder / "tiles"
            # Float32 positions: the patch vertices themselves (test_tiles_3d_compact.py
            # checks the compressed ones).
            write_3dtiles(tree, out, workers=2, origin=origin, compression="none")
            frame = EarthFrame(tree.terrain.crs, tree.terrain.domain.center, origin)
            cache[name] = (tree, out, frame)
        return cache[name]

    return get


def _tiles(out: Path):
    tileset = json.loads((out / "tileset.json").read_text())
    return tileset, list(walk(tileset))


@functools.lru_cache(maxsize=4096)
def _read(path: Path) -> dict:
    """A GLB's arrays, parsed once per test session (several tests walk the same tileset)."""
    return read_glb(path)


def _node(tile: dict, out: Path) -> tuple[int, dict] | None:
    if "content" not in tile:
        return None
    glb = _read(out / tile["content"]["uri"])
    return int(glb["extras"]["node"]), glb


def _ecef(glb: dict, m: np.ndarray) -> np.ndarray:
    """(n, 3) ECEF of a GLB's positions: glTF y-up → 3D Tiles z-up, then the tile's transform."""
    p = z_up(glb["positions"].astype(np.float64))
    return p @ m[:3, :3].T + m[:3, 3]


def _tolerance(glb: dict, frame: EarthFrame) -> tuple[float, float]:
    """(x, y tolerance, z tolerance) in terrain units: float32 rounding of positions of this
    size, plus 1 mm for pyproj's round trip through datum shifts (NAD27 → WGS84 and back
    differs by 0.3 mm)."""
    metres = 4.0 * float(np.spacing(np.abs(glb["positions"]).max())) + 1e-3
    if frame.crs is not None:
        from pyproj import CRS

        if CRS.from_user_input(frame.crs).is_geographic:
            return metres / 7e4, metres  # a degree spans at least 70 km here
    return metres, metres


@pytest.mark.parametrize("name", list(TERRAINS))
def test_glb_vertices_are_the_patch_vertices_back_in_the_crs(built, name):
    """Every tile's content, taken from glTF y-up through the cumulative transforms to ECEF
    and back (pyproj) to the terrain's CRS, is its node's patch: same vertices within float32
    rounding, same triangles first; then skirt vertices under border vertices; unit normals."""
    tree, out, frame = built(name)
    _, tiles = _tiles(out)
    seen = set()
    for tile, _, m in tiles:
        found = _node(tile, out)
        if found is None:
            continue
        i, glb = found
        seen.add(i)
        patch = tree.read_patch(i)
        verts = np.asarray(patch.vertices, dtype=np.float64)
        back = frame.from_ecef(_ecef(glb, m))
        tol_xy, tol_z = _tolerance(glb, frame)
        n = len(verts)
        np.testing.assert_allclose(back[:n, :2], verts[:, :2], rtol=0, atol=tol_xy)
        np.testing.assert_allclose(back[:n, 2], verts[:, 2], rtol=0, atol=tol_z)
        tris = np.asarray(patch.triangles).reshape(-1, 3)
        np.testing.assert_array_equal(glb["triangles"][: len(tris)], tris)
        # Skirt vertices hang below some patch vertex (same x, y).
        for v in back[n:][:: max(1, (len(back) - n) // 50)]:
            d = np.abs(verts[:, :2] - v[:2]).max(axis=1)
            k = int(np.argmin(d))
            assert d[k] <= tol_xy and v[2] <= verts[k, 2] + tol_z
        np.testing.assert_allclose(np.linalg.norm(glb["normals"], axis=1), 1.0, atol=1e-5)
    has_triangles = [i for i in range(len(tree.errors)) if len(tree.read_patch(i).triangles)]
    assert seen == set(has_triangles)


def _geodetic_up(p: np.ndarray) -> np.ndarray:
    """(n, 3) ellipsoid normals (geodetic up) at ECEF points (n, 3)."""
    to_geo = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon, lat, _ = to_geo.transform(p[:, 0], p[:, 1], p[:, 2])
    lam, phi = np.radians(lon), np.radians(lat)
    return np.column_stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)])


@pytest.mark.parametrize("name", list(TERRAINS))
def test_faces_and_normals_point_up_from_the_ellipsoid(built, name):
    """A height field seen in ECEF (glTF y-up turned back to z-up, through the transforms):
    every surface triangle, counter-clockwise as glTF front faces are, faces away from the
    ellipsoid, and so does every surface vertex's normal (y-up handedness and winding)."""
    tree, out, _ = built(name)
    _, tiles = _tiles(out)
    for tile, _, m in tiles[:25]:
        found = _node(tile, out)
        if found is None:
            continue
        i, glb = found
        n = len(tree.read_patch(i).vertices)
        t = np.asarray(tree.read_patch(i).triangles, dtype=np.int64).reshape(-1, 3)
        p = _ecef(glb, m)
        face = np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])
        up = _geodetic_up(p[t].mean(axis=1))
        assert (np.sum(face * up, axis=1) > 0).all()
        normals = z_up(glb["normals"][:n].astype(np.float64)) @ m[:3, :3].T
        assert (np.sum(normals * _geodetic_up(p[:n]), axis=1) > 0).all()


@pytest.mark.parametrize("name", list(TERRAINS))
def test_volumes_hold_content_and_children(built, name):
    """Each tile's bounding volume (region in radians for CRS terrain, box otherwise) holds
    every vertex of its GLB and the midpoint of every triangle edge (straight chords sag under
    the ellipsoid), and every child's volume."""
    _, out, frame = built(name)
    _, tiles = _tiles(out)
    to_geo = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    by_id = {id(t): (t, m) for t, _, m in tiles}

    def corners(tile: dict, m: np.ndarray) -> np.ndarray:
        """Points that must lie in the parent's volume: region corners or box corners (ECEF)."""
        bv = tile["boundingVolume"]
        if "region" in bv:
            w, s, e, n, lo, hi = bv["region"]
            return np.array([[w, s, lo], [e, n, hi]])
        c, h = np.array(bv["box"][:3]), np.array(bv["box"][3:]).reshape(3, 3)
        signs = np.array([[a, b, d] for a in (-1, 1) for b in (-1, 1) for d in (-1, 1)])
        local = c + signs @ h
        return local @ m[:3, :3].T + m[:3, 3]

    def inside(tile: dict, m: np.ndarray, ecef: np.ndarray | None, geo: np.ndarray | None):
        bv = tile["boundingVolume"]
        if "region" in bv:
            w, s, e, n, lo, hi = bv["region"]
            if geo is None:
                x, y, z = to_geo.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
                geo = np.column_stack([np.radians(x), np.radians(y), z])
            tol = 1e-12
            assert (geo[:, 0] >= w - tol).all() and (geo[:, 0] <= e + tol).all()
            assert (geo[:, 1] >= s - tol).all() and (geo[:, 1] <= n + tol).all()
            assert (geo[:, 2] >= lo - 1e-6).all() and (geo[:, 2] <= hi + 1e-6).all()
        else:
            c, h = np.array(bv["box"][:3]), np.array(bv["box"][3:]).reshape(3, 3)
            local = (ecef - m[:3, 3]) @ m[:3, :3]  # rotation part is orthonormal
            u = (local - c) @ h.T / np.sum(h * h, axis=1)
            assert (np.abs(u) <= 1 + 1e-6).all()

    for tile, parent, m in tiles:
        found = _node(tile, out)
        if found is not None:
            glb = found[1]
            p = _ecef(glb, m)
            t = glb["triangles"].astype(np.int64)
            mids = np.concatenate(
                [(p[t[:, a]] + p[t[:, b]]) / 2 for a, b in ((0, 1), (1, 2), (2, 0))]
            )
            inside(tile, m, np.concatenate([p, mids]), None)
        if parent is not None:
            pt, pm = by_id[id(parent)]
            c = corners(tile, m)
            if frame.georeferenced:
                inside(pt, pm, None, c)
            else:
                inside(pt, pm, c, None)


@pytest.mark.parametrize("name", list(TERRAINS))
def test_geometric_errors_are_the_tree_errors(built, name):
    """geometricError is ε_T(N) (plus its float32 rounding's bound) wherever no descendant has a
    larger error (never below it),
    no child's exceeds its parent's, and the tileset's is at least the terrain's horizontal
    extent (so a client draws the root whenever the terrain is on screen)."""
    tree, out, _ = built(name)
    tileset, tiles = _tiles(out)
    claimed = {}
    for tile, parent, _ in tiles:
        if parent is not None:
            assert tile["geometricError"] <= parent["geometricError"]
        found = _node(tile, out)
        if found is not None:
            claimed[found[0]] = tile["geometricError"]
    errors = np.asarray(tree.errors)
    expected = geometric_errors(errors, tree.parents, tree.levels, 1.0)
    exact = 0
    for i, g in claimed.items():
        if np.isfinite(errors[i]):
            assert g >= errors[i]
            # Exact up to what the tile's float32 positions add (a bound: 4 mm at the root of
            # a 1° SRTM tile, micrometres on leaves).
            exact += g <= errors[i] + 1e-2
            if all(errors[j] <= errors[i] for j in _descendants(tree, i)):
                assert g == pytest.approx(errors[i], abs=1e-2)
    assert exact >= 0.5 * len(claimed)
    x0, y0, x1, y1 = np.asarray(tree.rects)[0]
    extent = np.hypot(x1 - x0, y1 - y0)
    if tree.terrain.crs is not None and "4326" in str(tree.terrain.crs):
        extent *= 111_000 * np.cos(np.radians(abs(y0) + abs(y1)) / 2) * 0.99
    assert tileset["geometricError"] >= 0.99 * extent
    assert tileset["geometricError"] >= 2 * tileset["root"]["geometricError"]
    assert expected[0] <= tileset["root"]["geometricError"] + 1e-9 or not np.isfinite(errors).all()


def _descendants(tree, i: int) -> list[int]:
    out, stack = [], [i]
    while stack:
        k = stack.pop()
        s, c = int(tree.child_start[k]), int(tree.child_count[k])
        out.extend(range(s, s + c))
        stack.extend(range(s, s + c))
    return out


@pytest.mark.parametrize("name", list(TERRAINS))
def test_tileset_json_meets_the_3d_tiles_schema(built, name):
    """tileset.json validates against the 3D Tiles 1.1 schema's required parts; one tile per
    node, refine REPLACE; regions for CRS terrain, boxes (ENU at --origin) otherwise."""
    tree, out, frame = built(name)
    tileset, tiles = _tiles(out)
    check_schema(tileset)
    assert len(tiles) == len(tree.errors)
    assert all(t["refine"] == "REPLACE" for t, _, _ in tiles)
    kind = "region" if frame.georeferenced else "box"
    assert all(kind in t["boundingVolume"] for t, _, _ in tiles)


def test_local_frame_sits_at_the_origin(built):
    """Terrain without a CRS: the root's transform puts the domain centre on the ellipsoid
    at --origin (10°E, 45°N here): its ECEF centre's longitude and latitude are the origin's."""
    tree, out, _ = built("fractal")
    tileset, _ = _tiles(out)
    m = np.array(tileset["root"]["transform"]).reshape(4, 4).T
    to_geo = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    enu = EarthFrame(None, tree.terrain.domain.center, (10.0, 45.0)).matrix
    lon, lat, h = to_geo.transform(*enu[:3, 3])
    assert (lon, lat, h) == pytest.approx((10.0, 45.0, 0.0), abs=1e-6)
    # The root transform is the ENU matrix times a translation: same rotation.
    np.testing.assert_allclose(m[:3, :3], enu[:3, :3], atol=1e-12)


@pytest.mark.parametrize("name", ["nc", "crater"])
def test_every_glb_passes_the_khronos_validator(built, name):
    """The Khronos glTF validator (npm gltf-validator) finds 0 errors in every GLB."""
    _, out, _ = built(name)
    reports = validate_gltf(sorted(out.rglob("*.glb")))
    assert reports and all(r["errors"] == 0 for r in reports), [r for r in reports if r["errors"]][
        :3
    ]
    warnings = sorted({m["code"] for r in reports for m in r["messages"]})
    print(f"{len(reports)} GLBs, warnings: {warnings}")


def test_serial_and_parallel_writes_give_the_same_tileset(built, tmp_path):
    """Tiles are independent: 1 and 3 workers write byte-identical folders."""
    tree, _, _ = built("fractal")
    write_3dtiles(tree, tmp_path / "a", workers=1, origin=(10.0, 45.0))
    write_3dtiles(tree, tmp_path / "b", workers=3, origin=(10.0, 45.0))
    a = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    b = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    assert a == b and len(a) > 10
    for p in a:
        assert (tmp_path / "a" / p).read_bytes() == (tmp_path / "b" / p).read_bytes()


def test_textures_are_each_nodes_texture_patch(tmp_path):
    """With --textures every GLB embeds its node's texture patch (PNG, identical texels) and
    texture coordinates that put each vertex on the texel covering its x, y."""
    from approxtree.datasets import fractal_terrain
    from approxtree.geometry.rect import Rect
    from approxtree.textures.bake import bake
    from approxtree.textures.patch import TexturePatch
    from approxtree.textures.pyramid import TexturePyramid

    terrain = fractal_terrain(129, seed=5, relief=200.0, cell_size=10.0)
    bake(terrain, tmp_path / "tex", max_texture_size=64, gl=False)
    tree = at.ApproximationTree.build(terrain, epsilon=5.0, max_points=289)
    write_3dtiles(tree, tmp_path / "tiles", textures=tmp_path / "tex", compression="none")
    pyramid = TexturePyramid(tmp_path / "tex")
    _, tiles = _tiles(tmp_path / "tiles")
    checked = 0
    for tile, _, _ in tiles:
        found = _node(tile, tmp_path / "tiles")
        if found is None:
            continue
        i, glb = found
        patch = TexturePatch.for_rect(pyramid, Rect(*map(float, tree.rects[i])))
        image = np.asarray(Image.open(io.BytesIO(glb["image"])).convert("RGBA"))
        np.testing.assert_array_equal(image, patch.texels())
        # Each surface vertex's uv falls in the texel whose world cell holds its x, y.
        verts = np.asarray(tree.read_patch(i).vertices)
        uv = glb["uvs"][: len(verts)].astype(np.float64)
        ext = patch.extent
        x = ext.xmin + uv[:, 0] * ext.width
        y = ext.ymax - uv[:, 1] * ext.height
        np.testing.assert_allclose(x, verts[:, 0], atol=1e-3)
        np.testing.assert_allclose(y, verts[:, 1], atol=1e-3)
        assert (uv >= 0).all() and (uv <= 1).all()
        checked += 1
    assert checked == len(tiles)
    # Textured GLBs (PNG images, samplers, texture coordinates) pass the Khronos validator.
    if shutil.which("node") and (ROOT / "web" / "node_modules" / "gltf-validator").is_dir():
        reports = validate_gltf(sorted((tmp_path / "tiles").rglob("*.glb")))
        assert all(r["errors"] == 0 for r in reports), reports[:2]


def test_cli_writes_a_tileset_and_reports_figures(built, tmp_path):
    """`approxtree tiles TREE --out DIR --format 3dtiles --json` writes DIR/tileset.json and
    the GLBs, leaves no temp folder, and reports tiles and bytes."""
    _, out, _ = built("crater")
    tree_path = out.parent / "tree.zarr"
    target = tmp_path / "web"
    result = CliRunner().invoke(
        main,
        [
            "tiles",
            str(tree_path),
            "--out",
            str(target),
            "--format",
            "3dtiles",
            "--workers",
            "2",
            "--json",
        ],
    )
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    glbs = list(target.rglob("*.glb"))
    assert figures["tiles"] == len(glbs) > 1 and (target / "tileset.json").is_file()
    assert figures["bytes"] == sum(p.stat().st_size for p in glbs)
    assert [p.name for p in tmp_path.iterdir()] == ["web"]


def test_cli_refuses_a_folder_it_did_not_write(built, tmp_path):
    """An existing folder without tileset.json is never replaced: exit 2 with one Error line,
    the folder untouched."""
    _, out, _ = built("crater")
    keep = tmp_path / "photos"
    keep.mkdir()
    (keep / "a.jpg").write_bytes(b"x")
    result = CliRunner().invoke(
        main, ["tiles", str(out.parent / "tree.zarr"), "--out", str(keep), "--format", "3dtiles"]
    )
    assert result.exit_code == 2 and "holds no tileset.json" in result.output
    assert [p.name for p in keep.iterdir()] == ["a.jpg"]


def test_cli_rejects_a_bad_origin(built, tmp_path):
    """--origin outside longitude/latitude ranges exits 2 with a clear message."""
    _, out, _ = built("crater")
    result = CliRunner().invoke(
        main,
        [
            "tiles",
            str(out.parent / "tree.zarr"),
            "--out",
            str(tmp_path / "t"),
            "--format",
            "3dtiles",
            "--origin",
            "0",
            "95",
        ],
    )
    assert result.exit_code == 2 and "--origin" in result.output
