"""Cesium terrain as 3D Tiles: the tileset CesiumJS's Cesium3DTilesTerrainProvider reads.

The tiles are those of the quantized-mesh writer (tiles/quantized_mesh.py): Cesium's
geographic tiling, each tile its own greedy TIN within its level's error at the terrain's
data points (``tile_mesh``), carried as GLB instead of quantized-mesh:

- tileset.json: a root over the globe with two children, the western and the eastern
  hemisphere (level 0 of the geographic tiling), each an implicit QUADTREE (tiles/implicit.py)
  whose (level, x, y) is the geographic tile (level, x + 2^level · hemisphere, y), y from the
  south; subtrees carry tile metadata with the semantics the provider reads —
  TILE_MINIMUM_HEIGHT / TILE_MAXIMUM_HEIGHT (over the tile and its descendants, so parents'
  regions hold their children's), TILE_BOUNDING_SPHERE, TILE_HORIZON_OCCLUSION_POINT — and
  TILE_GEOMETRIC_ERROR: the tile's true error plus what its lattice adds (the implicit error,
  CesiumJS's level error 77 067 m / 2^level, bounds it).
- ``{hemisphere}/tiles/{level}/{x}/{y}.glb``: the TIN without skirts (the provider hangs its
  own), positions in ECEF on a lattice of the tile's east-north-up axes (tiles/lattice.py)
  stored as meshopt-compressed normalized shorts (the only compressed positions the provider
  decodes; the Khronos validator reports their node matrix, scaled by 65535 · step, as not
  decomposable to TRS: a float32 determinant test), octahedral normals, and
  CESIUM_tile_edges: the vertices on each side, which the provider needs to stitch and
  skirt the tile. The lattice is as coarse as 1 % of the level's error allows (16 bits at
  most; triangles that reach no measured data point, the 0 m cliffs beyond the DEM, do not
  count); a tile whose error plus the lattice's bound would pass its level's error is
  remeshed to a tighter error.

``approxtree verify`` recomputes each tile's error in longitude, latitude and height as it
does for quantized-mesh tiles.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import ApproxTreeError, InvalidParameterError
from approxtree.io.atomic import atomic_directory
from approxtree.io.gltf import vertex_normals
from approxtree.io.gltf_compact import MAX_BITS, compact_glb
from approxtree.io.output_path import check_output_folder
from approxtree.io.own_output import check_replaceable
from approxtree.io.quantized_mesh import tile_bounds
from approxtree.tiles.earth import geodetic_to_ecef
from approxtree.tiles.encoding import QMAX, bounding_sphere, horizon_occlusion_point
from approxtree.tiles.geographic import LEVEL_ZERO_ERROR, deepest_level, level_error
from approxtree.tiles.implicit import implicit_tiling, write_subtrees
from approxtree.tiles.lattice import Lattice, fit_lattice, geographic_factor, local_axes
from approxtree.tiles.parallel import check_workers, run_batches
from approxtree.tiles.quantized_mesh import (
    DEFAULT_LEAF_ERROR,
    DEFAULT_SAMPLES,
    SAMPLE_CHOICES,
    TileJob,
    plan_tiles,
)
from approxtree.tiles.sampling import TileSampler, check_has_data
from approxtree.tiles.tile_content import QUANTIZATION_SHARE
from approxtree.tiles.tile_tin import tile_mesh

#: Remeshing rounds a tile gets to fit its level's error with its lattice's bound.
_ROUNDS = 4
#: The metadata the provider reads, by semantic: (property name, type, array count).
_PROPERTIES = {
    "TILE_MINIMUM_HEIGHT": ("minimumHeight", "SCALAR", None),
    "TILE_MAXIMUM_HEIGHT": ("maximumHeight", "SCALAR", None),
    "TILE_BOUNDING_SPHERE": ("boundingSphere", "SCALAR", 4),
    "TILE_HORIZON_OCCLUSION_POINT": ("horizonOcclusionPoint", "VEC3", None),
    "TILE_GEOMETRIC_ERROR": ("geometricError", "SCALAR", None),
}


@dataclass
class TerrainTile:
    """What was written for one tile: its geographic address, GLB size, mesh size, its claim
    (true error + lattice bound), the error it had to meet, and the metadata of its subtree
    row (heights of its stored vertices, bounding sphere (4,), horizon occlusion point (3,))."""

    level: int
    x: int
    y: int
    bytes: int
    vertices: int
    triangles: int
    error: float
    level_error: float
    min_height: float
    max_height: float
    sphere: np.ndarray
    occlusion: np.ndarray


def _edges(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertex indices on the tile's west, south, east and north sides, sorted along them."""
    out = []
    for on, along in ((u == 0, v), (v == 0, u), (u == QMAX, v), (v == QMAX, u)):
        idx = np.flatnonzero(on)
        out.append(idx[np.argsort(along[idx], kind="stable")])
    return out[0], out[1], out[2], out[3]


