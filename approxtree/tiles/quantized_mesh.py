"""Cesium terrain (quantized-mesh-1.0) from a height grid: ``layer.json`` + ``z/x/y.terrain``.

Each tile of Cesium's geographic tiling (``tiles.geographic``) is its own TIN (``tile_tin``):
a greedy insertion over the terrain's data points in the tile and the tile's regular lon/lat
sample lattice (``sampling``; ``samples − 1`` divides 32767, so every sample sits on an exact
quantized (u, v)), until the mesh is within the level's geometric error (CesiumJS's
levelMaximumGeometricError) of every data point. The error is measured on the tile as
CesiumJS decodes it, at every data point's true position, before it is written: it is
``TileResult.max_error`` and the tile's metadata ``geometricError``.

Tiles are gzip-compressed (serve them with ``Content-Encoding: gzip``), carry oct-encoded
vertex normals, a metadata extension with the availability of their children, and an
optional water mask. The whole folder is written beside the target and renamed over it.
"""

from __future__ import annotations

import gzip
import itertools
import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from approxtree.errors import EmptyTerrainError, InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.tiles.encoding import QMAX, encode_tile
from approxtree.tiles.geographic import (
    MAX_LEVEL,
    deepest_level,
    level_error,
    tile_bounds,
    tiles_touching,
)
from approxtree.tiles.parallel import check_workers, run_batches
from approxtree.tiles.sampling import NO_DATA, TileSampler, check_has_data
from approxtree.tiles.tile_tin import EdgeHeights, tile_mesh
from approxtree.tiles.water_mask import WaterMask

#: Samples along a tile side: (samples − 1) divides 32767 = 7 · 31 · 151, so every sample has
#: an exact quantized coordinate.
SAMPLE_CHOICES = (32, 152, 218)
DEFAULT_SAMPLES = 152

#: The deepest level's error (m) by default: the vertical resolution of integer-metre DEMs
#: (SRTM); a tree store's own ε replaces it on the command line.
DEFAULT_LEAF_ERROR = 1.0


@dataclass
class TileResult:
    """What was written for one tile: its address, mesh size, bytes on disk (gzip), the
    decoded tile's true max error over the terrain's data points in it, the error it had to
    meet (the level's, or the leaf error on the deepest level), the lattice samples that had a
    height, the data points measured, and the insertion rounds run."""

    level: int
    x: int
    y: int
    vertices: int
    triangles: int
    bytes: int
    max_error: float
    level_error: float
    valid_samples: int
    data_points: int
    rounds: int


#: layer.json's metadataAvailability (CesiumJS World Terrain's convention): tiles of levels
#: 0, 10, 20... carry the availability of the next 10 levels of their subtree, which CesiumJS
#: then takes instead of layer.json's list; every other tile carries its children's.
METADATA_LEVELS = 10


