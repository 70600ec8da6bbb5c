"""OGC 3D Tiles 1.1 tileset of an approximation tree: tileset.json and one GLB per node.

One tile per node (an explicit tree, refine REPLACE), so a client streams the tree's patches
and refines by screen-space error exactly as the paging renderer refines by α:

- ``geometricError`` is ε_T(N) in metres (z units) plus a bound of what the content's float32
  positions add to it (``_rounding_bound``), made monotone bottom-up (a node claims
  at least its children's errors; the 3D Tiles spec wants a child's error no larger than its
  parent's, and claiming more only refines sooner). Nodes of infinite error (patches missing
  data points) claim relief + largest finite error + 1, so clients always refine them. The
  tileset's own geometricError is the error of drawing nothing: the terrain's extent in metres
  (at least twice the root's error and the relief), so clients draw the root whenever the
  terrain is on screen.
- Content: ``{level}/{node}.glb``, the node's patch with its skirts (patches/skirts.py, as the
  renderer draws it), positions relative to the tile's centre in the tileset frame (RTC: the
  centre is the tile's ``transform``, relative to its parent's), written in glTF's y-up axes
  (the client applies glTF's y-up → z-up rotation), with vertex normals (surface normals, a
  skirt vertex takes its top vertex's), texture coordinates and the node's texture patch
  (textures/patch.py) embedded as PNG or JPEG when a pyramid is given.
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.rect import Rect
from approxtree.io.atomic import atomic_directory
from approxtree.io.gltf import glb_bytes, surface_normals, y_up
from approxtree.io.output_path import check_output_folder
from approxtree.io.own_output import check_replaceable
from approxtree.patches.skirts import add_skirts, patches_reach_rect, skirt_base, skirt_depths
from approxtree.textures.embed import IMAGE_FORMATS, embedded_texture
from approxtree.tiles.earth import WGS84_A, WGS84_B, EarthFrame, geodetic_to_ecef
from approxtree.tiles.parallel import check_workers, run_batches

#: Smallest radius of curvature of the WGS84 ellipsoid (m), for chord sagittas.
_MIN_RADIUS = WGS84_B**2 / WGS84_A


@dataclass(frozen=True)
class TileContent:
    """What writing one node's GLB yields for tileset.json.

    center: (3,) tileset-frame centre (RTC); low, high: (3,) bounds of the content — frame
    coordinates for box volumes, (lon, lat radians, height m) for regions; nbytes: GLB size.
    """

    node: int
    center: np.ndarray
    low: np.ndarray
    high: np.ndarray
    nbytes: int
    vertices: int
    triangles: int
    #: Bound (m) of what the float32 positions' rounding adds to the patch's error.
    rounding: float = 0.0


def tile_uri(level: int, node: int) -> str:
    """Content path of a node's GLB, relative to tileset.json."""
    return f"{level}/{node}.glb"


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
    """The TexturePyramid of ``textures`` (a folder or a pyramid), checked against the terrain's
    CRS, or None."""
    if textures is None:
        return None
    from approxtree.textures.pyramid import TexturePyramid

    pyramid = textures if isinstance(textures, TexturePyramid) else TexturePyramid(textures)
    if pyramid.crs and terrain.crs:
        from pyproj import CRS

        if not CRS.from_user_input(pyramid.crs).equals(CRS.from_user_input(terrain.crs)):
            raise InvalidParameterError(
                f"The texture pyramid's CRS ({pyramid.crs}) differs from the terrain's "
                f"({terrain.crs}); bake the texture in the terrain's CRS."
            )
    return pyramid


