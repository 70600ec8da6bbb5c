"""OGC 3D Tiles 1.1 tileset of an approximation tree: tileset.json and one GLB per node.

One tile per node (refine REPLACE), so a client streams the tree's patches and refines by
screen-space error exactly as the paging renderer refines by α:

- ``geometricError`` is ε_T(N) in metres (z units) plus a bound of what the content's stored
  positions add to it (tiles/tile_content.py: float32 rounding, or the lattice of compressed
  content, at most 1 % of max(ε_T(N), ε)), made monotone bottom-up (a node claims at least
  its children's errors; the 3D Tiles spec wants a child's error no larger than its
  parent's, and claiming more only refines sooner). Nodes of infinite error (patches missing
  data points) claim relief + largest finite error + 1, so clients always refine them. The
  tileset's own geometricError is the error of drawing nothing: the terrain's extent in metres
  (at least twice the root's error and the relief), so clients draw the root whenever the
  terrain is on screen.
- Content (tiles/tile_content.py): the node's patch with its skirts, as the renderer draws it,
  relative to the tile's centre in the tileset frame, in glTF's y-up axes, with normals and,
  given a pyramid, the node's texture patch (of the detail pyramid for the nodes a
  ``DetailTextures`` gives it); ``compression`` ``meshopt`` (default: EXT_meshopt_compression
  + KHR_mesh_quantization), ``draco`` (KHR_draco_mesh_compression)
  or ``none`` (float32). Explicit tiling: ``{level}/{node}.glb``, each tile's ``transform``
  its centre relative to its parent's. Implicit tiling (``implicit``, tiles/implicit.py): the
  nodes as a QUADTREE (a child's quadrant is where its centre lies in its parent), contents
  ``tiles/{level}/{x}/{y}.glb`` carrying their centre in their node matrix, subtree files with
  each tile's exact geometricError and volume as tile metadata (TILE_GEOMETRIC_ERROR,
  TILE_BOUNDING_REGION / BOX); clients without metadata halve the root's error per level, so
  the root claims the largest 2^level × error of any tile, and derive quadrant volumes,
  which need not hold the content (CesiumJS reads the metadata, 3DTilesRendererJS 0.5.3 not).
- Frame (tiles/earth.py): terrain with a CRS goes to ECEF (pyproj); its bounding volumes are
  ``region``s (radians, ellipsoidal heights) lowered by the sagitta of the longest chord of the
  tile so the straight triangle edges stay inside. Terrain without a CRS lies in a local
  east-north-up frame at ``origin`` (the root's transform places it on the ellipsoid); its
  volumes are axis-aligned ``box``es of that frame. A tile's volume holds its content and
  its children's volumes (a client culls a subtree by its root's volume).

Tiles are independent: with ``workers`` > 1 (or a dask ``scheduler``) batches of nodes are
dask tasks (tiles/parallel.py) on a local cluster of worker threads (or the scheduler's),
each reading its nodes' patches on its own (``read_patch``: the tree is never loaded whole).
The folder is written all or nothing (``atomic_directory``).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.io.atomic import atomic_directory
from approxtree.io.gltf_compact import COMPRESSIONS, DEFAULT_COMPRESSION
from approxtree.io.output_path import check_output_folder
from approxtree.io.own_output import check_replaceable
from approxtree.textures.detail import open_drape
from approxtree.textures.embed import IMAGE_FORMATS
from approxtree.tiles.earth import EarthFrame
from approxtree.tiles.implicit import (
    implicit_tiling,
    quadtree_addresses,
    write_subtrees,
)
from approxtree.tiles.parallel import check_workers, run_batches
from approxtree.tiles.tile_content import NodeWriter, TileContent, implicit_uri, tile_uri

#: The implicit tiles' content, relative to tileset.json.
IMPLICIT_CONTENT = implicit_uri("{level}", "{x}", "{y}")  # type: ignore[arg-type]


def geometric_errors(errors: np.ndarray, parents: np.ndarray, levels: np.ndarray, relief: float):
    """(n,) float64 geometricError of each tile: ε_T(N) with inf replaced by relief + largest
    finite error + 1, then raised to its children's largest (bottom-up), so no child exceeds
    its parent."""
    e = np.asarray(errors, dtype=np.float64).copy()
    finite = np.isfinite(e)
    e[~finite] = relief + float(e[finite].max(initial=0.0)) + 1.0
    for level in range(int(levels.max(initial=0)), 0, -1):
        nodes = np.flatnonzero(levels == level)
        np.maximum.at(e, parents[nodes], e[nodes])
    return e


def _check_tree(tree: Any) -> None:
    if not hasattr(tree, "read_patch") or not hasattr(tree, "rects"):
        raise InvalidParameterError(
            f"3D Tiles are made from an approximation tree; got a {type(tree).__name__} "
            "(point quadtrees hold no patches): build the tree with approxtree build."
        )


def _check_target(out: Path) -> None:
    """The output folder must be new, empty or a tileset approxtree wrote holding nothing
    else (it is replaced whole), unless an ``overwriting`` block allows it."""
    check_output_folder(out, "tileset folder")
    check_replaceable(out, "3D Tiles tileset")


def _open_pyramid(textures: Any, terrain: Any) -> Any:
    """The TexturePyramid (or DetailTextures) of ``textures``, checked against the terrain's
    CRS, or None."""
    return None if textures is None else open_drape(textures, terrain)


def _write_nodes(writer: NodeWriter, nodes: Sequence[int]) -> list[TileContent | None]:
    """A batch of nodes' GLBs (a dask task, or the whole tree in this process)."""
    return [writer.write(int(i)) for i in nodes]


