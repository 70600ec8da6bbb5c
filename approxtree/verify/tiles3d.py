"""Verify a 3D Tiles folder (``approxtree tiles --format 3dtiles`` or ``3dtiles-terrain``)
against its source terrain.

The tileset is walked from tileset.json through every tile, external tileset (a content uri
ending in .json) and implicit tileset (``implicitTiling``: its subtree files read by
verify/implicit_read.py, each available tile with the volume and error its tile metadata
declares), each tile's transform composed with its parent's. Checks:

- ``content``: every content uri exists and parses as GLB (pygltflib; Draco through DracoPy,
  meshopt through meshoptimizer), with triangles;
- ``implicit`` (implicit tilesets): subtrees parse, every available tile's parent is
  available, and each tile's halved error (what clients without metadata use) is at least
  its declared one;
- ``volumes``: every tile's bounding volume (region or box) holds its content's vertices and
  its children's volumes (spheres are not checked);
- ``monotone``: no child claims a larger geometricError than its parent;
- ``errors``: each tile's true max |mesh − h_T| over the source's data points under its
  triangles is within its ``geometricError``: positions are taken through glTF's y-up → z-up
  and the tile's transform to ECEF, then to the terrain's CRS (pyproj, EPSG:4978 → 4979 →
  the CRS, heights as ellipsoidal heights, as the writer placed them), or, for terrain without
  a CRS, back through the local east-north-up frame of the root's transform (centred on the
  terrain's domain). The stored positions count as they decode (float32 rounding, lattice
  quantization); skirts hold no point: vertical walls in float32 content, a primitive marked
  ``"extras": {"skirt": true}`` in compressed content (on a lattice its walls lean a little).
  3D Tiles terrain (the two hemispheres of Cesium's geographic tiling as implicit tilesets)
  is measured in longitude, latitude and height, as quantized-mesh tiles are.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import StoreError
from approxtree.verify.implicit_read import implicit_tiles
from approxtree.verify.measure import measure_for
from approxtree.verify.mesh import measure_tolerance
from approxtree.verify.mesh_read import read_glb_parts, z_up
from approxtree.verify.quantized_mesh import LonLatMeasure, tile_bounds
from approxtree.verify.report import VerifyReport, claims_hold

#: WGS84 axes (m), for the east-north-up frame of terrain without a CRS.
_A, _B = 6378137.0, 6356752.314245179
#: Volume slack: radians of a region, metres of heights, fraction of a box's half axes.
_RAD, _METRES, _BOX = 1e-9, 1e-3, 1e-6
#: Tiles read (and measured) together.
_BATCH = 256


@dataclass
class Tile:
    """One tile of the walk: its address, composed transform, volume, claim and content."""

    address: str
    matrix: np.ndarray
    volume: dict[str, Any]
    error: float
    parent: int
    contents: list[Path] = field(default_factory=list)
    #: (level, x, y) in Cesium's geographic tiling (TMS, y from the south) for the tiles of
    #: an implicit hemisphere (3D Tiles terrain), else None.
    geographic: tuple[int, int, int] | None = None


def _matrix(tile: dict[str, Any]) -> np.ndarray:
    t = tile.get("transform")
    return np.eye(4) if t is None else np.array(t, dtype=np.float64).reshape(4, 4).T


def walk(path: Path, report: VerifyReport) -> list[Tile]:
    """Every tile of the tileset at ``path`` and of its external tilesets, parents first."""
    tiles: list[Tile] = []
    content = report.check("content", "every content referenced exists and parses as GLB")

    def load(json_path: Path) -> dict[str, Any]:
        try:
            return json.loads(json_path.read_text())
        except (OSError, ValueError) as exc:
            raise StoreError(f"{json_path} is not a readable tileset.json: {exc}") from exc

    doc = load(path)
    report.figures["tileset_geometric_error"] = doc.get("geometricError")
    stack: list[tuple[dict, np.ndarray, int, str, Path, dict]] = [
        (doc.get("root") or {}, np.eye(4), -1, "root", path.parent, doc.get("schema") or {})
    ]
    seen: set[Path] = {path.resolve()}
    while stack:
        raw, parent_m, parent, address, base, schema = stack.pop()
        m = parent_m @ _matrix(raw)
        if "implicitTiling" in raw:
            _expand_implicit(raw, m, parent, address, base, schema, tiles, report)
            continue
        me = len(tiles)
        tile = Tile(
            address,
            m,
            raw.get("boundingVolume") or {},
            float(raw.get("geometricError", math.inf)),
            parent,
        )
        tiles.append(tile)
        refs = [raw["content"]] if "content" in raw else list(raw.get("contents") or [])
        for ref in refs:
            uri = ref.get("uri") or ref.get("url")
            target = base / str(uri)
            content.items += 1
            if uri is None or not target.is_file():
                content.fail(f"{address} → {uri}", "a file", "missing")
            elif str(uri).lower().endswith(".json"):
                # An external tileset: its root hangs below this tile.
                if target.resolve() in seen:
                    content.fail(str(uri), "a tileset", "referenced twice (a cycle)")
                    continue
                seen.add(target.resolve())
                sub = load(target)
                stack.append(
                    (
                        sub.get("root") or {},
                        m,
                        me,
                        f"{uri}:root",
                        target.parent,
                        sub.get("schema") or {},
                    )
                )
            else:
                tile.contents.append(target)
        for k, child in enumerate(raw.get("children") or []):
            stack.append((child, m, me, f"{address}/{k}", base, schema))
    return tiles


def _expand_implicit(
    raw: dict,
    matrix: np.ndarray,
    parent: int,
    address: str,
    base: Path,
    schema: dict,
    tiles: list[Tile],
    report: VerifyReport,
) -> None:
    """Append the available tiles of an implicit tile (parents first), each with the volume
    and error its metadata declares (or its subdivision derives). The ``implicit`` check:
    subtrees parse, and every tile's derived (halved) error is at least its declared one, so
    clients that ignore tile metadata refine at least as soon."""
    content = report.checks["content"]
    check = report.check(
        "implicit", "subtrees parse; each tile's halved error holds its declared one"
    )
    try:
        found = implicit_tiles(raw, base, schema)
    except (StoreError, KeyError, ValueError, IndexError) as exc:
        check.items += 1
        check.fail(address, "readable subtrees", str(exc)[:120])
        # The tile itself stays in the walk (its volume and claim as tileset.json gives them).
        volume = raw.get("boundingVolume") or {}
        tiles.append(Tile(address, matrix, volume, float(raw.get("geometricError", 0)), parent))
        return
    index: dict[tuple[int, int, int], int] = {}
    hemisphere = _hemisphere(raw.get("boundingVolume") or {})
    for t in found:
        name = f"{address}@{t.level}/{t.x}/{t.y}"
        up = parent if t.level == 0 else index.get((t.level - 1, t.x >> 1, t.y >> 1), -2)
        check.items += 1
        if up == -2:
            check.fail(name, "its parent available", "missing")
            up = parent
        if t.error < t.declared_error * (1 - 1e-12):
            check.fail(name, f">= {t.declared_error}", t.error, t.declared_error - t.error)
        index[(t.level, t.x, t.y)] = len(tiles)
        tile = Tile(name, matrix, t.declared_volume, t.declared_error, up)
        if hemisphere is not None:
            tile.geographic = (t.level, t.x + (hemisphere << t.level), t.y)
        if t.content is not None:
            content.items += 1
            if t.content.is_file():
                tile.contents.append(t.content)
            else:
                content.fail(name, "a file", "missing")
        tiles.append(tile)


class _Frame:
    """Tileset frame (ECEF) → the terrain's coordinates."""

    def __init__(self, terrain: Any, root: Tile) -> None:
        self.crs = getattr(terrain, "crs", None) if terrain is not None else None
        if self.crs is None and terrain is not None:
            # The root's rotation is the local east-north-up frame at (lon, lat, 0).
            r = root.matrix[:3, :3]
            up = r[:, 2] / np.linalg.norm(r[:, 2])
            lam, phi = math.atan2(up[1], up[0]), math.asin(max(-1.0, min(1.0, up[2])))
            e2 = 1.0 - (_B / _A) ** 2
            n = _A / math.sqrt(1.0 - e2 * math.sin(phi) ** 2)
            self.origin = np.array(
                [
                    n * math.cos(phi) * math.cos(lam),
                    n * math.cos(phi) * math.sin(lam),
                    n * (1 - e2) * math.sin(phi),
                ]
            )
            self.rotation = r
            c = terrain.domain.center
            self.center = np.array([c[0], c[1], 0.0])

    def to_terrain(self, ecef: np.ndarray) -> np.ndarray:
        if self.crs is None:
            return (ecef - self.origin) @ self.rotation + self.center
        # The inverse of the writer's steps: ECEF → lon, lat, height → the CRS, in 3-D (a datum
        # shift such as NAD27's may move x, y with the height).
        lon, lat, h = _transformer("EPSG:4978", "EPSG:4979").transform(
            ecef[:, 0], ecef[:, 1], ecef[:, 2]
        )
        back = _transformer("EPSG:4979", self.crs)
        x0 = np.column_stack(back.transform(lon, lat, h))
        # pyproj's inverse of some datum shifts is not exact (NAD27: 0.26 mm off, 0.5 mm of
        # height on a steep tile): one step x0 − (back(forward(x0)) − x0) takes the writer's
        # forward transform exactly back (1e-9 m).
        again = np.column_stack(
            back.transform(*_transformer(self.crs, "EPSG:4979").transform(*x0.T))
        )
        return 2.0 * x0 - again