class _TileWriter:
    """Writes one node's GLB into ``folder``; sent once to every dask worker (read-only)."""

    def __init__(
        self,
        tree: Any,
        frame: EarthFrame,
        folder: Path,
        pyramid: Any,
        image_format: str,
        skirts: bool,
    ) -> None:
        self.tree = tree
        self.frame = frame
        self.folder = folder
        self.pyramid = pyramid
        self.image_format = image_format
        self.skirts = skirts
        terrain = tree.terrain
        # Skirts exactly as the renderer hangs them (render/engine.py).
        extents = tree.bboxes[:, 5] - tree.bboxes[:, 2]
        self.node_borders = patches_reach_rect(terrain)
        rects = np.asarray(tree.rects, dtype=np.float64) if self.node_borders else None
        self.depths = skirt_depths(tree.errors, terrain.z_range, extents, rects)
        self.base = skirt_base(tree.errors, terrain.z_range, extents)
        d = terrain.domain
        self.domain = (d.xmin, d.ymin, d.xmax, d.ymax)

    def mesh(self, i: int) -> tuple[np.ndarray, np.ndarray, int]:
        """(terrain vertices (n, 3) float64, triangles (m, 3), patch triangle count) of node i
        with its skirts; the patch's own vertices come first, in the patch's order."""
        patch = self.tree.read_patch(i)
        verts = np.asarray(patch.vertices, dtype=np.float64).reshape(-1, 3)
        tris = np.asarray(patch.triangles, dtype=np.int64).reshape(-1, 3)
        surface = len(tris)
        if self.skirts and surface:
            verts, tris, _ = add_skirts(
                verts,
                tris,
                float(self.depths[i]),
                self.domain,
                self.base,
                patch.rect.as_tuple() if self.node_borders else None,
            )
        return verts, tris, surface

    def encode(self, i: int) -> tuple[bytes, TileContent] | None:
        """Node i's GLB and what tileset.json needs of it; None for a node whose patch has no
        triangle (no content). The server (tiles/serve) makes its tiles with this too."""
        verts, tris, surface = self.mesh(i)
        if surface == 0:
            return None
        geo = None
        if self.frame.georeferenced:
            geo = self.frame.to_geodetic(verts)
            points = geodetic_to_ecef(geo[:, 0], geo[:, 1], geo[:, 2])
        else:
            points = self.frame.to_frame(verts)
        # Normals of the surface only; a skirt vertex takes the normal of the top vertex it
        # hangs from (same x, y), so walls do not tilt the shading of the border.
        normals = surface_normals(points, tris, surface, verts[:, :2])
        lo, hi = points.min(axis=0), points.max(axis=0)
        center = (lo + hi) / 2
        rounding = _rounding_bound(points, center, tris[:surface], self.frame.georeferenced)
        uvs = image = None
        mime = "image/png"
        if self.pyramid is not None:
            rect = Rect(*map(float, self.tree.rects[i]))
            uvs, image, mime = embedded_texture(self.pyramid, rect, verts, self.image_format)
        data = glb_bytes(
            y_up(points - center),
            y_up(normals),
            tris,
            uvs,
            image,
            mime,
            extras={"node": int(i), "error": _json_float(self.tree.errors[i])},
        )
        if geo is not None:
            low, high = self._region(geo, points, tris)
        else:
            low, high = lo, hi
        return data, TileContent(i, center, low, high, len(data), len(verts), len(tris), rounding)

    def write(self, i: int) -> TileContent | None:
        """Write node i's GLB into the folder; None for a node without content."""
        made = self.encode(i)
        if made is None:
            return None
        data, content = made
        path = self.folder / tile_uri(int(self.tree.levels[i]), i)
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(data)
        return content

    def _region(self, geo: np.ndarray, points: np.ndarray, tris: np.ndarray):
        """(west, south, min height), (east, north, max height) in radians and metres holding
        the vertices (geo: (n, 3) lon, lat degrees, height; points: (n, 3) ECEF) and the
        straight edges between them (lowered by the longest chord's sagitta) and a float32
        rounding margin."""
        edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
        d = points[edges[:, 0]] - points[edges[:, 1]]
        chord = float(np.sqrt(np.einsum("ij,ij->i", d, d).max()))
        sag = chord * chord / (8.0 * _MIN_RADIUS) + 1e-2
        lat = np.radians(geo[:, 1])
        coslat = max(float(np.cos(np.abs(lat).max())), 1e-6)
        pad = np.array([sag / (_MIN_RADIUS * coslat), sag / _MIN_RADIUS, sag])
        low = np.array([np.radians(geo[:, 0].min()), lat.min(), geo[:, 2].min()]) - pad
        high = np.array([np.radians(geo[:, 0].max()), lat.max(), geo[:, 2].max() + 1e-2])
        high[:2] += pad[:2]
        return low, high


def _rounding_bound(
    points: np.ndarray, center: np.ndarray, surface: np.ndarray, georeferenced: bool
) -> float:
    """Largest height change the float32 positions (relative to ``center``) can cause at a
    point of the surface triangles: max displacement × (1 + steepest slope), since a plane
    moved by d at its corners moves by at most |d_z| + slope · |d_xy| (``approxtree verify``
    measured 2e-5..9e-5 m over claims of 0 on full-resolution leaves without it)."""
    rel = points - center
    moved = float(np.linalg.norm(rel.astype(np.float32).astype(np.float64) - rel, axis=1).max())
    if moved == 0.0 or not len(surface):
        return moved
    # Up: the ellipsoid's normal at the tile (ECEF), or the local frame's z.
    if georeferenced:
        up = center / np.linalg.norm(center) * np.array([1.0, 1.0, (WGS84_A / WGS84_B) ** 2])
        up /= np.linalg.norm(up)
    else:
        up = np.array([0.0, 0.0, 1.0])
    n = np.cross(rel[surface[:, 1]] - rel[surface[:, 0]], rel[surface[:, 2]] - rel[surface[:, 0]])
    vertical = np.abs(n @ up)
    flat = np.linalg.norm(n - np.outer(n @ up, up), axis=1)
    slope = float((flat / np.maximum(vertical, 1e-300)).max())
    return moved * (1.0 + slope)


