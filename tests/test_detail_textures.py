"""Detail textures by level (seed §3.3): a detail pyramid used for nodes at or below a tree
level inside its footprint, the base pyramid elsewhere (issue 30, item 3)."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner
from conftest import data_file

import approxtree as at
from approxtree import ApproximationTree, InvalidParameterError
from approxtree.cli import main as cli_main
from approxtree.geometry.rect import Rect
from approxtree.render.cache_keys import NODE, MeshKey
from approxtree.textures.bake import bake
from approxtree.textures.detail import DetailTextures, parse_textures

MAGENTA = (255, 0, 255)
#: The detail image: a magenta rectangle over the DEM's south-west (EPSG:32119).
DETAIL_BOX = (630000.0, 215000.0, 637500.0, 221000.0)


@pytest.fixture(scope="module")
def nc(data_dir, tmp_path_factory) -> dict:
    """The NC tree, a base pyramid (the land use, paletted image) and a magenta detail one."""
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    landuse = data_file(data_dir, "nc/landuse_r.tif")
    tree = ApproximationTree.build(at.open_terrain(dem), epsilon=1.0, progress=False)
    work = tmp_path_factory.mktemp("detail")
    base = bake(tree.terrain, work / "base", shading=None, images=[landuse], max_texture_size=512)
    x0, y0, x1, y1 = DETAIL_BOX
    cols, rows = int((x1 - x0) / 5), int((y1 - y0) / 5)
    image = work / "city.tif"
    with rasterio.open(
        image, "w", driver="GTiff", width=cols, height=rows, count=3, dtype="uint8",
        crs="EPSG:32119", transform=Affine(5.0, 0, x0, 0, -5.0, y1),
    ) as ds:  # fmt: skip
        ds.write(np.broadcast_to(np.array(MAGENTA, np.uint8)[:, None, None], (3, rows, cols)))
    detail = bake(tree.terrain, work / "city", shading=None, images=[image], max_texture_size=512)
    return {"tree": tree, "base": base.pyramid, "detail": detail.pyramid, "work": work}


def test_detail_used_only_at_its_levels_and_places(nc):
    """uses_detail holds exactly for nodes at tree level >= L whose domain lies inside the
    magenta rectangle (minus a coarse texel of slack at its border), never elsewhere."""
    tree = nc["tree"]
    detail = DetailTextures(nc["base"], nc["detail"], 3)
    rects = np.asarray(tree.rects, dtype=np.float64)
    used = detail.uses_detail(tree.levels, rects)
    x0, y0, x1, y1 = DETAIL_BOX
    inside = (rects[:, 0] >= x0) & (rects[:, 2] <= x1) & (rects[:, 1] >= y0) & (rects[:, 3] <= y1)
    assert not (used & ~inside).any()
    assert not (used & (tree.levels < 3)).any()
    # Well inside (by one coarse texel of the detail pyramid), every deep node uses it.
    slack = max(nc["detail"].levels[-1].texel_size)
    well = (rects[:, 0] >= x0 + slack) & (rects[:, 2] <= x1 - slack)
    well &= (rects[:, 1] >= y0 + slack) & (rects[:, 3] <= y1 - slack)
    assert (used == (well & (tree.levels >= 3)))[well | ~inside].all()
    assert used.sum() > 10


def test_rendered_frame_shows_detail_only_where_used(gl_context, nc):
    """A top-down decal render draws magenta exactly where the texturing node uses the detail
    pyramid (away from node borders), and the base's land-use colours elsewhere; γ follows."""
    from approxtree.render import Camera, Cut, Engine, Style

    tree = nc["tree"]
    detail = DetailTextures(nc["base"], nc["detail"], 3)
    c = tree.terrain.domain.center
    cam = Camera.look_at((c[0] - 2000, c[1] - 1500, 6000), (c[0] - 2000, c[1] - 1499, 0), fov=60)
    cut = Cut(alpha=0.5, gamma=0.5, share_textures=False)
    with Engine(tree, textures=detail, context=gl_context, offscreen=True) as eng:
        frame = eng.render(cam, (400, 300), cut, style=Style(lighting=False))
        eng.world_positions(frame)
        patch = eng.texture_patch(int(frame.texture_nodes[0]))
        assert patch.pyramid in (nc["base"], nc["detail"])
    rects = np.asarray(tree.rects, dtype=np.float64)
    owners = np.asarray(frame.texture_nodes)
    owner_detail = detail.uses_detail(tree.levels[owners], rects[owners])
    assert owner_detail.any() and not owner_detail.all()
    surface = frame.positions[..., 3] == 1
    xy = frame.positions[surface][:, :2]
    drawn = frame.image[surface][:, :3].astype(np.int64)
    # The selected node under each pixel (selected domains partition the terrain).
    sel = np.asarray(frame.selection.nodes)
    r = rects[sel]
    hit = (xy[:, None, 0] > r[None, :, 0] + 20) & (xy[:, None, 0] < r[None, :, 2] - 20)
    hit &= (xy[:, None, 1] > r[None, :, 1] + 20) & (xy[:, None, 1] < r[None, :, 3] - 20)
    one = hit.sum(axis=1) == 1
    which = hit[one].argmax(axis=1)
    magenta = np.abs(drawn[one] - MAGENTA).max(axis=1) <= 3
    want = owner_detail[which]
    assert want.sum() > 1000 and (~want).sum() > 1000
    assert magenta[want].mean() > 0.99
    assert magenta[~want].mean() < 0.01