def make_terrain_tile(job: TileJob, level: int, x: int, y: int) -> tuple[bytes, TerrainTile]:
    """The GLB of geographic tile (level, x, y) (TMS, y from the south) and its facts."""
    west, south, east, north = bounds = tile_bounds(level, x, y)
    h, measured = job.sampler.lattice(bounds, job.samples)
    err = job.tile_error(level)
    reach = 1.5 * job.sampler.cell_degrees / (east - west) * QMAX
    points = job.sampler.points(bounds)
    target = err
    for _ in range(_ROUNDS):
        mesh = tile_mesh(h, measured, points, job.edge_heights(bounds), reach, target)
        # Edge vertices on the tile's own longitude / latitude, exactly (as quantized-mesh).
        lon = np.where(mesh.u == QMAX, east, west + (east - west) * mesh.u / QMAX)
        lat = np.where(mesh.v == QMAX, north, south + (north - south) * mesh.v / QMAX)
        geo = np.column_stack([lon, lat, mesh.decoded])
        xyz = geodetic_to_ecef(lon, lat, mesh.decoded)
        center = (xyz.min(axis=0) + xyz.max(axis=0)) / 2
        lattice = _lattice(job, geo, xyz - center, local_axes(center, True), mesh.triangles, err)
        claim = mesh.error + lattice.bound
        if claim <= err or lattice.bound >= 0.5 * err:
            break
        # Tighter, so that the TIN's error and the lattice's bound fit together.
        target = err - 1.25 * lattice.bound
    normals = vertex_normals(xyz, mesh.triangles)
    data = compact_glb(
        lattice.q,
        lattice.step,
        lattice.bits,
        lattice.placement(center),
        lattice.local(normals),
        mesh.triangles,
        "meshopt",
        edges=_edges(mesh.u, mesh.v),
        normalized=True,
        extras={"tile": [level, x, y], "error": claim},
    )
    stored = center + lattice.positions()
    sphere_c, radius = bounding_sphere(stored)
    pad = lattice.moved + 1e-3
    facts = TerrainTile(
        level,
        x,
        y,
        len(data),
        len(mesh.u),
        len(mesh.triangles),
        claim,
        err,
        float(mesh.decoded.min()) - pad,
        float(mesh.decoded.max()) + pad,
        np.r_[sphere_c, radius],
        # Towards the tile's middle on the ellipsoid: the sphere of a level-0 tile (4 vertices
        # at the poles) is centred on the Earth's, which gives no direction.
        horizon_occlusion_point(stored, _middle(bounds)),
    )
    return data, facts


def _lattice(
    job: TileJob, geo: np.ndarray, rel: np.ndarray, axes: np.ndarray, tris: np.ndarray, err: float
) -> Lattice:
    """The tile's lattice within 1 % of its error where its triangles allow. Triangles beyond
    the terrain (sampled at 0 m outside it: cliffs at its edge) count only where they reach
    1.4 sample spacings inside it, where ``approxtree verify`` measures (it leaves out the data
    points within 1.5 spacings of the edge)."""
    budget = QUANTIZATION_SHARE * err
    lattice = fit_lattice(
        rel, axes, geographic_factor(geo, tris), budget, math.inf, MAX_BITS["meshopt"]
    )
    if lattice is not None and lattice.bound <= budget:
        return lattice
    from shapely import intersects, polygons

    spacing = (geo[:, 0].max() - geo[:, 0].min()) / (job.samples - 1)
    inner = job.sampler.footprint.buffer(-1.4 * spacing)
    inside = intersects(polygons(geo[tris][:, :, :2]), inner)
    lattice = fit_lattice(
        rel, axes, geographic_factor(geo, tris[inside]), budget, math.inf, MAX_BITS["meshopt"]
    )
    if lattice is None:
        raise ApproxTreeError(
            "A tile has a degenerate triangle (no area in longitude and latitude); check the "
            "terrain's heights for NaN or infinities."
        )
    return lattice


