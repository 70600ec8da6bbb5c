"""Re-bakes of pyramids with a thematic layer, images, overlays or water polygons: the shading
is re-blended with them, texel for texel as a fresh bake with the same inputs; an input gone or
changed is refused."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file
from test_rebake import cells_rect, random_edits, same_pyramid

from approxtree.cli import main
from approxtree.errors import StoreError
from approxtree.geometry.grid import Grid
from approxtree.io import read_grid
from approxtree.textures.bake import bake
from approxtree.textures.pyramid import TexturePyramid
from approxtree.textures.rebake import rebake
from approxtree.tree.approximation_tree import ApproximationTree


@pytest.fixture
def nc(data_dir) -> Grid:
    """The NC DEM (500 × 450, 30 m cells)."""
    return read_grid(data_file(data_dir, "nc/elev_ned_30m.tif"))


@pytest.fixture
def landuse(data_dir, tmp_path) -> Path:
    """A copy of NC's land use raster (class table), free to be changed by a test."""
    path = tmp_path / "landuse.tif"
    shutil.copy(data_file(data_dir, "nc/landuse_r.tif"), path)
    return path


def test_thematic_rebakes_equal_fresh_bakes(nc, landuse, tmp_path) -> None:
    """Random edits (nodata, edges) under NC's land use, and a rising water level between the
    two: each re-bake re-blends only the reached tiles and equals a fresh bake with the same
    thematic raster and water level."""
    args = {"gl": False, "max_texture_size": 256, "thematic": landuse, "texel_size": 10.0}
    folder = tmp_path / "p"
    bake(nc, folder, water_level=50.0, **args)
    assert TexturePyramid(folder).recipe["thematic"]["path"] == str(landuse.resolve())
    heights = np.array(nc.heights, dtype=np.float64)
    for i, (r0, c0, patch) in enumerate(random_edits(nc, seed=11, count=3, largest=60)):
        heights[r0 : r0 + patch.shape[0], c0 : c0 + patch.shape[1]] = patch
        grid = Grid(heights.astype(np.float32), nc.transform, nc.crs, allow_empty=True)
        level = 50.0 + 10.0 * i
        result = rebake(folder, grid, cells_rect(nc, r0, c0, *patch.shape), water_level=level)
        assert not result.whole and sum(result.tiles) < sum(result.tiles_total)
        fresh = tmp_path / f"fresh{i}"
        bake(grid, fresh, water_level=level, **args)
        same_pyramid(folder, fresh)