def test_cli_textures_detail_spelling(nc, tmp_path):
    """render --textures BASE --textures DETAIL@LEVEL renders; a detail without a base, a
    negative level and two details are one Error line each (exit 2)."""
    runner = CliRunner()
    tree_file = tmp_path / "nc.zarr"
    nc["tree"].save(tree_file)
    base, city = str(nc["base"].folder), str(nc["detail"].folder)
    out = tmp_path / "nc.png"
    args = ["render", str(tree_file), "--size", "200x150", "--out", str(out)]
    res = runner.invoke(cli_main, [*args, "--textures", base, "--textures", f"{city}@4"])
    assert res.exit_code == 0, res.output
    assert out.is_file()
    assert isinstance(parse_textures([base, f"{city}@4"])[0], DetailTextures)
    for bad in ([f"{city}@4"], [base, f"{city}@-1"], [base, f"{city}@4", f"{city}@5"]):
        flags = [x for spec in bad for x in ("--textures", spec)]
        res = runner.invoke(cli_main, [*args, *flags, "--overwrite"])
        assert res.exit_code == 2, res.output
        assert res.output.strip().startswith("Error: "), res.output
    with pytest.raises(InvalidParameterError, match="level"):
        DetailTextures(nc["base"], nc["detail"], -2)


def test_shared_texture_patches_stay_in_their_pyramid(gl_context, nc):
    """With texture sharing on (the default cut), a selected node that uses the detail is
    textured by a node that uses it too, though the base's root patch meets γ."""
    from approxtree.render import Camera, Cut, Engine, Style

    tree = nc["tree"]
    detail = DetailTextures(nc["base"], nc["detail"], 3)
    x0, y0, x1, y1 = DETAIL_BOX
    x, y = (x0 + x1) / 2, (y0 + y1) / 2
    cam = Camera.look_at((x, y - 1500, 2000), (x, y, 0), fov=60)
    with Engine(tree, textures=detail, context=gl_context, offscreen=True) as eng:
        frame = eng.render(cam, (320, 240), Cut(alpha=0.3, gamma=2.0), style=Style(lighting=False))
    rects = np.asarray(tree.rects, dtype=np.float64)
    selected = np.asarray(frame.selection.nodes)
    owners = np.asarray(frame.texture_nodes)
    used = detail.uses_detail(tree.levels[selected], rects[selected])
    assert used.any() and (owners != selected).any()
    assert (detail.uses_detail(tree.levels[owners], rects[owners]) == used).all()
    assert _magenta(frame.image).mean() > 0.05