def _middle(bounds: tuple[float, float, float, float]) -> np.ndarray:
    """(3,) ECEF of a tile's middle (longitude, latitude) on the ellipsoid."""
    west, south, east, north = bounds
    mid = np.array([(west + east) / 2]), np.array([(south + north) / 2]), np.zeros(1)
    return geodetic_to_ecef(*mid)[0]


def glb_path(level: int, x: int, y: int) -> str:
    """Where geographic tile (level, x, y) is written, relative to tileset.json."""
    hemisphere, ix = divmod(x, 2**level)
    return f"{hemisphere}/tiles/{level}/{ix}/{y}.glb"


def _write_batch(job: TileJob, addresses: Sequence[tuple[int, int, int]]) -> list[TerrainTile]:
    """Make and write a batch of tiles into ``job.folder``; their facts."""
    out = []
    for level, x, y in addresses:
        data, facts = make_terrain_tile(job, level, x, y)
        path = Path(job.folder, glb_path(level, x, y))
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        out.append(facts)
    return out


def _schema() -> dict:
    properties = {}
    for semantic, (name, kind, count) in _PROPERTIES.items():
        prop: dict[str, Any] = {"type": kind, "componentType": "FLOAT64", "semantic": semantic}
        if count is not None:
            prop.update(array=True, count=count)
        properties[name] = prop
    return {"id": "approxtree_terrain", "classes": {"tile": {"properties": properties}}}


def _tileset(results: list[TerrainTile], maxzoom: int, samples: int) -> dict:
    """tileset.json: the globe, then one implicit tileset per hemisphere."""
    lo = min(r.min_height for r in results)
    hi = max(r.max_height for r in results)
    children = []
    for hemisphere, (w, e) in enumerate(((-math.pi, 0.0), (0.0, math.pi))):
        tiling = implicit_tiling(maxzoom + 1)
        tiling["subtrees"]["uri"] = f"{hemisphere}/{tiling['subtrees']['uri']}"
        children.append(
            {
                "boundingVolume": {"region": [w, -math.pi / 2, e, math.pi / 2, lo, hi]},
                "geometricError": LEVEL_ZERO_ERROR,
                "refine": "REPLACE",
                "content": {"uri": f"{hemisphere}/tiles/{{level}}/{{x}}/{{y}}.glb"},
                "implicitTiling": tiling,
            }
        )
    return {
        "asset": {"version": "1.1", "generator": "approxtree"},
        # Samples along a tile side: verify leaves out the data points within 1.5 sample
        # spacings of the DEM's edge (outside it the tiles are sampled at 0 m).
        "extras": {"samples": samples},
        "schema": _schema(),
        "geometricError": 2.0 * LEVEL_ZERO_ERROR,
        "root": {
            "boundingVolume": {"region": [-math.pi, -math.pi / 2, math.pi, math.pi / 2, lo, hi]},
            "geometricError": 2.0 * LEVEL_ZERO_ERROR,
            "refine": "REPLACE",
            "children": children,
        },
    }


def _write_subtrees(folder: Path, results: list[TerrainTile]) -> None:
    """Each hemisphere's subtrees, its tiles' heights and errors grown over their
    descendants' (no child claims more than its parent, as 3D Tiles wants)."""
    key = {(r.level, r.x, r.y): k for k, r in enumerate(results)}
    low = np.array([r.min_height for r in results])
    high = np.array([r.max_height for r in results])
    error = np.array([r.error for r in results])
    # Deepest first: each tile passes its heights and error up to its parent.
    for k in sorted(range(len(results)), key=lambda k: -results[k].level):
        r = results[k]
        parent = key.get((r.level - 1, r.x >> 1, r.y >> 1))
        if parent is not None:
            low[parent] = min(low[parent], low[k])
            high[parent] = max(high[parent], high[k])
            error[parent] = max(error[parent], error[k])
    for hemisphere in (0, 1):
        mine = [k for k, r in enumerate(results) if r.x >> r.level == hemisphere]
        if not mine:
            continue
        addresses = np.array(
            [
                (results[k].level, results[k].x - (hemisphere << results[k].level), results[k].y)
                for k in mine
            ],
            dtype=np.int64,
        )
        names = {semantic: name for semantic, (name, _, _) in _PROPERTIES.items()}
        table = {
            names["TILE_MINIMUM_HEIGHT"]: low[mine],
            names["TILE_MAXIMUM_HEIGHT"]: high[mine],
            names["TILE_BOUNDING_SPHERE"]: np.array([results[k].sphere for k in mine]),
            names["TILE_HORIZON_OCCLUSION_POINT"]: np.array([results[k].occlusion for k in mine]),
            names["TILE_GEOMETRIC_ERROR"]: error[mine],
        }
        write_subtrees(folder / str(hemisphere), addresses, np.ones(len(mine), bool), table)


