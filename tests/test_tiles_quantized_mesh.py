"""`approxtree tiles --format quantized-mesh`: every written tile decoded and checked.

Tiles are decoded here by a parser written from the format's specification (independent of
approxtree.tiles.encoding) and by the project's reader (io.quantized_mesh, through
quantized-mesh-tile); errors are recomputed at every data point of the terrain (its valid
cell centres, carried to lon/lat by pyproj) with matplotlib's triangle interpolation
(``qm_points``).
"""

from __future__ import annotations

import gzip
import json
import struct
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file
from qm_points import DataPoints, cell_degrees, tin_at

from approxtree.cli import main
from approxtree.errors import (
    ApproxTreeError,
    EmptyTerrainError,
    InvalidParameterError,
    StoreError,
    TerrainFormatError,
)
from approxtree.geometry import Grid
from approxtree.io import open_terrain
from approxtree.io.quantized_mesh import read_quantized_mesh
from approxtree.tiles import write_quantized_mesh
from approxtree.tiles.geographic import level_error, tile_bounds

QMAX = 32767
WGS84_A, WGS84_B = 6378137.0, 6356752.3142451793


# -- an independent decoder ------------------------------------------------------------------


def _unzigzag(z: np.ndarray) -> np.ndarray:
    z = z.astype(np.int64)
    return np.cumsum((z >> 1) ^ -(z & 1))


def decode(path: Path) -> dict:
    """A .terrain file (gzip) decoded by the specification."""
    raw = path.read_bytes()
    assert raw[:2] == b"\x1f\x8b", f"{path} is not gzip-compressed"
    b = gzip.decompress(raw)
    h = struct.unpack_from("<3d2f4d3d", b, 0)
    pos = 88
    (n,) = struct.unpack_from("<I", b, pos)
    pos += 4
    uvh = np.frombuffer(b, "<u2", 3 * n, pos).reshape(3, n)
    pos += 6 * n
    u, v, hq = (_unzigzag(a) for a in uvh)
    wide = n > 65536
    itype = np.dtype("<u4") if wide else np.dtype("<u2")
    if pos % itype.itemsize:
        pos += itype.itemsize - pos % itype.itemsize
    (m,) = struct.unpack_from("<I", b, pos)
    pos += 4
    codes = np.frombuffer(b, itype, 3 * m, pos).astype(np.int64)
    pos += 3 * m * itype.itemsize
    # High-water mark: an index is (the count of zero codes before it) − its code.
    highest = np.concatenate([[0], np.cumsum(codes == 0)[:-1]])
    tri = (highest - codes).reshape(m, 3)
    edges = {}
    for side in ("west", "south", "east", "north"):
        (k,) = struct.unpack_from("<I", b, pos)
        pos += 4
        edges[side] = np.frombuffer(b, itype, k, pos).astype(np.int64)
        pos += k * itype.itemsize
    ext = {}
    while pos < len(b):
        eid, length = struct.unpack_from("<BI", b, pos)
        pos += 5
        ext[eid] = b[pos : pos + length]
        pos += length
    assert pos == len(b)
    lo, hi = h[3], h[4]
    return {
        "centre": np.array(h[0:3]),
        "min_h": lo,
        "max_h": hi,
        "sphere": (np.array(h[5:8]), h[8]),
        "hop": np.array(h[9:12]),
        "u": u,
        "v": v,
        "hq": hq,
        "height": lo + (hi - lo) * hq / QMAX,
        "tri": tri,
        "edges": edges,
        "ext": ext,
    }


def lonlat(tile: dict, bounds) -> tuple[np.ndarray, np.ndarray]:
    west, south, east, north = bounds
    return west + (east - west) * tile["u"] / QMAX, south + (north - south) * tile["v"] / QMAX


def ecef(lon, lat, h) -> np.ndarray:
    from pyproj import Transformer

    t = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    return np.column_stack(t.transform(lon, lat, h))


def written(folder: Path) -> set[tuple[int, int, int]]:
    return {
        (int(p.parent.parent.name), int(p.parent.name), int(p.stem))
        for p in folder.glob("*/*/*.terrain")
    }


def expand(ranges_by_level: list) -> set[tuple[int, int, int]]:
    return {
        (level, x, y)
        for level, ranges in enumerate(ranges_by_level)
        for r in ranges
        for x in range(r["startX"], r["endX"] + 1)
        for y in range(r["startY"], r["endY"] + 1)
    }