def subtree_availability(
    level: int, x: int, y: int, plan: dict[int, np.ndarray], maxzoom: int
) -> list[list[dict[str, int]]]:
    """The metadata extension's ``available``: one list of ranges per level below the tile
    (METADATA_LEVELS of them on levels that are multiples of it, else 1), clipped at maxzoom;
    plan: (k, 2) int64 x, y of the tiles written at each level."""
    depth = METADATA_LEVELS if level % METADATA_LEVELS == 0 else 1
    out = []
    for d in range(1, min(depth, maxzoom - level) + 1):
        xy = plan.get(level + d, np.empty((0, 2), dtype=np.int64))
        span = 2**d
        inside = (xy[:, 0] // span == x) & (xy[:, 1] // span == y)
        out.append(availability(map(tuple, xy[inside].tolist())))
    return out


def availability(tiles: Iterable[tuple[int, int]]) -> list[dict[str, int]]:
    """layer.json ranges of one level: runs of x per row, rows with equal runs merged."""
    rows: dict[int, list[int]] = {}
    for x, y in tiles:
        rows.setdefault(y, []).append(x)
    runs_of: dict[int, tuple[tuple[int, int], ...]] = {}
    for y, row in rows.items():
        xs = sorted(row)
        runs: list[tuple[int, int]] = []
        start = xs[0]
        for a, b in itertools.pairwise(xs):
            if b != a + 1:
                runs.append((start, a))
                start = b
        runs.append((start, xs[-1]))
        runs_of[y] = tuple(runs)
    out = []
    ys = sorted(runs_of)
    i = 0
    while i < len(ys):
        j = i
        while j + 1 < len(ys) and ys[j + 1] == ys[j] + 1 and runs_of[ys[j + 1]] == runs_of[ys[i]]:
            j += 1
        for x0, x1 in runs_of[ys[i]]:
            out.append({"startX": x0, "startY": ys[i], "endX": x1, "endY": ys[j]})
        i = j + 1
    return out


@dataclass
class TileJob:
    """Everything a worker needs for a batch of tiles (pickled once per batch)."""

    sampler: TileSampler
    water: WaterMask | None
    samples: int
    folder: str
    plan: dict[int, np.ndarray]
    maxzoom: int
    leaf_error: float = math.inf

    def edge_heights(self, bounds: tuple[float, float, float, float]) -> EdgeHeights:
        """The lattice's heights at quantized positions (u, v) on the edges of the tile
        ``bounds``: the edge's own longitude or latitude, exactly, so that neighbours agree."""
        west, south, east, north = bounds
        spacing = (east - west) / (self.samples - 1)

        def heights(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            lon = west + (east - west) * u / QMAX
            lat = south + (north - south) * v / QMAX
            lon = np.where(u == 0, west, np.where(u == QMAX, east, lon))
            lat = np.where(v == 0, south, np.where(v == QMAX, north, lat))
            return self.sampler.heights_at(lon, lat, spacing)[0]

        return heights

    def tile_error(self, level: int) -> float:
        """The error a tile of ``level`` must meet: CesiumJS's level error, and on the
        deepest level (which CesiumJS keeps showing as the camera comes closer) at most the
        leaf error, so the DEM's detail is shown there."""
        err = level_error(level)
        return min(err, self.leaf_error) if level == self.maxzoom else err


def make_tile(job: TileJob, level: int, x: int, y: int) -> tuple[bytes, TileResult]:
    """The gzip-compressed bytes of tile (level, x, y) and its figures."""
    bounds = tile_bounds(level, x, y)
    h, measured = job.sampler.lattice(bounds, job.samples)
    err = job.tile_error(level)
    # Data points within 1.5 cells of an edge get a point beside them on it.
    reach = 1.5 * job.sampler.cell_degrees / (bounds[2] - bounds[0]) * QMAX
    points = job.sampler.points(bounds)
    mesh = tile_mesh(h, measured, points, job.edge_heights(bounds), reach, err)
    water = job.water.tile_mask(bounds) if job.water is not None else None
    meta = {
        "available": subtree_availability(level, x, y, job.plan, job.maxzoom),
        "geometricError": mesh.error,
    }
    raw = encode_tile(
        mesh.u,
        mesh.v,
        mesh.hq,
        mesh.decoded,
        mesh.triangles,
        bounds,
        water_mask=water,
        metadata=meta,
    )
    data = gzip.compress(raw, compresslevel=6, mtime=0)
    result = TileResult(
        level,
        x,
        y,
        len(mesh.u),
        len(mesh.triangles),
        len(data),
        mesh.error,
        err,
        int(np.count_nonzero(measured)),
        mesh.data_points,
        mesh.rounds,
    )
    return data, result


def _write_batch(job: TileJob, addresses: Sequence[tuple[int, int, int]]) -> list[TileResult]:
    """Make and write a batch of tiles into ``job.folder``; their figures."""
    out = []
    for level, x, y in addresses:
        data, result = make_tile(job, level, x, y)
        path = Path(job.folder, str(level), str(x), f"{y}.terrain")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        out.append(result)
    return out


def plan_tiles(
    sampler: TileSampler, minzoom: int, maxzoom: int
) -> dict[int, list[tuple[int, int]]]:
    """(x, y) of the tiles to write at each level: those meeting the terrain's footprint,
    and at level 0 both tiles (CesiumJS asks for every root tile)."""
    plan = {}
    for level in range(minzoom, maxzoom + 1):
        tiles = tiles_touching(sampler.footprint, level)
        if level == 0:
            tiles = [(0, 0), (1, 0)]
        plan[level] = tiles
    return plan


def layer_json(
    sampler: TileSampler,
    plan: dict[int, list[tuple[int, int]]],
    water: bool,
    name: str,
) -> dict:
    """The tileset's layer.json (TileJSON 2.1.0 as CesiumTerrainProvider reads it)."""
    extensions = ["octvertexnormals", "metadata"]
    if water:
        extensions.insert(1, "watermask")
    levels = sorted(plan)
    return {
        "tilejson": "2.1.0",
        "name": name,
        "description": "Greedy-insertion TINs made by approxtree, each within CesiumJS's "
        "geometric error of its level.",
        "version": "1.0.0",
        "format": "quantized-mesh-1.0",
        "attribution": "",
        "scheme": "tms",
        "tiles": ["{z}/{x}/{y}.terrain"],
        "projection": "EPSG:4326",
        "bounds": [round(v, 9) for v in sampler.footprint.bounds],
        "minzoom": levels[0],
        "maxzoom": levels[-1],
        "metadataAvailability": METADATA_LEVELS,
        "available": [availability(plan.get(level, [])) for level in range(levels[-1] + 1)],
        "extensions": extensions,
    }


def check_output(out: str | os.PathLike) -> None:
    """StoreError unless ``out`` is new, empty, or a terrain tileset approxtree wrote holding
    nothing else (it is replaced whole), unless an ``overwriting`` block allows it."""
    from approxtree.io.output_path import check_output_folder
    from approxtree.io.own_output import check_replaceable

    check_output_folder(out, "terrain tileset folder")
    check_replaceable(out, "terrain tileset")


def terrain_job(
    terrain: Grid,
    samples: int = DEFAULT_SAMPLES,
    minzoom: int = 0,
    maxzoom: int | None = None,
    max_error: float | None = None,
    water_mask: str | os.PathLike | None = None,
    leaf_error: float = DEFAULT_LEAF_ERROR,
) -> tuple[TileJob, dict[int, list[tuple[int, int]]]]:
    """The job that makes each tile (``make_tile``) of ``write_quantized_mesh``'s tileset with
    these arguments (checked, its levels chosen), and the tiles of each level (``plan_tiles``).
    The server (tiles/serve) makes its tiles with it, byte for byte as written."""
    if samples not in SAMPLE_CHOICES:
        raise InvalidParameterError(
            f"samples must be one of {SAMPLE_CHOICES} (samples − 1 must divide 32767), "
            f"got {samples}."
        )
    if not (isinstance(leaf_error, (int, float)) and leaf_error > 0 and not math.isnan(leaf_error)):
        raise InvalidParameterError(
            f"leaf_error must be a positive number of metres (or inf), got {leaf_error!r}."
        )
    sampler = TileSampler(terrain)
    check_has_data(sampler)
    if max_error is not None:
        if maxzoom is not None:
            raise InvalidParameterError(
                "Give --maxzoom or --max-error, not both: --max-error chooses the deepest level."
            )
        if not (math.isfinite(max_error) and max_error >= level_error(MAX_LEVEL)):
            raise InvalidParameterError(
                f"max_error must be at least {level_error(MAX_LEVEL):.4g} m (the error of "
                f"level {MAX_LEVEL}), got {max_error}."
            )
    if maxzoom is None:
        maxzoom = max(deepest_level(sampler.cell_degrees, samples), minzoom)
        # Deeper still until the level's error reaches the wanted one.
        while max_error is not None and level_error(maxzoom) > max_error:
            maxzoom += 1
    if not (0 <= minzoom <= maxzoom <= 22):
        raise InvalidParameterError(
            f"Levels must satisfy 0 <= minzoom <= maxzoom <= 22, got {minzoom}..{maxzoom}."
        )
    water = WaterMask.open(water_mask) if water_mask is not None else None
    plan = plan_tiles(sampler, minzoom, maxzoom)
    arrays = {level: np.array(t, dtype=np.int64).reshape(-1, 2) for level, t in plan.items()}
    return TileJob(sampler, water, samples, "", arrays, maxzoom, float(leaf_error)), plan


def write_quantized_mesh(
    terrain: Grid,
    out: str | os.PathLike,
    *,
    samples: int = DEFAULT_SAMPLES,
    minzoom: int = 0,
    maxzoom: int | None = None,
    max_error: float | None = None,
    workers: int = 1,
    water_mask: str | os.PathLike | None = None,
    leaf_error: float = DEFAULT_LEAF_ERROR,
    scheduler: str | None = None,
) -> dict:
    """Write the Cesium terrain tileset of ``terrain`` into the folder ``out`` (atomically).

    samples: samples along a tile side (one of SAMPLE_CHOICES); maxzoom: deepest level, by
    default the first whose sample spacing reaches the terrain's cell, or deeper until the
    level's error is <= ``max_error`` metres when that is given; leaf_error: the deepest
    level's tiles are within min(its level error, leaf_error) metres (``math.inf``: the level
    error only); workers > 1: tiles are made as dask tasks on a LocalCluster of that many
    processes, or on the dask cluster at ``scheduler`` (which must see ``out``). Returns the
    figures (tiles, bytes, levels, worst error ratio, leaf error and the deepest level's
    measured worst, per-level counts).
    """
    from approxtree.io.atomic import atomic_directory

    check_workers(workers, scheduler)
    job, plan = terrain_job(terrain, samples, minzoom, maxzoom, max_error, water_mask, leaf_error)
    minzoom, maxzoom = min(plan), max(plan)
    out = Path(out)
    check_output(out)
    addresses = [(level, x, y) for level, tiles in plan.items() for x, y in tiles]
    results: list[TileResult] = []
    with atomic_directory(out) as tmp:
        job.folder = str(tmp)
        # In this process, or batches of tiles as dask tasks (the job sent once per worker).
        results = run_batches(_write_batch, job, addresses, workers, scheduler, "tiles")
        if not any(r.valid_samples or r.data_points for r in results) and terrain.point_count == 0:
            # A windowed terrain of nodata only: scanned only now that no tile sampled a
            # height (tiles too coarse to hit the data need not mean nodata); nothing is kept.
            raise EmptyTerrainError(NO_DATA)
        layer = layer_json(job.sampler, plan, job.water is not None, out.name)
        (tmp / "layer.json").write_text(json.dumps(layer, indent=1))
    return {
        "tiles": len(results),
        "levels": f"{minzoom}..{maxzoom}",
        "samples": samples,
        "bytes": sum(r.bytes for r in results),
        "vertices": sum(r.vertices for r in results),
        "worst_error_ratio": max(r.max_error / r.level_error for r in results),
        "leaf_error": float(leaf_error),
        "leaf_max_error": max((r.max_error for r in results if r.level == maxzoom), default=0.0),
        "tiles_per_level": {str(level): len(t) for level, t in plan.items()},
        "results": [asdict(r) for r in results],
    }