@functools.lru_cache(maxsize=8)
def _transformer(source: str, target: str):
    from pyproj import Transformer

    return Transformer.from_crs(source, target, always_xy=True)


def _geodetic(ecef: np.ndarray) -> np.ndarray:
    """(n, 3) lon, lat radians and ellipsoidal height of ECEF points (pyproj)."""
    lon, lat, h = _transformer("EPSG:4978", "EPSG:4979").transform(
        ecef[:, 0], ecef[:, 1], ecef[:, 2]
    )
    return np.column_stack([np.radians(lon), np.radians(lat), h])


def _tile_mesh(tile: Tile) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ECEF (n, 3), triangles (m, 3), skirt flags (m,)) of a tile's GLB contents."""
    pts, tris, skirts, count = [], [], [], 0
    for path in tile.contents:
        pos, tri, skirt, _ = read_glb_parts(path.read_bytes(), str(path))
        pts.append(z_up(pos, tile.matrix))
        tris.append(tri + count)
        skirts.append(skirt)
        count += len(pos)
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=bool)
    return np.concatenate(pts), np.concatenate(tris), np.concatenate(skirts)


def _hemisphere(volume: dict[str, Any]) -> int | None:
    """0 or 1 for a region of the western or eastern hemisphere (level 0 of Cesium's
    geographic tiling), else None."""
    region = volume.get("region")
    if region is None:
        return None
    for k, west in enumerate((-math.pi, 0.0)):
        if np.allclose(region[:4], [west, -math.pi / 2, west + math.pi, math.pi / 2], atol=1e-12):
            return k
    return None