def check_terrain_options(out: str | os.PathLike, minzoom: int, water_mask: object) -> None:
    """InvalidParameterError for options of quantized-mesh that the 3D Tiles terrain has not
    (CesiumJS starts at level 0, so every level from 0 is written; no water mask), StoreError
    for an output folder that cannot be written (checked before the terrain is read)."""
    if minzoom != 0:
        raise InvalidParameterError(
            "--minzoom does not apply to 3dtiles-terrain: Cesium3DTilesTerrainProvider starts "
            "at level 0, so every level from 0 is written. Leave it out."
        )
    if water_mask is not None:
        raise InvalidParameterError(
            "--water-mask is written into quantized-mesh tiles only; 3dtiles-terrain has no "
            "water mask. Leave it out or use --format quantized-mesh."
        )
    check_output_folder(out, "tileset folder")


def write_3dtiles_terrain(
    terrain,
    out: str | os.PathLike,
    *,
    samples: int = DEFAULT_SAMPLES,
    maxzoom: int | None = None,
    max_error: float | None = None,
    workers: int = 1,
    leaf_error: float = DEFAULT_LEAF_ERROR,
    scheduler: str | None = None,
) -> dict:
    """Write the 3D Tiles terrain of ``terrain`` (a georeferenced Grid) into the folder
    ``out`` (atomically; see the module docstring). samples, maxzoom, max_error, leaf_error,
    workers, scheduler: as ``write_quantized_mesh``'s (every level from 0 is written: the
    provider starts at level 0). Returns the figures: tiles, bytes, bytes_per_tile, levels,
    worst error over the level's, tiles per level."""
    if samples not in SAMPLE_CHOICES:
        raise InvalidParameterError(
            f"samples must be one of {SAMPLE_CHOICES} (samples − 1 must divide 32767), "
            f"got {samples}."
        )
    check_workers(workers, scheduler)
    if not (isinstance(leaf_error, (int, float)) and leaf_error > 0 and not math.isnan(leaf_error)):
        raise InvalidParameterError(
            f"leaf_error must be a positive number of metres (or inf), got {leaf_error!r}."
        )
    sampler = TileSampler(terrain)
    check_has_data(sampler)
    if max_error is not None and maxzoom is not None:
        raise InvalidParameterError(
            "Give --maxzoom or --max-error, not both: --max-error chooses the deepest level."
        )
    if maxzoom is None:
        maxzoom = deepest_level(sampler.cell_degrees, samples)
        while max_error is not None and level_error(maxzoom) > max_error and maxzoom < 22:
            maxzoom += 1
    if not 0 <= maxzoom <= 22:
        raise InvalidParameterError(f"maxzoom must be in 0..22, got {maxzoom}.")
    target = Path(out)
    check_output_folder(target, "tileset folder")
    check_replaceable(target, "3D Tiles tileset")
    plan = plan_tiles(sampler, 0, maxzoom)
    addresses = [(level, x, y) for level, tiles in plan.items() for x, y in tiles]
    arrays = {level: np.array(t, dtype=np.int64).reshape(-1, 2) for level, t in plan.items()}
    with atomic_directory(target) as tmp:
        job = TileJob(sampler, None, samples, str(tmp), arrays, maxzoom, float(leaf_error))
        results = run_batches(_write_batch, job, addresses, workers, scheduler, "tiles")
        _write_subtrees(tmp, results)
        (tmp / "tileset.json").write_text(json.dumps(_tileset(results, maxzoom, samples), indent=1))
    nbytes = sum(r.bytes for r in results)
    return {
        "out": str(target),
        "format": "3dtiles-terrain",
        "tiles": len(results),
        "levels": f"0..{maxzoom}",
        "samples": samples,
        "bytes": nbytes,
        "bytes_per_tile": nbytes / max(len(results), 1),
        "worst_error_ratio": max(r.error / r.level_error for r in results),
        "leaf_error": float(leaf_error),
        "tiles_per_level": {str(level): len(t) for level, t in plan.items()},
    }