def terrain_truth(terrain: Grid, lon: np.ndarray, lat: np.ndarray, spacing: float) -> np.ndarray:
    """What the tiles promise at lon/lat points (any one shape) of a lattice of ``spacing``
    degrees, recomputed through pyproj: h_T inside the terrain's domain; within 1.5 spacings
    (at least 2 cells) outside it h_T at the domain's nearest edge point (the edge carried
    outward); 0 beyond; NaN where h_T has no value and within 1 % of that band's edge."""
    from pyproj import CRS, Transformer

    crs = CRS.from_user_input(terrain.crs)
    if crs.equals(CRS.from_epsg(4326), ignore_axis_order=True):
        x, y = lon, lat
    else:
        x, y = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    fr, fc = terrain.fractional_index(x, y)
    rows, cols = terrain.shape
    cr, cc = np.clip(fr, 0, rows - 1), np.clip(fc, 0, cols - 1)
    dist = np.hypot(fr - cr, fc - cc)
    band = max(2.0, 1.5 * spacing / cell_degrees(terrain))
    t = terrain.transform
    r_off, c_off = terrain.index_offset
    # Back to world coordinates a hair inside, so round-off does not put the edge outside.
    cr, cc = np.clip(cr, 1e-9, rows - 1 - 1e-9), np.clip(cc, 1e-9, cols - 1 - 1e-9)
    h = terrain.height_at(t.c + (cc + c_off + 0.5) * t.a, t.f + (cr + r_off + 0.5) * t.e)
    h = np.where(dist > band, 0.0, h)
    return np.where(np.abs(dist - band) < 0.01 * band, np.nan, h)