def verify_3dtiles(output: Path, terrain: Any, report: VerifyReport) -> None:
    path = output / "tileset.json" if output.is_dir() else output
    tiles = walk(path, report)
    report.figures["tiles"] = len(tiles)
    volumes = report.check("volumes", "each volume holds its content and its children's")
    _nested(tiles, volumes)
    _monotone(tiles, report)
    errors: _Errors | _GeographicErrors | None = None
    if terrain is not None:
        geographic = [t for t in tiles if t.contents]
        if geographic and all(t.geographic is not None for t in geographic):
            samples = (json.loads(path.read_text()).get("extras") or {}).get("samples", 152)
            errors = _GeographicErrors(terrain, report, int(samples))
        else:
            errors = _Errors(terrain, tiles[0], report)
    # Tiles a batch at a time: each GLB parsed once, memory bounded by a batch.
    meshes = [k for k, t in enumerate(tiles) if t.contents]
    for a in range(0, len(meshes), _BATCH):
        batch: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for k in meshes[a : a + _BATCH]:
            mesh = _read_tile(tiles[k], report)
            if mesh is not None:
                volumes.items += 1
                _content_inside(tiles[k], mesh[0], volumes)
                batch[k] = mesh
        if isinstance(errors, _GeographicErrors):
            errors.measure_tiles(tiles, batch)
        elif errors is not None:
            errors.measure(tiles, batch)
    if errors is not None:
        errors.finish()