def test_thematic_rebake_refuses_a_changed_or_gone_raster(nc, landuse, tmp_path) -> None:
    """A thematic raster touched (new modification time) or removed since the bake: the
    re-bake is a StoreError naming it, and the CLI says so on one Error: line."""
    folder = tmp_path / "p"
    bake(nc, folder, gl=False, max_texture_size=256, thematic=landuse)
    st = landuse.stat()
    os.utime(landuse, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    with pytest.raises(StoreError, match="changed since"):
        rebake(folder, nc, cells_rect(nc, 10, 10, 5, 5))
    # Given its time back, the raster re-bakes again; removed, it is refused.
    os.utime(landuse, ns=(st.st_atime_ns, st.st_mtime_ns))
    rebake(folder, nc, cells_rect(nc, 10, 10, 5, 5))
    store = tmp_path / "dem.zarr"
    ApproximationTree.build(nc, epsilon=2.0, max_points=33 * 33).save(store)
    landuse.unlink()
    result = CliRunner().invoke(main, ["update", str(store), "--textures", str(folder)])
    assert result.exit_code != 0
    assert "is gone" in result.output and result.output.count("Error:") == 1


def write_water(path: Path, grid: Grid) -> Path:
    """A GeoJSON of three water polygons (one with a hole) over the grid, in its CRS."""
    d = grid.domain
    w, h = d.xmax - d.xmin, d.ymax - d.ymin

    def ring(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
        xa, ya = d.xmin + x0 * w, d.ymin + y0 * h
        xb, yb = d.xmin + x1 * w, d.ymin + y1 * h
        return [[xa, ya], [xb, ya + 0.3 * (yb - ya)], [xb, yb], [xa, yb], [xa, ya]]

    polygons = [
        [ring(0.1, 0.1, 0.35, 0.3)],
        [ring(0.5, 0.5, 0.9, 0.85), ring(0.6, 0.6, 0.7, 0.7)],
        [ring(0.0, 0.7, 0.2, 1.0)],
    ]
    features = [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": p}}
        for p in polygons
    ]
    crs = {"type": "name", "properties": {"name": grid.crs}}
    path.write_text(json.dumps({"type": "FeatureCollection", "crs": crs, "features": features}))
    return path


def edit_and_compare(tmp_path: Path, grid: Grid, args: dict, seed: int) -> Grid:
    """Bake ``grid`` with ``args``, then random edits (nodata, edges): each re-bake rewrites
    only the reached tiles and equals a fresh bake of the edited grid; returns the last grid."""
    folder = tmp_path / "p"
    bake(grid, folder, **args)
    heights = np.array(grid.heights, dtype=np.float64)
    edits = [*random_edits(grid, seed=seed, count=3, largest=60), (0, 0, np.full((30, 30), 90.0))]
    for i, (r0, c0, patch) in enumerate(edits):
        heights[r0 : r0 + patch.shape[0], c0 : c0 + patch.shape[1]] = patch
        edited = Grid(heights.astype(np.float32), grid.transform, grid.crs, allow_empty=True)
        result = rebake(folder, edited, cells_rect(grid, r0, c0, *patch.shape))
        assert not result.whole and sum(result.tiles) < sum(result.tiles_total)
        fresh = tmp_path / f"fresh{i}"
        bake(edited, fresh, **args)
        same_pyramid(folder, fresh)
    return edited


def test_overlay_rebakes_equal_fresh_bakes(nc, data_dir, tmp_path) -> None:
    """NC's streams drawn over the shading (redrawn at every level, a width and colour of
    their own): re-bakes (edits, a new light) equal fresh bakes; a stream file changed since is
    refused."""
    streams = tmp_path / "streams"
    streams.mkdir()
    for ext in ("shp", "shx", "dbf", "prj"):
        shutil.copy(data_file(data_dir, f"nc/streams.{ext}"), streams / f"streams.{ext}")
    lines = streams / "streams.shp"
    args = {"gl": False, "max_texture_size": 256, "texel_size": 10.0, "overlays": [lines]}
    args |= {"overlay_colour": (200, 30, 30, 200), "overlay_width": 25.0}
    edited = edit_and_compare(tmp_path, nc, args, seed=3)
    recipe = TexturePyramid(tmp_path / "p").recipe
    assert recipe["overlay_colour"] == [200, 30, 30, 200] and recipe["overlay_width"] == 25.0
    # A new light re-bakes it whole with the recorded streams, colour and width.
    assert rebake(tmp_path / "p", edited, shading_options={"azimuth": 200.0}).whole
    bake(edited, tmp_path / "light", shading_options={"azimuth": 200.0}, **args)
    same_pyramid(tmp_path / "p", tmp_path / "light")
    st = lines.stat()
    os.utime(lines, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    with pytest.raises(StoreError, match="changed since"):
        rebake(tmp_path / "p", edited, cells_rect(nc, 10, 10, 5, 5))


def test_water_polygon_rebakes_equal_fresh_bakes(nc, tmp_path) -> None:
    """Water polygons (one with a hole) over the shading: re-bakes equal fresh bakes."""
    water = write_water(tmp_path / "lakes.geojson", nc)
    args = {"gl": False, "max_texture_size": 256, "texel_size": 15.0, "water": [water]}
    edit_and_compare(tmp_path, nc, args, seed=8)


def test_thematic_overlay_water_rebakes_equal_fresh_bakes(nc, landuse, data_dir, tmp_path):
    """Land use, streams (hidden under its water classes: the water mask, coarsened at every
    level) and water polygons together: re-bakes equal fresh bakes; a polygon file gone is
    refused."""
    streams = data_file(data_dir, "nc/streams.shp")
    water = write_water(tmp_path / "lakes.geojson", nc)
    args = {"gl": False, "max_texture_size": 256, "thematic": landuse, "palette": "landclass96"}
    args |= {"overlays": [streams], "water": [water], "water_level": 60.0}
    edited = edit_and_compare(tmp_path, nc, args, seed=21)
    water.unlink()
    with pytest.raises(StoreError, match="is gone"):
        rebake(tmp_path / "p", edited, cells_rect(nc, 10, 10, 5, 5))


def write_image(path: Path, grid: Grid) -> Path:
    """An RGB GeoTIFF in EPSG:4326 (reprojected by the bake) over most of the grid: smooth
    gradients with a checker, 400 × 360 pixels."""
    import rasterio
    from affine import Affine
    from rasterio.warp import transform_bounds

    d = grid.domain
    west, south, east, north = transform_bounds(
        grid.crs, "EPSG:4326", d.xmin, d.ymin, d.xmax, d.ymax
    )
    rows, cols = 360, 400
    y, x = np.mgrid[0:rows, 0:cols]
    rgb = np.stack([x * 255 // cols, y * 255 // rows, ((x // 20 + y // 20) % 2) * 200 + 30])
    t = Affine((east - west) / cols * 0.9, 0, west, 0, -(north - south) / rows * 0.9, north)
    profile = {"driver": "GTiff", "width": cols, "height": rows, "count": 3, "dtype": "uint8"}
    with rasterio.open(path, "w", crs="EPSG:4326", transform=t, **profile) as ds:
        ds.write(rgb.astype(np.uint8))
    return path


def test_image_rebakes_equal_fresh_bakes(nc, landuse, tmp_path) -> None:
    """An image in another CRS under the land use and the shading: edits (one at the image's
    edge) re-blend only the reached tiles, equal to fresh bakes with the same inputs; an image
    changed since is refused."""
    image = write_image(tmp_path / "photo.tif", nc)
    args = {"gl": False, "max_texture_size": 256, "texel_size": 10.0, "images": [image]}
    args["thematic"] = landuse
    folder = tmp_path / "p"
    bake(nc, folder, **args)
    heights = np.array(nc.heights, dtype=np.float64)
    edits = [*random_edits(nc, seed=5, count=2, largest=60), (400, 440, np.full((40, 40), 80.0))]
    for i, (r0, c0, patch) in enumerate(edits):
        heights[r0 : r0 + patch.shape[0], c0 : c0 + patch.shape[1]] = patch
        grid = Grid(heights.astype(np.float32), nc.transform, nc.crs, allow_empty=True)
        result = rebake(folder, grid, cells_rect(nc, r0, c0, *patch.shape))
        assert not result.whole and sum(result.tiles) < sum(result.tiles_total)
        fresh = tmp_path / f"fresh{i}"
        bake(grid, fresh, **args)
        same_pyramid(folder, fresh)
    write_image(image, nc)
    st = image.stat()
    os.utime(image, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    with pytest.raises(StoreError, match="changed since"):
        rebake(folder, grid, cells_rect(nc, 10, 10, 5, 5))


def test_new_light_over_a_thematic_layer_equals_fresh_bake(nc, landuse, tmp_path) -> None:
    """A new light re-bakes a thematic pyramid whole with its recorded raster and palette."""
    args = {"gl": False, "max_texture_size": 256, "thematic": landuse, "palette": "nlcd"}
    bake(nc, tmp_path / "p", **args)
    result = rebake(tmp_path / "p", nc, shading_options={"azimuth": 200.0})
    assert result.whole
    bake(nc, tmp_path / "fresh", shading_options={"azimuth": 200.0}, **args)
    same_pyramid(tmp_path / "p", tmp_path / "fresh")
    assert TexturePyramid(tmp_path / "p").recipe["thematic"]["palette"] == "nlcd"