def terrain_samples(terrain: Grid, bounds, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """``terrain_truth`` on the tile's sample grid (row 0 south), and where the sample lies
    inside the terrain's domain (there the tiles promise their error at the data points, not
    at interpolated samples)."""
    west, south, east, north = bounds
    t = np.arange(samples) / (samples - 1)
    lon, lat = np.meshgrid(west + (east - west) * t, south + (north - south) * t)
    truth = terrain_truth(terrain, lon, lat, (east - west) / (samples - 1))
    from pyproj import CRS, Transformer

    crs = CRS.from_user_input(terrain.crs)
    if crs.equals(CRS.from_epsg(4326), ignore_axis_order=True):
        x, y = lon, lat
    else:
        x, y = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    fr, fc = terrain.fractional_index(x, y)
    rows, cols = terrain.shape
    inside = (fr >= -1e-3) & (fr <= rows - 1 + 1e-3) & (fc >= -1e-3) & (fc <= cols - 1 + 1e-3)
    return truth, inside


def tin_at_samples(tile: dict, samples: int) -> np.ndarray:
    """The decoded TIN interpolated at the sample points (matplotlib), (s, s) row 0 south."""
    q = np.arange(samples) * (QMAX / (samples - 1))
    qu, qv = np.meshgrid(q, q)
    h = tin_at(tile["u"], tile["v"], tile["height"], tile["tri"], qu.ravel(), qv.ravel())
    return h.reshape(samples, samples)


# -- checks of one tileset --------------------------------------------------------------------


def check_tileset(folder: Path, terrain: Grid, samples: int, leaf_error: float = 1.0) -> dict:
    """Every check of the issue on every tile (those of the deepest level within leaf_error
    too); returns figures for further asserts (the worst true error at the terrain's data
    points per level among them)."""
    from scipy.spatial import cKDTree

    layer = json.loads((folder / "layer.json").read_text())
    assert layer["format"] == "quantized-mesh-1.0"
    assert layer["scheme"] == "tms" and layer["projection"] == "EPSG:4326"
    assert "octvertexnormals" in layer["extensions"] and "metadata" in layer["extensions"]
    # CesiumJS reads the tiles' metadata only with metadataAvailability (else it fails on it).
    assert layer["metadataAvailability"] == 10
    tiles = written(folder)
    assert expand(layer["available"]) == tiles
    assert {t[0] for t in tiles} == set(range(layer["minzoom"], layer["maxzoom"] + 1))
    points = DataPoints(terrain)
    vertices_checked = vertices_total = 0
    decoded = {}
    worst_ratio = 0.0
    worst_of_level: dict[int, float] = {}
    for level, x, y in sorted(tiles):
        path = folder / str(level) / str(x) / f"{y}.terrain"
        t = decode(path)
        decoded[level, x, y] = t
        bounds = tile_bounds(level, x, y)
        # Vertices inside the tile, every vertex used, counter-clockwise triangles.
        assert t["u"].min() >= 0 and t["u"].max() <= QMAX
        assert t["v"].min() >= 0 and t["v"].max() <= QMAX
        assert t["hq"].min() >= 0 and t["hq"].max() <= QMAX
        assert set(np.unique(t["tri"])) == set(range(len(t["u"])))
        a, b, c = (np.column_stack([t["u"], t["v"]])[t["tri"][:, k]] for k in range(3))
        cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (
            c[:, 0] - a[:, 0]
        )
        assert (cross > 0).all()
        # Edge lists: exactly the vertices on each side.
        for side, mask in (
            ("west", t["u"] == 0),
            ("south", t["v"] == 0),
            ("east", t["u"] == QMAX),
            ("north", t["v"] == QMAX),
        ):
            assert sorted(t["edges"][side]) == sorted(np.flatnonzero(mask)), side
        # The project's reader (quantized-mesh-tile) decodes the same geometry.
        tin = read_quantized_mesh(path)
        lon, lat = lonlat(t, bounds)
        np.testing.assert_allclose(tin.vertices[:, 0], lon, atol=1e-9)
        np.testing.assert_allclose(tin.vertices[:, 1], lat, atol=1e-9)
        np.testing.assert_allclose(tin.vertices[:, 2], t["height"], atol=1e-3)
        limit = level_error(level)
        if level == layer["maxzoom"]:
            limit = min(limit, leaf_error)
        quantum = (t["max_h"] - t["min_h"]) / QMAX
        # The true error: the decoded TIN at every data point of the terrain in the tile's
        # closed square, at its own (unrounded) position; within the error, allowing only the
        # height quantization's half step.
        pu, pv, pz = points.in_tile(bounds)
        approx = tin_at(t["u"], t["v"], t["height"], t["tri"], pu, pv)
        assert np.isfinite(approx).all(), (level, x, y)
        err = float(np.abs(approx - pz).max()) if len(pz) else 0.0
        assert err <= limit + 0.5 * quantum + 1e-6, (level, x, y, err, limit)
        worst_of_level[level] = max(worst_of_level.get(level, 0.0), err)
        worst_ratio = max(worst_ratio, err / limit)
        # Outside the terrain the tile stays within the error of the edge carried outward,
        # then of 0 (the ellipsoid); inside, the error is promised at the data points above.
        truth, inside = terrain_samples(terrain, bounds, samples)
        at_samples = tin_at_samples(t, samples)
        ok = np.isfinite(truth) & ~inside
        assert np.isfinite(at_samples).all()
        off = float(np.abs(at_samples[ok] - truth[ok]).max()) if ok.any() else 0.0
        assert off <= limit * (1 + 1e-9) + 0.5 * quantum + 1e-6, (level, x, y, off, limit)
        # Each vertex is a data point (at its position rounded to the quantized grid) or a
        # lattice or edge point of the tile holding the terrain's promise there: its decoded
        # height is that within half a quantum.
        near_data = np.zeros(len(t["u"]), dtype=bool)
        if len(pz):
            around = cKDTree(np.column_stack([pu, pv])).query_ball_point(
                np.column_stack([t["u"], t["v"]]), r=1.5
            )
            near_data = np.array(
                [
                    bool(len(i)) and np.abs(pz[i] - h).min() <= 0.5 * quantum + 1e-4
                    for i, h in zip(around, t["height"], strict=True)
                ]
            )
        spacing = (bounds[2] - bounds[0]) / (samples - 1)
        own = terrain_truth(terrain, lon, lat, spacing)
        holds = np.abs(own - t["height"]) <= 0.5 * quantum + 1e-4
        assert (near_data | holds | np.isnan(own)).all(), (level, x, y)
        vertices_checked += int((near_data | holds).sum())
        vertices_total += len(t["u"])
        # Header: heights, centre, bounding sphere, horizon occlusion point.
        assert t["min_h"] == pytest.approx(t["height"].min(), abs=1e-3)
        assert t["max_h"] == pytest.approx(t["height"].max(), abs=1e-3)
        xyz = ecef(lon, lat, t["height"])
        assert np.all(t["centre"] >= xyz.min(axis=0) - 1e-3)
        assert np.all(t["centre"] <= xyz.max(axis=0) + 1e-3)
        centre, radius = t["sphere"]
        assert np.linalg.norm(xyz - centre, axis=1).max() <= radius * (1 + 1e-9) + 1e-3
        scaled = xyz / np.array([WGS84_A, WGS84_A, WGS84_B])
        hop = t["hop"]
        assert np.linalg.norm(hop) >= 1.0
        if level >= 3:
            # Seen from the occlusion point, every vertex is on or behind the horizon cone's
            # side it covers: a vertex at angle α from the point's direction and with horizon
            # angle β = acos(1/|p|) needs |point| ≥ 1 / cos(α + β) (Cesium's construction).
            d = hop / np.linalg.norm(hop)
            mag = np.linalg.norm(scaled, axis=1)
            alpha = np.arccos(np.clip((scaled / mag[:, None]) @ d, -1, 1))
            beta = np.arccos(1 / np.maximum(mag, 1))
            assert (alpha + beta < np.pi / 2).all()
            assert (np.linalg.norm(hop) * np.cos(alpha + beta) >= 1 - 1e-9).all()
        # Oct-encoded normals: unit after decoding, close to the recomputed vertex normals.
        enc = np.frombuffer(t["ext"][1], np.uint8).reshape(-1, 2)
        assert len(enc) == len(t["u"])
        f = enc.astype(float) / 255 * 2 - 1
        z = 1 - np.abs(f).sum(axis=1)
        nx = np.where(z < 0, (1 - np.abs(f[:, 1])) * np.sign(f[:, 0] + 1e-300), f[:, 0])
        ny = np.where(z < 0, (1 - np.abs(f[:, 0])) * np.sign(f[:, 1] + 1e-300), f[:, 1])
        normals = np.column_stack([nx, ny, z])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        face = np.cross(
            xyz[t["tri"][:, 1]] - xyz[t["tri"][:, 0]], xyz[t["tri"][:, 2]] - xyz[t["tri"][:, 0]]
        )
        acc = np.zeros_like(xyz)
        for kk in range(3):
            np.add.at(acc, t["tri"][:, kk], face)
        acc /= np.linalg.norm(acc, axis=1, keepdims=True)
        assert (np.einsum("ij,ij->i", normals, acc) >= np.cos(np.radians(1.5))).all()
        # Metadata: the tiles that exist below, 10 levels deep on levels 0, 10, 20 (the
        # layer's metadataAvailability), else 1; the tile's own measured error.
        (length,) = struct.unpack_from("<I", t["ext"][4], 0)
        meta = json.loads(t["ext"][4][4 : 4 + length])
        depth = min(10 if level % 10 == 0 else 1, layer["maxzoom"] - level)
        assert len(meta["available"]) == depth
        below = expand([[]] * (level + 1) + meta["available"])
        expected = {
            (z, tx, ty)
            for z, tx, ty in tiles
            if level < z <= level + depth and tx >> (z - level) == x and ty >> (z - level) == y
        }
        assert below == expected
        # The tile's declared error is the true one at its data points.
        assert meta["geometricError"] == pytest.approx(err, rel=1e-6, abs=1e-6)
    # The vertex check above skips only vertices of unknown promise (filled nodata, the band's
    # edge): most are checked.
    assert vertices_checked > 0.75 * vertices_total
    # Neighbours: where both have a vertex at the same point of the shared edge, the heights
    # agree (the same sample) within the two tiles' quantization.
    shared = 0
    for (level, x, y), t in decoded.items():
        # East edge against the east neighbour's west edge (keyed by v), north edge against
        # the north neighbour's south edge (keyed by u).
        for other, mine, theirs, key in (
            (decoded.get((level, x + 1, y)), "east", "west", "v"),
            (decoded.get((level, x, y + 1)), "north", "south", "u"),
        ):
            if other is None:
                continue
            a = dict(zip(t[key][t["edges"][mine]], t["height"][t["edges"][mine]], strict=True))
            b = dict(
                zip(
                    other[key][other["edges"][theirs]],
                    other["height"][other["edges"][theirs]],
                    strict=True,
                )
            )
            q = (t["max_h"] - t["min_h"] + other["max_h"] - other["min_h"]) / QMAX
            for k in set(a) & set(b):
                assert abs(a[k] - b[k]) <= 0.5 * q + 1e-4, (level, x, y, mine)
                shared += 1
    return {
        "tiles": tiles,
        "decoded": decoded,
        "worst_ratio": worst_ratio,
        "shared": shared,
        "worst_of_level": worst_of_level,
    }


# -- tests ------------------------------------------------------------------------------------


def srtm_crop(data_dir: Path) -> Grid:
    g = open_terrain(data_file(data_dir, "srtm/N44W072.hgt"))
    # 0.2° × 0.2° around Mt Washington (no voids in this tile).
    return g.window(600, 840, 700, 940)


def utm_mountain(data_dir: Path) -> Grid:
    """Mt Washington (SRTM 3″, summit inside) warped to UTM 19N at 30 m: a steep DEM in a
    projected CRS the other tests do not use (330 × 465 cells, relief about 1,400 m)."""
    import rasterio
    from rasterio.warp import Resampling, calculate_default_transform, reproject
    from rasterio.windows import Window

    path = data_file(data_dir, "srtm/N44W072.hgt")
    with rasterio.open(path) as ds:
        window = Window(760, 800, 150, 150)
        src = ds.read(1, window=window).astype(np.float32)
        src_transform = ds.window_transform(window)
        transform, width, height = calculate_default_transform(
            ds.crs,
            "EPSG:32619",
            150,
            150,
            *rasterio.windows.bounds(window, ds.transform),
            resolution=30.0,
        )
        dst = np.full((height, width), np.nan, dtype=np.float32)
        reproject(
            src,
            dst,
            src_transform=src_transform,
            src_crs=ds.crs,
            dst_transform=transform,
            dst_crs="EPSG:32619",
            resampling=Resampling.bilinear,
            dst_nodata=np.nan,
        )
    return Grid(dst, transform, crs="EPSG:32619")


def test_steep_projected_dem_is_within_its_error_at_every_data_point(data_dir, tmp_path):
    """A steep mountain DEM in UTM (nodata corners from the warp): every tile's decoded TIN is
    within its level's error (the leaf level's 1 m) at every data point in it, recomputed
    independently, and each tile declares that true error (figures and metadata)."""
    terrain = utm_mountain(data_dir)
    assert terrain.nodata_count > 0 and np.ptp(terrain.z_range) > 1000
    figures = write_quantized_mesh(terrain, tmp_path / "m")
    found = check_tileset(tmp_path / "m", terrain, 152)
    deepest = max(found["worst_of_level"])
    assert figures["leaf_max_error"] == pytest.approx(found["worst_of_level"][deepest], rel=1e-6)
    assert 0.5 < figures["leaf_max_error"] <= 1.0
    # Every data point is measured in some tile of the deepest level (on shared edges in two).
    measured = sum(r["data_points"] for r in figures["results"] if r["level"] == deepest)
    assert terrain.point_count <= measured < 1.1 * terrain.point_count


def test_decimated_tiles_are_measured_at_every_point(data_dir, tmp_path, monkeypatch):
    """A tile holding more points than the insertion starts from (here 4,096 of NC's 225,000)
    takes a decimated subset, measures every point in chunks, adds the points over the error
    and runs again: still within its error at every data point, as recomputed here."""
    from approxtree.tiles import tile_tin

    monkeypatch.setattr(tile_tin, "FIRST_CANDIDATES", 4096)
    monkeypatch.setattr(tile_tin, "POINT_CAP", 16384)
    monkeypatch.setattr(tile_tin, "MEASURE_CHUNK", 5000)
    monkeypatch.setattr(tile_tin, "VIOLATOR_CAP", 256)
    terrain = open_terrain(data_file(data_dir, "nc/elev_ned_30m.tif"))
    figures = write_quantized_mesh(terrain, tmp_path / "d", maxzoom=11, leaf_error=5.0)
    check_tileset(tmp_path / "d", terrain, 152, leaf_error=5.0)
    big = [r for r in figures["results"] if r["data_points"] > 16384]
    assert big and max(r["rounds"] for r in big) > 1


def test_tile_bounds_follow_morecantile_world_crs84_quad():
    morecantile = pytest.importorskip("morecantile")
    tms = morecantile.tms.get("WorldCRS84Quad")
    for z, x, y in [(0, 0, 0), (0, 1, 0), (3, 5, 2), (9, 533, 383), (13, 4606, 5721)]:
        # morecantile counts y from the north (XYZ); the TMS scheme from the south.
        b = tms.bounds(morecantile.Tile(x, 2**z - 1 - y, z))
        assert tile_bounds(z, x, y) == pytest.approx((b.left, b.bottom, b.right, b.top))


def test_srtm_tiles_are_exact_to_their_level_error(data_dir, tmp_path):
    terrain = srtm_crop(data_dir)
    out = tmp_path / "srtm"
    figures = write_quantized_mesh(terrain, out, samples=152)
    found = check_tileset(out, terrain, 152)
    assert figures["tiles"] == len(found["tiles"])
    # The deepest level's sample spacing reaches the 3″ cell, the level above's does not.
    deepest = max(level for level, _, _ in found["tiles"])
    assert 180 / 2**deepest / 151 <= 1 / 1200 < 180 / 2 ** (deepest - 1) / 151
    # The greedy insertion went as far as the error allows: some tile is close to it.
    assert found["worst_ratio"] > 0.5
    assert found["shared"] > 0


def test_projected_dem_from_tree_store_and_workers_match_the_raster(data_dir, tmp_path):
    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    runner = CliRunner()
    store = tmp_path / "nc.zarr"
    r = runner.invoke(main, ["build", str(dem), "--out", str(store), "--epsilon", "2"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(
        main,
        [
            "tiles",
            str(store),
            "--out",
            str(tmp_path / "a"),
            "--format",
            "quantized-mesh",
            "--maxzoom",
            "12",
            "--workers",
            "2",
            "--json",
        ],
    )
    assert r.exit_code == 0, r.output
    figures = json.loads(r.output)
    assert figures["tiles"] == len(written(tmp_path / "a"))
    # The deepest level is made to the store's ε by default.
    assert figures["leaf_error"] == 2.0
    r = runner.invoke(
        main,
        [
            "tiles",
            str(dem),
            "--out",
            str(tmp_path / "b"),
            "--format",
            "quantized-mesh",
            "--maxzoom",
            "12",
            "--leaf-error",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    for z, x, y in written(tmp_path / "a"):
        rel = Path(str(z), str(x), f"{y}.terrain")
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes()
    assert written(tmp_path / "a") == written(tmp_path / "b")
    check_tileset(tmp_path / "a", open_terrain(dem), 152, leaf_error=2.0)


def test_deepest_level_is_within_the_leaf_error(data_dir, tmp_path):
    """CesiumJS keeps showing the deepest level as the camera comes closer: its tiles are made
    to the leaf error (here 3 m) instead of the level's error (37.6 m at level 11), measured
    on every decoded tile against the terrain; with an infinite leaf error they are not."""
    terrain = srtm_crop(data_dir)
    fine = write_quantized_mesh(terrain, tmp_path / "fine", leaf_error=3.0)
    found = check_tileset(tmp_path / "fine", terrain, 152, leaf_error=3.0)
    deepest = max(found["worst_of_level"])
    assert level_error(deepest) > 10 * 3.0
    # Within 3 m, and the greedy insertion went that far (it did not insert everything).
    assert 1.5 < found["worst_of_level"][deepest] <= 3.0
    assert fine["leaf_max_error"] == pytest.approx(found["worst_of_level"][deepest], rel=1e-6)
    # The levels above keep their level's error.
    assert found["worst_of_level"][deepest - 1] > 3.0
    coarse = write_quantized_mesh(terrain, tmp_path / "coarse", leaf_error=float("inf"))
    found = check_tileset(tmp_path / "coarse", terrain, 152, leaf_error=float("inf"))
    assert found["worst_of_level"][deepest] > 3.0
    assert coarse["vertices"] < fine["vertices"]
    with pytest.raises(InvalidParameterError, match="leaf_error"):
        write_quantized_mesh(terrain, tmp_path / "x", leaf_error=0.0)


def test_nodata_holes_are_filled_from_neighbouring_samples(data_dir, tmp_path):
    terrain = open_terrain(data_file(data_dir, "edge/SainteHelens.dem"))
    assert terrain.nodata_count > 0
    out = tmp_path / "sh"
    write_quantized_mesh(terrain, out, samples=32, maxzoom=11)
    found = check_tileset(out, terrain, 32)
    zmin, zmax = terrain.z_range
    for (level, _, _), t in found["decoded"].items():
        h = t["height"]
        # Holes take a neighbouring sample's height, never a height outside the data's range
        # (samples outside the DEM's domain are 0).
        inside = (h >= zmin - 1) & (h <= zmax + 1)
        assert (inside | (np.abs(h) < 1e-3)).all()
        if level == 11:
            assert inside.any()


def test_water_mask_tiles(data_dir, tmp_path):
    import rasterio
    from rasterio.transform import from_origin

    terrain = srtm_crop(data_dir)
    west, south, east, north = (
        terrain.domain.xmin,
        terrain.domain.ymin,
        terrain.domain.xmax,
        terrain.domain.ymax,
    )
    # Water north of the crop's middle latitude, land south of it.
    n = 400
    water = np.zeros((n, n), dtype=np.uint8)
    water[: n // 2] = 1
    mask_file = tmp_path / "water.tif"
    with rasterio.open(
        mask_file,
        "w",
        driver="GTiff",
        width=n,
        height=n,
        count=1,
        dtype="uint8",
        crs="EPSG:4326",
        transform=from_origin(west, north, (east - west) / n, (north - south) / n),
    ) as ds:
        ds.write(water, 1)
    out = tmp_path / "w"
    write_quantized_mesh(terrain, out, samples=152, maxzoom=10, water_mask=mask_file)
    layer = json.loads((out / "layer.json").read_text())
    assert "watermask" in layer["extensions"]
    middle = 0.5 * (south + north)
    kinds = set()
    for z, x, y in written(out):
        t = decode(out / str(z) / str(x) / f"{y}.terrain")
        mask = np.frombuffer(t["ext"][2], np.uint8)
        w, s, e, nn = tile_bounds(z, x, y)
        if len(mask) == 1:
            kinds.add("uniform")
            # Uniform tiles lie wholly on one side (or outside the mask: land).
            assert mask[0] in (0, 255)
            continue
        kinds.add("mixed")
        assert len(mask) == 256 * 256
        m = mask.reshape(256, 256)
        # Row 0 is north: pixel centres north of the middle (and inside the mask) are water.
        lat = nn - (nn - s) * (np.arange(256) + 0.5) / 256
        lon = w + (e - w) * (np.arange(256) + 0.5) / 256
        in_lon = (lon > west + 1e-3) & (lon < east - 1e-3)
        rows_water = (lat > middle + 1e-3) & (lat < north - 1e-3)
        rows_land = lat < middle - 1e-3
        assert (m[np.ix_(rows_water, in_lon)] == 255).all()
        assert (m[np.ix_(rows_land, in_lon)] == 0).all()
    assert kinds == {"uniform", "mixed"}


def test_terrain_without_crs_is_refused(data_dir, tmp_path):
    dem = data_file(data_dir, "scape/crater.stm")
    r = CliRunner().invoke(
        main, ["tiles", str(dem), "--out", str(tmp_path / "t"), "--format", "quantized-mesh"]
    )
    assert r.exit_code == 2
    assert r.output.startswith("Error:") and "no CRS" in r.output
    assert not (tmp_path / "t").exists()
    with pytest.raises(TerrainFormatError, match="no CRS"):
        write_quantized_mesh(open_terrain(dem), tmp_path / "t")


def test_tiles_on_an_existing_dask_scheduler_match_serial(data_dir, tmp_path):
    """--scheduler: the tile batches run on an existing dask cluster (here one in this process)
    and give the same bytes as the serial run; a scheduler and a worker count together are
    refused."""
    from distributed import LocalCluster

    terrain = srtm_crop(data_dir)
    write_quantized_mesh(terrain, tmp_path / "a", maxzoom=7)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False) as cluster:
        address = cluster.scheduler_address
        write_quantized_mesh(terrain, tmp_path / "b", maxzoom=7, scheduler=address)
        with pytest.raises(InvalidParameterError, match="not both"):
            write_quantized_mesh(terrain, tmp_path / "c", maxzoom=7, workers=2, scheduler=address)
    tiles = written(tmp_path / "a")
    assert tiles == written(tmp_path / "b") and len(tiles) > 8
    for z, x, y in tiles:
        rel = Path(str(z), str(x), f"{y}.terrain")
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes()


def test_bad_input_gets_clear_errors(tmp_path):
    from affine import Affine

    nodata_only = Grid(
        np.full((20, 20), np.nan),
        Affine(0.01, 0, -72, 0, -0.01, 45),
        crs="EPSG:4326",
        allow_empty=True,
    )
    with pytest.raises(EmptyTerrainError, match="nodata only"):
        write_quantized_mesh(nodata_only, tmp_path / "a")
    # A windowed one is not scanned beforehand: found when no tile sampled a height, and
    # nothing is left behind.
    from approxtree.geometry.windowed import ArraySource, WindowedHeights

    windowed = Grid(
        WindowedHeights(ArraySource(np.full((20, 20), np.nan))),
        Affine(0.01, 0, -72, 0, -0.01, 45),
        crs="EPSG:4326",
        allow_empty=True,
    )
    with pytest.raises(EmptyTerrainError, match="nodata only"):
        write_quantized_mesh(windowed, tmp_path / "w", maxzoom=12)
    assert not (tmp_path / "w").exists()
    ok = Grid(np.zeros((20, 20)), Affine(0.01, 0, -72, 0, -0.01, 45), crs="EPSG:4326")
    with pytest.raises(InvalidParameterError, match="32767"):
        write_quantized_mesh(ok, tmp_path / "a", samples=65)
    with pytest.raises(InvalidParameterError, match="minzoom"):
        write_quantized_mesh(ok, tmp_path / "a", minzoom=5, maxzoom=3)
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "thesis.tex").write_text("keep me")
    with pytest.raises(StoreError, match="not a terrain tileset"):
        write_quantized_mesh(ok, precious, maxzoom=2)
    assert (precious / "thesis.tex").read_text() == "keep me"
    # A tileset folder is replaced as a whole.
    write_quantized_mesh(ok, tmp_path / "ts", maxzoom=3)
    write_quantized_mesh(ok, tmp_path / "ts", maxzoom=2)
    assert max(z for z, _, _ in written(tmp_path / "ts")) == 2
    assert issubclass(EmptyTerrainError, ApproxTreeError)


def cesium_engine() -> Path:
    """CesiumJS's engine module: web/node_modules of this checkout (APPROXTREE_CESIUM_ENGINE
    overrides); the test skips when node or the npm package is absent."""
    import os
    import shutil

    if shutil.which("node") is None:
        pytest.skip("node is not installed")
    default = Path(__file__).resolve().parents[1] / "web/node_modules/@cesium/engine/index.js"
    engine = Path(os.environ.get("APPROXTREE_CESIUM_ENGINE", default))
    if not engine.is_file():
        pytest.skip(f"CesiumJS (npm @cesium/engine) is not installed at {engine}")
    return engine


def test_cesiumjs_terrain_provider_loads_every_tile(data_dir, tmp_path):
    """CesiumJS's own CesiumTerrainProvider (in node) reads layer.json, walks the quadtree by
    the availability it gets from the tiles' metadata, and decodes exactly the tiles written,
    with their normals and water masks."""
    import subprocess

    engine = cesium_engine()
    terrain = srtm_crop(data_dir)
    d = terrain.domain
    import rasterio
    from rasterio.transform import from_origin

    mask_file = tmp_path / "water.tif"
    water = np.zeros((100, 100), dtype=np.uint8)
    water[:30] = 1
    with rasterio.open(
        mask_file,
        "w",
        driver="GTiff",
        width=100,
        height=100,
        count=1,
        dtype="uint8",
        crs="EPSG:4326",
        transform=from_origin(d.xmin, d.ymax, (d.xmax - d.xmin) / 100, (d.ymax - d.ymin) / 100),
    ) as ds:
        ds.write(water, 1)
    out = tmp_path / "t"
    write_quantized_mesh(terrain, out, maxzoom=11, water_mask=mask_file)
    script = Path(__file__).with_name("js") / "cesium_terrain_walk.mjs"
    proc = subprocess.run(
        ["node", str(script), str(engine), str(out)], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["hasVertexNormals"] and report["hasWaterMask"] and report["hasMetadata"]
    loaded = {(t["level"], t["x"], t["y"]) for t in report["tiles"]}
    assert loaded == written(out)
    for t in report["tiles"]:
        mine = decode(out / str(t["level"]) / str(t["x"]) / f"{t['y']}.terrain")
        assert t["vertices"] == t["normals"] == len(mine["u"])
        assert t["waterMask"] == len(mine["ext"][2])
        assert t["minimumHeight"] == pytest.approx(mine["min_h"])
    assert {t["waterMask"] for t in report["tiles"]} == {1, 256 * 256}


def test_max_error_chooses_a_deeper_maxzoom(data_dir, tmp_path):
    """--max-error 20: the 3″ crop's default deepest level 11 (37.6 m) is not enough, level 12
    (18.8 m) is; every tile of it is within 20 m, measured on the decoded tile."""
    terrain = srtm_crop(data_dir)
    out = tmp_path / "e"
    r = CliRunner().invoke(
        main,
        [
            "tiles",
            str(data_file(data_dir, "srtm/N44W072.hgt")),
            "--out",
            str(out),
            "--format",
            "quantized-mesh",
            "--max-error",
            "20",
            "--json",
        ],
    )
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["levels"] == "0..12"
    out2 = tmp_path / "e2"
    write_quantized_mesh(terrain, out2, max_error=20.0)
    found = check_tileset(out2, terrain, 152)
    assert max(z for z, _, _ in found["tiles"]) == 12
    with pytest.raises(InvalidParameterError, match="not both"):
        write_quantized_mesh(terrain, tmp_path / "x", max_error=20.0, maxzoom=3)
    with pytest.raises(InvalidParameterError, match="at least"):
        write_quantized_mesh(terrain, tmp_path / "x", max_error=0.0)