def _column_major(m: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(m, dtype=np.float64).T.ravel()]


def _translation(t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def write_3dtiles(
    tree: Any,
    out: str | os.PathLike,
    textures: Any = None,
    workers: int = 1,
    origin: tuple[float, float] = (0.0, 0.0),
    skirts: bool = True,
    image_format: str = "png",
    scheduler: str | None = None,
    compression: str = DEFAULT_COMPRESSION,
    implicit: bool = False,
) -> dict[str, Any]:
    """Write the 3D Tiles 1.1 tileset of ``tree`` into the folder ``out`` (see the module
    docstring); workers > 1: batches of tiles are dask tasks on a LocalCluster of that many
    worker threads, or on the cluster at ``scheduler`` (which must see ``out``); compression:
    one of COMPRESSIONS (tiles/tile_content.py); implicit: implicit tiling (subtree files)
    instead of an explicit tile tree. Returns figures: out, tiles, bytes, seconds,
    tiles_per_second, frame, geometric_error (the tileset's), quantization (the largest bound
    a tile's stored positions add to its claim)."""
    _check_tree(tree)
    check_workers(workers, scheduler)
    if image_format not in IMAGE_FORMATS:
        raise InvalidParameterError(
            f"Unknown texture format {image_format!r}; use one of {', '.join(IMAGE_FORMATS)}."
        )
    if compression not in COMPRESSIONS:
        raise InvalidParameterError(
            f"Unknown compression {compression!r}; use one of {', '.join(COMPRESSIONS)}."
        )
    target = Path(out)
    _check_target(target)
    terrain = tree.terrain
    pyramid = _open_pyramid(textures, terrain)
    frame = EarthFrame(terrain.crs, terrain.domain.center, origin)
    parents = np.asarray(tree.parents, dtype=np.int64)
    levels = np.asarray(tree.levels, dtype=np.int64)
    addresses = quadtree_addresses(tree.rects, parents, levels) if implicit else None
    start = time.perf_counter()
    n = len(tree.errors)
    with atomic_directory(target) as tmp:
        writer = NodeWriter(tree, frame, tmp, pyramid, image_format, skirts, compression, addresses)
        # A local cluster of worker threads: reading patches, pyproj, numpy and zlib release
        # the GIL (2 threads wrote 1.5-2.2x the tiles per second of one), and threads start at
        # once where a process takes seconds to import approxtree.
        contents = run_batches(
            _write_nodes, writer, range(n), workers, scheduler, "tiles", processes=False
        )
        errors, low, high, centers = _tile_arrays(tree, frame, contents)
        if addresses is None:
            tileset = _tileset_json(tree, frame, contents, errors, low, high, centers)
        else:
            tileset = _implicit_json(tree, frame, errors, low, high, addresses)
            has_content = np.array([c is not None for c in contents])
            table = {
                "geometricError": errors,
                "boundingVolume": _metadata_volumes(frame, low, high),
            }
            write_subtrees(tmp, addresses, has_content, table)
        (tmp / "tileset.json").write_bytes(tileset_bytes(tileset))
    seconds = time.perf_counter() - start
    written = [c for c in contents if c is not None]
    nbytes = sum(c.nbytes for c in written)
    return {
        "out": str(target),
        "format": "3dtiles",
        "compression": compression,
        "implicit": implicit,
        "tiles": len(written),
        "bytes": nbytes,
        "bytes_per_tile": nbytes / max(len(written), 1),
        "seconds": seconds,
        "tiles_per_second": len(written) / seconds if seconds > 0 else None,
        "workers": workers,
        "scheduler": scheduler,
        "frame": "ecef" if frame.georeferenced else f"enu at lon/lat {frame.origin}",
        "geometric_error": tileset["geometricError"],
        "quantization": max((c.rounding for c in written), default=0.0),
        "float32_tiles": sum(c.bits == 0 for c in written) if compression != "none" else None,
    }


def tile_maker(
    tree: Any,
    textures: Any = None,
    origin: tuple[float, float] = (0.0, 0.0),
    skirts: bool = True,
    image_format: str = "png",
    compression: str = DEFAULT_COMPRESSION,
) -> tuple[NodeWriter, EarthFrame]:
    """What ``write_3dtiles`` makes tiles with, for a caller that wants the bytes (the
    server): the node writer (its ``encode(node)``) and the frame, same arguments (explicit
    tiling)."""
    _check_tree(tree)
    if image_format not in IMAGE_FORMATS:
        raise InvalidParameterError(
            f"Unknown texture format {image_format!r}; use one of {', '.join(IMAGE_FORMATS)}."
        )
    if compression not in COMPRESSIONS:
        raise InvalidParameterError(
            f"Unknown compression {compression!r}; use one of {', '.join(COMPRESSIONS)}."
        )
    terrain = tree.terrain
    frame = EarthFrame(terrain.crs, terrain.domain.center, origin)
    pyramid = _open_pyramid(textures, terrain)
    writer = NodeWriter(tree, frame, Path(), pyramid, image_format, skirts, compression, None)
    return writer, frame


def tileset_document(tree: Any, frame: EarthFrame, contents: list[TileContent | None]) -> bytes:
    """tileset.json's bytes, as ``write_3dtiles`` writes them (explicit tiling), from every
    node's content."""
    errors, low, high, centers = _tile_arrays(tree, frame, contents)
    return tileset_bytes(_tileset_json(tree, frame, contents, errors, low, high, centers))


def tileset_bytes(tileset: dict) -> bytes:
    """The bytes of a tileset.json document (compact separators, as written)."""
    return json.dumps(tileset, separators=(",", ":")).encode()


def _tile_arrays(tree: Any, frame: EarthFrame, contents: list[TileContent | None]):
    """(errors (n,), low (n, 3), high (n, 3), centers (n, 3)) of the tiles: each tile's claim
    (``geometric_errors`` of its patch's error plus what its stored positions can add) and its
    volume's bounds (its content's, grown over its children's) and centre."""
    n = len(contents)
    parents = np.asarray(tree.parents, dtype=np.int64)
    levels = np.asarray(tree.levels, dtype=np.int64)
    relief = float(terrain_relief(tree))
    # Each tile claims its patch's error plus what its stored positions can add.
    rounding = np.zeros(n)
    for c in contents:
        if c is not None:
            rounding[c.node] = c.rounding
    errors = geometric_errors(np.asarray(tree.errors) + rounding, parents, levels, relief)
    # Content bounds, then each tile's volume grown over its children's, bottom-up.
    low = np.full((n, 3), np.inf)
    high = np.full((n, 3), -np.inf)
    centers = np.zeros((n, 3))
    for c in contents:
        if c is not None:
            low[c.node], high[c.node], centers[c.node] = c.low, c.high, c.center
    for level in range(int(levels.max(initial=0)), 0, -1):
        nodes = np.flatnonzero(levels == level)
        np.minimum.at(low, parents[nodes], low[nodes])
        np.maximum.at(high, parents[nodes], high[nodes])
    # A tile without content (no triangle) is centred on its volume; one with no triangle
    # below it either gets an empty volume at its parent's centre (parents come first in node
    # order, so theirs is settled): at the parent's corner, a box's least half size (1 mm)
    # reached out of the parent's volume (hugo_site.asc's nodata corners, found by verify).
    for i in np.flatnonzero([c is None for c in contents]):
        if not np.isfinite(low[i]).all():
            low[i] = high[i] = (low[parents[i]] + high[parents[i]]) / 2 if i else np.zeros(3)
        if not frame.georeferenced:
            centers[i] = (low[i] + high[i]) / 2
    return errors, low, high, centers


def _tileset_json(
    tree: Any,
    frame: EarthFrame,
    contents: list[TileContent | None],
    errors: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    centers: np.ndarray,
) -> dict:
    """tileset.json of the written contents (one tile per node, children in node order)."""
    n = len(contents)
    parents = np.asarray(tree.parents, dtype=np.int64)
    levels = np.asarray(tree.levels, dtype=np.int64)
    tiles: list[dict[str, Any]] = []
    for i in range(n):
        tile: dict[str, Any] = {
            "boundingVolume": _volume(frame, low[i], high[i], centers[i]),
            "geometricError": float(errors[i]),
            "refine": "REPLACE",
        }
        if i == 0:
            tile["transform"] = _column_major(frame.matrix @ _translation(centers[0]))
        else:
            tile["transform"] = _column_major(_translation(centers[i] - centers[parents[i]]))
        if contents[i] is not None:
            tile["content"] = {"uri": tile_uri(int(levels[i]), i)}
        tiles.append(tile)
    # Children in node order: child_start + range(child_count).
    for i in range(n):
        count = int(tree.child_count[i])
        if count:
            s = int(tree.child_start[i])
            tiles[i]["children"] = tiles[s : s + count]
    return {
        "asset": {"version": "1.1", "generator": "approxtree"},
        "geometricError": tileset_error(tree, frame, float(errors[0]), terrain_relief(tree)),
        "root": tiles[0],
    }


def _implicit_json(
    tree: Any,
    frame: EarthFrame,
    errors: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    addresses: np.ndarray,
) -> dict:
    """tileset.json of an implicit tileset: one root tile with ``implicitTiling``, the
    metadata schema of the subtrees' tile properties (exact errors and volumes)."""
    # Clients without tile metadata halve the root's error per level: the root claims
    # enough that every tile's halved claim still holds its own.
    root_error = float((errors * 2.0 ** addresses[:, 0].astype(np.float64)).max())
    bound = "TILE_BOUNDING_REGION" if frame.georeferenced else "TILE_BOUNDING_BOX"
    count = 6 if frame.georeferenced else 12
    schema = {
        "id": "approxtree",
        "classes": {
            "tile": {
                "properties": {
                    "geometricError": {
                        "type": "SCALAR",
                        "componentType": "FLOAT64",
                        "semantic": "TILE_GEOMETRIC_ERROR",
                    },
                    "boundingVolume": {
                        "type": "SCALAR",
                        "componentType": "FLOAT64",
                        "array": True,
                        "count": count,
                        "semantic": bound,
                    },
                }
            }
        },
    }
    root = {
        "boundingVolume": _volume(frame, low[0], high[0], np.zeros(3)),
        "geometricError": root_error,
        "refine": "REPLACE",
        "transform": _column_major(frame.matrix),
        "content": {"uri": IMPLICIT_CONTENT},
        "implicitTiling": implicit_tiling(int(addresses[:, 0].max()) + 1),
    }
    return {
        "asset": {"version": "1.1", "generator": "approxtree"},
        "schema": schema,
        "geometricError": tileset_error(tree, frame, root_error, terrain_relief(tree)),
        "root": root,
    }


def _metadata_volumes(frame: EarthFrame, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(n, 6) regions or (n, 12) boxes (in the root's frame) of the tiles, as metadata."""
    return np.array(
        [
            next(iter(_volume(frame, lo, hi, np.zeros(3)).values()))
            for lo, hi in zip(low, high, strict=True)
        ]
    )


def tileset_error(tree: Any, frame: EarthFrame, root_error: float, relief: float) -> float:
    """The tileset's own geometricError: the error of drawing nothing at all, i.e. the
    terrain's extent (the diagonal of its domain in the tileset frame, metres), and never less
    than twice the root's error or the relief. A client draws the root only while this error
    projects above its screen-space threshold, so it must be large: twice the root's error
    (25 m on the NC DEM) projects under 2 px in an overview and CesiumJS drew an empty scene."""
    x0, y0, x1, y1 = (float(v) for v in np.asarray(tree.rects, dtype=np.float64)[0])
    corners = frame.to_frame(np.array([[x0, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0], [x1, y0, 0.0]]))
    extent = max(
        float(np.linalg.norm(corners[1] - corners[0])),
        float(np.linalg.norm(corners[3] - corners[2])),
    )
    return max(extent, 2.0 * root_error, relief, 1.0)


def terrain_relief(tree: Any) -> float:
    lo, hi = tree.terrain.z_range
    return max(float(hi) - float(lo), 0.0)


def _volume(frame: EarthFrame, low: np.ndarray, high: np.ndarray, center: np.ndarray) -> dict:
    """A region (georeferenced) or a box in the tile's frame (relative to its centre)."""
    if frame.georeferenced:
        return {"region": [float(v) for v in (*low[:2], *high[:2], low[2], high[2])]}
    mid = (low + high) / 2 - center
    half = np.maximum((high - low) / 2, 1e-3)
    return {
        "box": [
            *map(float, mid),
            float(half[0]),
            0.0,
            0.0,
            0.0,
            float(half[1]),
            0.0,
            0.0,
            0.0,
            float(half[2]),
        ]
    }