def _read_tile(tile: Tile, report: VerifyReport) -> tuple[np.ndarray, np.ndarray] | None:
    """(ECEF vertices, surface triangles) of a tile's contents (skirt primitives left out:
    their walls claim nothing); None (a failure) when they do not parse or hold no
    triangle."""
    content = report.checks["content"]
    try:
        ecef, tris, skirt = _tile_mesh(tile)
        tris = tris[~skirt]
    except StoreError as exc:
        content.fail(tile.address, "GLB", str(exc)[:120])
        return None
    if len(tris) == 0:
        content.fail(tile.address, "triangles", 0)
        return None
    return ecef, tris


def _content_inside(tile: Tile, ecef: np.ndarray, check) -> None:
    v = tile.volume
    if "region" in v:
        w, s, e, n, lo, hi = v["region"]
        g = _geodetic(ecef)
        out = (g[:, 0] < w - _RAD) | (g[:, 0] > e + _RAD) | (g[:, 1] < s - _RAD)
        out |= (g[:, 1] > n + _RAD) | (g[:, 2] < lo - _METRES) | (g[:, 2] > hi + _METRES)
    elif "box" in v:
        q = _box_coords(v["box"], tile.matrix, ecef)
        out = (np.abs(q) > 1 + _BOX).any(axis=1)
    else:
        return
    if out.any():
        check.fail(tile.address, "its content inside", f"{int(out.sum())} vertices outside")


def _box_coords(box: list[float], matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n, 3) coordinates of points (tileset frame) in a box's half-axes (|q| <= 1 inside)."""
    c = np.array(box[:3], dtype=np.float64)
    axes = np.array(box[3:12], dtype=np.float64).reshape(3, 3).T
    local = (points - matrix[:3, 3]) @ np.linalg.inv(matrix[:3, :3]).T - c
    return local @ np.linalg.pinv(axes).T


def _box_corners(box: list[float], matrix: np.ndarray) -> np.ndarray:
    c = np.array(box[:3], dtype=np.float64)
    axes = np.array(box[3:12], dtype=np.float64).reshape(3, 3)
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    local = c + signs @ axes
    return local @ matrix[:3, :3].T + matrix[:3, 3]


def _nested(tiles: list[Tile], check) -> None:
    for tile in tiles:
        if tile.parent < 0:
            continue
        p = tiles[tile.parent]
        check.items += 1
        a, b = tile.volume, p.volume
        if "region" in a and "region" in b:
            w, s, e, n, lo, hi = a["region"]
            W, S, E, N, LO, HI = b["region"]
            inside = w >= W - _RAD and s >= S - _RAD and e <= E + _RAD and n <= N + _RAD
            inside = inside and lo >= LO - _METRES and hi <= HI + _METRES
        elif "box" in a and "box" in b:
            q = _box_coords(b["box"], p.matrix, _box_corners(a["box"], tile.matrix))
            inside = bool((np.abs(q) <= 1 + _BOX).all())
        else:
            continue
        if not inside:
            check.fail(tile.address, f"inside {p.address}'s volume", "reaches out of it")


def _monotone(tiles: list[Tile], report: VerifyReport) -> None:
    check = report.check("monotone", "no child's geometricError exceeds its parent's")
    for tile in tiles:
        if tile.parent >= 0:
            check.items += 1
            parent = tiles[tile.parent].error
            if tile.error > parent * (1 + 1e-12):
                check.fail(tile.address, f"<= {parent}", tile.error, tile.error - parent)