def _write_nodes(writer: _TileWriter, nodes: Sequence[int]) -> list[TileContent | None]:
    """A batch of nodes' GLBs (a dask task, or the whole tree in this process)."""
    return [writer.write(int(i)) for i in nodes]


def _json_float(value: float) -> float | None:
    value = float(value)
    return value if np.isfinite(value) else None


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
) -> dict[str, Any]:
    """Write the 3D Tiles 1.1 tileset of ``tree`` into the folder ``out`` (see the module
    docstring); workers > 1: batches of tiles are dask tasks on a LocalCluster of that many
    worker threads, or on the cluster at ``scheduler`` (which must see ``out``); returns figures:
    out, tiles, bytes, seconds, tiles_per_second, frame, geometric_error (the tileset's)."""
    _check_tree(tree)
    check_workers(workers, scheduler)
    if image_format not in IMAGE_FORMATS:
        raise InvalidParameterError(
            f"Unknown texture format {image_format!r}; use one of {', '.join(IMAGE_FORMATS)}."
        )
    target = Path(out)
    _check_target(target)
    terrain = tree.terrain
    pyramid = _open_pyramid(textures, terrain)
    frame = EarthFrame(terrain.crs, terrain.domain.center, origin)
    start = time.perf_counter()
    n = len(tree.errors)
    with atomic_directory(target) as tmp:
        writer = _TileWriter(tree, frame, tmp, pyramid, image_format, skirts)
        # A local cluster of worker threads: reading patches, pyproj, numpy and zlib release
        # the GIL (2 threads wrote 1.5-2.2x the tiles per second of one), and threads start at
        # once where a process takes seconds to import approxtree.
        contents = run_batches(
            _write_nodes, writer, range(n), workers, scheduler, "tiles", processes=False
        )
        tileset = _tileset_json(tree, frame, contents)
        (tmp / "tileset.json").write_bytes(tileset_bytes(tileset))
    seconds = time.perf_counter() - start
    written = [c for c in contents if c is not None]
    nbytes = sum(c.nbytes for c in written)
    return {
        "out": str(target),
        "format": "3dtiles",
        "tiles": len(written),
        "bytes": nbytes,
        "bytes_per_tile": nbytes / max(len(written), 1),
        "seconds": seconds,
        "tiles_per_second": len(written) / seconds if seconds > 0 else None,
        "workers": workers,
        "scheduler": scheduler,
        "frame": "ecef" if frame.georeferenced else f"enu at lon/lat {frame.origin}",
        "geometric_error": tileset["geometricError"],
    }


def tile_maker(
    tree: Any,
    textures: Any = None,
    origin: tuple[float, float] = (0.0, 0.0),
    skirts: bool = True,
    image_format: str = "png",
) -> tuple[_TileWriter, EarthFrame]:
    """What ``write_3dtiles`` makes tiles with, for a caller that wants the bytes (the
    server): the tile writer (its ``encode(node)``) and the frame, same arguments."""
    _check_tree(tree)
    if image_format not in IMAGE_FORMATS:
        raise InvalidParameterError(
            f"Unknown texture format {image_format!r}; use one of {', '.join(IMAGE_FORMATS)}."
        )
    terrain = tree.terrain
    frame = EarthFrame(terrain.crs, terrain.domain.center, origin)
    pyramid = _open_pyramid(textures, terrain)
    return _TileWriter(tree, frame, Path(), pyramid, image_format, skirts), frame


def tileset_document(tree: Any, frame: EarthFrame, contents: list[TileContent | None]) -> bytes:
    """tileset.json's bytes, as ``write_3dtiles`` writes them, from every node's content."""
    return tileset_bytes(_tileset_json(tree, frame, contents))


def tileset_bytes(tileset: dict) -> bytes:
    return json.dumps(tileset, separators=(",", ":")).encode()


def _tileset_json(tree: Any, frame: EarthFrame, contents: list[TileContent | None]) -> dict:
    """tileset.json of the written contents (one tile per node, children in node order)."""
    n = len(contents)
    parents = np.asarray(tree.parents, dtype=np.int64)
    levels = np.asarray(tree.levels, dtype=np.int64)
    relief = float(terrain_relief(tree))
    # Each tile claims its patch's error plus what its float32 positions can add.
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
    for i in np.flatnonzero([c is None for c in contents]).tolist():
        if not np.isfinite(low[i]).all():
            low[i] = high[i] = (low[parents[i]] + high[parents[i]]) / 2 if i else np.zeros(3)
        if not frame.georeferenced:
            centers[i] = (low[i] + high[i]) / 2
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
        "geometricError": tileset_error(tree, frame, float(errors[0]), relief),
        "root": tiles[0],
    }


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