@pytest.fixture(scope="module")
def gl_context():
    """One headless EGL context for this module's render test."""
    from approxtree.render.context import create_context

    ctx = create_context()
    yield ctx
    ctx.release()


def test_node_keys_name_their_pyramid(nc):
    """A node's TextureKey carries its pyramid's source: 1 for a detail node, 0 otherwise."""
    from approxtree.render.texture_binding import TextureBinding

    tree = nc["tree"]
    detail = DetailTextures(nc["base"], nc["detail"], 3)
    rects = np.asarray(tree.rects, dtype=np.float64)
    binding = TextureBinding(
        detail,
        tree.origin,
        lambda o: Rect(*(float(v) for v in tree.rects[o.item])),
        lambda o: int(tree.levels[o.item]),
    )
    used = detail.uses_detail(tree.levels, rects)
    for node in np.flatnonzero(used)[:5].tolist() + np.flatnonzero(~used)[:5].tolist():
        key = binding.key(MeshKey(NODE, node))
        assert key.source == int(used[node])
        assert binding.texels(key).shape == (key.height, key.width, 4)


def _magenta(rgba: np.ndarray) -> np.ndarray:
    """(...) bool: which of (..., 3+) uint8 pixels are the detail's magenta (opaque)."""
    near = np.abs(rgba[..., :3].astype(np.int64) - MAGENTA).max(axis=-1) <= 3
    return near & (rgba[..., 3] > 250) if rgba.shape[-1] == 4 else near


@pytest.fixture(scope="module")
def nc_store(nc) -> str:
    """The NC tree saved as a store, for the commands."""
    path = nc["work"] / "nc.zarr"
    nc["tree"].save(path)
    return str(path)


def test_cli_3dtiles_detail_only_in_deep_tiles_inside(nc, nc_store, tmp_path):
    """tiles --format 3dtiles --textures BASE --textures DETAIL@3: the texture of a tile whose
    node uses the detail (level >= 3, inside the magenta box) is magenta, every other's holds
    none; both kinds are written."""
    import io

    from PIL import Image
    from tiles3d_checks import read_glb

    out = tmp_path / "tileset"
    base, city = str(nc["base"].folder), str(nc["detail"].folder)
    args = ["tiles", nc_store, "--format", "3dtiles", "--out", str(out), "--compression", "none"]
    res = CliRunner().invoke(cli_main, [*args, "--textures", base, "--textures", f"{city}@3"])
    assert res.exit_code == 0, res.output
    tree = nc["tree"]
    detail = DetailTextures(nc["base"], nc["detail"], 3)
    used = detail.uses_detail(tree.levels, np.asarray(tree.rects, dtype=np.float64))
    seen = {True: 0, False: 0}
    for path in out.rglob("*.glb"):
        glb = read_glb(path)
        node = int(glb["extras"]["node"])
        image = np.asarray(Image.open(io.BytesIO(glb["image"])).convert("RGBA"))
        share = _magenta(image).mean()
        assert share > 0.95 if used[node] else share == 0.0, (node, tree.levels[node], share)
        seen[bool(used[node])] += 1
    assert seen[True] > 10 and seen[False] > 10