class _Errors:
    """Each tile's true error against its geometricError, batch by batch."""

    def __init__(self, terrain: Any, root: Tile, report: VerifyReport) -> None:
        self.terrain = terrain
        self.frame = _Frame(terrain, root)
        self.source = measure_for(terrain)
        self.check = report.check(
            "errors", "each tile's geometricError is its true max error or more"
        )
        self.report = report
        self.slack = 1e-9 * (1.0 + max(abs(v) for v in terrain.z_range))
        self.worst = 0.0
        self.points = 0

    def measure(self, tiles: list[Tile], batch: dict[int, tuple[np.ndarray, np.ndarray]]):
        if not batch:
            return
        keys = sorted(batch)
        soups, rects = [], np.empty((len(keys), 4))
        for j, k in enumerate(keys):
            ecef, tris = batch[k]
            verts = self.frame.to_terrain(ecef)
            soups.append(verts[tris].reshape(-1, 9))
            lo, hi = verts.min(axis=0), verts.max(axis=0)
            rects[j] = (lo[0], lo[1], hi[0], hi[1])
        which = np.repeat(np.arange(len(keys)), [len(t) for t in soups])
        soup = np.concatenate(soups)
        # Each tile is measured with the slack of its own float32 rounding (its extent): one
        # slack for the whole batch (the terrain's extent on a point cloud, 3e-3 ft) let the
        # plane of a steep sliver near a border vertex count 3e-3 outside itself (13.4 ft off
        # at a vertex of a 1-ft tile of autzen_trim.laz). Tiles of like extent go together.
        # (A raster's slack is in cells, the same for every tile: one group.)
        extents = np.maximum(rects[:, 2] - rects[:, 0], rects[:, 3] - rects[:, 1])
        tols = np.array([measure_tolerance(self.source, float(e)) for e in extents])
        bucket = np.ceil(np.log2(np.maximum(tols, 1e-300))).astype(np.int64)
        measured = np.zeros(len(keys))
        for b in np.unique(bucket).tolist():
            group = np.flatnonzero(bucket == b)
            extent = float(extents[group].max())

            def triangles_of(owners: np.ndarray, group=group) -> tuple[np.ndarray, np.ndarray]:
                keep = np.isin(which, group[owners])
                return soup[keep], np.searchsorted(group, which[keep])

            found = self.source.errors(
                rects[group], triangles_of, measure_tolerance(self.source, extent)
            )
            measured[group] = np.maximum(found.err, 0.0)
            self.points += int(found.measured.sum())
        claimed = np.array([tiles[k].error for k in keys])
        for j in np.flatnonzero(~claims_hold(measured, claimed, self.slack)).tolist():
            tile = tiles[keys[j]]
            name = tile.contents[0].name
            self.check.fail(
                f"{tile.address} ({name})", claimed[j], measured[j], measured[j] - claimed[j]
            )
        self.check.items += len(keys)
        self.worst = max(self.worst, float(measured.max(initial=0.0)))

    def finish(self) -> None:
        self.report.figures["worst_tile_error"] = self.worst
        self.report.figures["data_points_measured"] = self.points


class _GeographicErrors:
    """3D Tiles terrain (Cesium's geographic tiling): each tile's TIN taken to longitude,
    latitude and ellipsoidal height (pyproj) and measured linear in them against its declared
    error, as quantized-mesh tiles are (``LonLatMeasure``: the data points within 1.5 sample
    spacings of the DEM's edge are left out)."""

    def __init__(self, terrain: Any, report: VerifyReport, samples: int) -> None:
        self.measure = LonLatMeasure(terrain, report)
        self.samples = samples

    def measure_tiles(self, tiles: list[Tile], batch: dict[int, tuple[np.ndarray, np.ndarray]]):
        for k, (ecef, tris) in sorted(batch.items()):
            level, x, y = tiles[k].geographic  # type: ignore[misc]
            self.measure.spacing[level] = 180.0 / 2**level / (self.samples - 1)
            g = _geodetic(ecef)
            verts = np.column_stack([np.degrees(g[:, 0]), np.degrees(g[:, 1]), g[:, 2]])
            address = f"{level}/{x}/{y}"
            self.measure.mesh(address, level, tile_bounds(level, x, y), verts, tris, tiles[k].error)

    def finish(self) -> None:
        self.measure.finish()