def test_cli_imagery_detail_only_from_its_zoom(nc, nc_store, tmp_path):
    """tiles --format imagery --textures BASE --textures DETAIL@Z: the magenta box's centre is
    magenta in the tiles of zoom >= Z and not above; a point outside the box never is."""
    import json

    from map_checks import pixel_at
    from pyproj import Transformer

    out = tmp_path / "imagery"
    base, city = str(nc["base"].folder), str(nc["detail"].folder)
    args = ["tiles", nc_store, "--format", "imagery", "--out", str(out), "--textures", base]
    res = CliRunner().invoke(cli_main, [*args, "--textures", f"{city}@10", "--minzoom", "7"])
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "tilejson.json").read_text())
    assert doc["maxzoom"] >= 11
    to_lonlat = Transformer.from_crs("EPSG:32119", "EPSG:4326", always_xy=True)
    x0, y0, x1, y1 = DETAIL_BOX
    inside = to_lonlat.transform((x0 + x1) / 2, (y0 + y1) / 2)
    outside = to_lonlat.transform(642000.0, 226000.0)
    for z in range(7, doc["maxzoom"] + 1):
        centre, away = pixel_at(out, *inside, z), pixel_at(out, *outside, z)
        assert centre is not None and away is not None
        assert bool(_magenta(centre)) == (z >= 10), z
        assert not _magenta(away) and away[3] == 255, z


def test_verify_imagery_with_a_detail_pyramid(nc, nc_store, tmp_path):
    """verify --textures BASE --textures DETAIL@Z checks imagery cut with a detail pyramid
    pixel by pixel (exit 0); with the base alone the colours are "not checked", never a false
    failure; with the detail at another zoom the magenta box's tiles fail (exit 1)."""
    import json

    out = tmp_path / "imagery"
    base, city = str(nc["base"].folder), str(nc["detail"].folder)
    args = ["tiles", nc_store, "--format", "imagery", "--out", str(out), "--textures", base]
    res = CliRunner().invoke(cli_main, [*args, "--textures", f"{city}@10", "--minzoom", "8"])
    assert res.exit_code == 0, res.output
    check = ["verify", str(out), "--json", "--textures", base]
    res = CliRunner().invoke(cli_main, [*check, "--textures", f"{city}@10"])
    report = json.loads(res.output)
    assert res.exit_code == 0, res.output
    assert next(c for c in report["checks"] if c["name"] == "colours")["items"] > 0
    alone = CliRunner().invoke(cli_main, check)
    assert alone.exit_code == 0, alone.output
    assert any("detail pyramid" in n for n in json.loads(alone.output)["not_checked"])
    wrong = CliRunner().invoke(cli_main, [*check, "--textures", f"{city}@9"])
    assert wrong.exit_code == 1, wrong.output


def test_cli_detail_refused_where_no_texture_is_draped(nc, nc_store, tmp_path):
    """tiles --format terrarium with a detail pyramid, and tiles with two base pyramids, are
    one Error line each (exit 2)."""
    base, city = str(nc["base"].folder), str(nc["detail"].folder)
    runner = CliRunner()
    for fmt, specs in (("terrarium", [base, f"{city}@3"]), ("3dtiles", [base, base])):
        flags = [x for spec in specs for x in ("--textures", spec)]
        args = ["tiles", nc_store, "--format", fmt, "--out", str(tmp_path / fmt), *flags]
        res = runner.invoke(cli_main, args)
        assert res.exit_code == 2, res.output
        assert res.output.strip().startswith("Error: ") and "\n" not in res.output.strip()
        assert not (tmp_path / fmt).exists()


def test_cli_view_opens_with_a_detail_pyramid(nc, nc_store, tmp_path):
    """view --textures BASE --textures DETAIL@3 opens (Xvfb) and its keyframes show magenta
    looking straight down inside the box, the land use outside it."""
    from map_checks import view_keyframes

    x0, y0, x1, y1 = DETAIL_BOX
    points = [((x0 + x1) / 2, (y0 + y1) / 2), (642000.0, 226000.0)]
    script = [{"eye": [x, y - 1.0, 1500.0], "target": [x, y, 0.0], "frames": 3} for x, y in points]
    base, city = str(nc["base"].folder), str(nc["detail"].folder)
    args = ["view", nc_store, "--textures", base, "--textures", f"{city}@3"]
    shots = view_keyframes(tmp_path, args, script)
    centre = [shot[55:65, 75:85] for shot in shots]
    assert _magenta(centre[0]).all()
    assert not _magenta(centre[1]).any()
