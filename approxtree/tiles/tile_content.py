"""The GLB content of one node's tile: its patch with skirts, in the tileset's frame.

``NodeWriter.write(i)`` reads node i's patch (``read_patch``: the tree is never loaded whole),
hangs its skirts (patches/skirts.py, as the renderer does), takes the vertices to the tileset
frame (tiles/earth.py), computes surface normals (a skirt vertex takes its top vertex's) and,
with a texture pyramid, the node's texture patch and coordinates (a ``DetailTextures``: of
the pyramid the node uses), then stores the positions
as the compression asks:

- ``none``: float32 positions relative to the tile's centre (io/gltf.py); what they add to
  the patch's error is bounded by ``float32_bound``;
- ``draco`` / ``meshopt``: positions on a lattice of the tile's east-north-up axes
  (tiles/lattice.py, io/gltf_compact.py), the lattice as coarse as a budget allows:
  ``QUANTIZATION_SHARE`` of max(ε_T(N), the tree's ε). A tile the lattice cannot hold within
  reason (a near-vertical sliver) falls back to float32.

Content sits relative to the tile's centre: the tile's transform carries the centre
(explicit tiling), or, for implicit tiling (``addresses`` given: one transform for all
tiles), the GLB's node matrix does. Volumes are computed from the stored positions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.geometry.rect import Rect
from approxtree.io.gltf import column_bounds, glb_bytes, y_up
from approxtree.io.gltf_compact import MAX_BITS, compact_glb
from approxtree.kernels import mesh_normals, skirt_walls, tile_bounds
from approxtree.kernels._jit import readonly
from approxtree.patches.skirts import add_skirts, patches_reach_rect, skirt_base, skirt_depths
from approxtree.textures.detail import DetailTextures
from approxtree.textures.embed import embedded_texture
from approxtree.tiles.earth import WGS84_A, WGS84_B, EarthFrame, geodetic_to_ecef
from approxtree.tiles.lattice import Y_UP, Lattice, bound_factor, fit_lattice, local_axes, verticals

#: Smallest radius of curvature of the WGS84 ellipsoid (m), for chord sagittas.
MIN_RADIUS = WGS84_B**2 / WGS84_A
#: Compressed content: what the lattice may add to a tile's claim, as a share of its node's
#: error (or of the tree's ε, when larger: full-resolution leaves have an error of 0).
QUANTIZATION_SHARE = 0.01


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
    #: Bound (m) of what the stored positions (float32 or lattice) add to the patch's error.
    rounding: float = 0.0
    #: Bits per axis of the lattice positions; 0 for float32 positions.
    bits: int = 0


def tile_uri(level: int, node: int) -> str:
    """Content path of a node's GLB, relative to tileset.json (explicit tiling)."""
    return f"{level}/{node}.glb"


def implicit_uri(level: int, x: int, y: int) -> str:
    """Content path of a tile's GLB, relative to tileset.json (implicit tiling)."""
    return f"tiles/{level}/{x}/{y}.glb"


def json_float(value: float) -> float | None:
    value = float(value)
    return value if np.isfinite(value) else None


class NodeWriter:
    """Writes one node's GLB into ``folder``; sent once to every dask worker (read-only).

    addresses: (n, 3) int64 implicit (level, x, y) of every node, or None (explicit tiling).
    """

    def __init__(
        self,
        tree: Any,
        frame: EarthFrame,
        folder: Path,
        pyramid: Any,
        image_format: str,
        skirts: bool,
        compression: str = "none",
        addresses: np.ndarray | None = None,
    ) -> None:
        self.tree = tree
        self.frame = frame
        self.folder = folder
        self.pyramid = pyramid
        self.image_format = image_format
        self.skirts = skirts
        self.compression = compression
        self.addresses = addresses
        self.epsilon = float(getattr(tree, "epsilon", 0.0) or 0.0)
        terrain = tree.terrain
        # Skirts exactly as the renderer hangs them (render/engine.py).
        extents = tree.bboxes[:, 5] - tree.bboxes[:, 2]
        self.node_borders = patches_reach_rect(terrain)
        rects = np.asarray(tree.rects, dtype=np.float64) if self.node_borders else None
        self.depths = skirt_depths(tree.errors, terrain.z_range, extents, rects)
        self.base = skirt_base(tree.errors, terrain.z_range, extents)
        d = terrain.domain
        self.domain = (d.xmin, d.ymin, d.xmax, d.ymax)

    def uri(self, i: int) -> str:
        """Content path of node i, relative to tileset.json."""
        if self.addresses is None:
            return tile_uri(int(self.tree.levels[i]), i)
        return implicit_uri(*(int(v) for v in self.addresses[i]))

    def mesh(self, i: int) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
        """(terrain vertices (n, 3) float64, triangles (m, 3), patch triangle count, tops) of
        node i with its skirts: the patch's own vertices come first, in the patch's order,
        then the skirts' bottom vertices, tops (k,) int64 the patch vertex each hangs from."""
        patch = self.tree.read_patch(i)
        verts = np.asarray(patch.vertices, dtype=np.float64).reshape(-1, 3)
        tris = np.asarray(patch.triangles, dtype=np.int64).reshape(-1, 3)
        surface = len(tris)
        tops = np.zeros(0, dtype=np.int64)
        if self.skirts and surface:
            verts, tris, _ = add_skirts(
                verts,
                tris,
                float(self.depths[i]),
                self.domain,
                self.base,
                patch.rect.as_tuple() if self.node_borders else None,
            )
            tops = skirt_tops(tris[surface:])
        return verts, tris, surface, tops

    def write(self, i: int) -> TileContent | None:
        """Write node i's GLB into the folder; None for a node without content."""
        made = self.encode(i)
        if made is None:
            return None
        data, content = made
        path = self.folder / self.uri(i)
        # One write per file; its folder is made by the first tile that finds it missing.
        try:
            path.write_bytes(data)
        except FileNotFoundError:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        return content

    def encode(self, i: int) -> tuple[bytes, TileContent] | None:
        """Node i's GLB and what tileset.json needs of it; None for a node whose patch has no
        triangle (no content). The server (tiles/serve) makes its tiles with this too."""
        verts, tris, surface, tops = self.mesh(i)
        if surface == 0:
            return None
        if self.compression != "none":
            # A border vertex's two bottom vertices (one per wall) mostly coincide.
            verts, tris, tops = merge_bottoms(verts, tris, surface, tops)
        geo = None
        if self.frame.georeferenced:
            geo = self.frame.to_geodetic(verts)
            points = geodetic_to_ecef(geo[:, 0], geo[:, 1], geo[:, 2])
        else:
            points = self.frame.to_frame(verts)
        # Normals of the surface only; a skirt vertex takes the normal of the top vertex it
        # hangs from, so walls do not tilt the shading of the border.
        faces, normals = mesh_normals.surface_normals(
            readonly(points), readonly(tris, np.int64), surface, readonly(tops, np.int64)
        )
        low, high = column_bounds(points)
        center = (low + high) / 2
        uvs = image = None
        mime = "image/png"
        if self.pyramid is not None:
            rect = Rect(*map(float, self.tree.rects[i]))
            # A detail pyramid textures the nodes at or below its level inside its footprint.
            pyramid = self.pyramid
            if isinstance(pyramid, DetailTextures):
                pyramid = pyramid.pyramid_for(int(self.tree.levels[i]), rect)
            uvs, image, mime = embedded_texture(pyramid, rect, verts, self.image_format)
        extras: dict[str, Any] = {"node": int(i), "error": json_float(self.tree.errors[i])}
        # Implicit tiles share one transform: their content carries its centre itself.
        offset = None if self.addresses is None else center
        lattice = self._lattice(i, points, center, faces, tris[:surface], geo)
        if lattice is None:
            rounding = float32_bound(points, center, faces, self.frame.georeferenced)
            matrix = None
            if offset is not None:
                m = np.eye(4)
                m[:3, 3] = Y_UP @ offset
                matrix = [float(v) for v in m.T.ravel()]
            data = glb_bytes(
                y_up(points - center), y_up(normals), tris, uvs, image, mime, matrix, extras
            )
            stored, moved, bits = points, 0.0, 0
        else:
            extras["quantization"] = {"bits": lattice.bits, "step": lattice.step}
            data = compact_glb(
                lattice.q,
                lattice.step,
                lattice.bits,
                lattice.placement(offset),
                lattice.local(normals),
                tris,
                self.compression,
                skirt_from=surface,
                uvs=uvs,
                image=image,
                mime=mime,
                extras=extras,
            )
            rounding = lattice.bound
            stored, moved, bits = center + lattice.positions(), lattice.moved, lattice.bits
        if geo is not None:
            low, high = region(geo, stored, tris[:surface], moved)
        else:
            low, high = column_bounds(stored)
        content = TileContent(
            i, center, low, high, len(data), len(verts), len(tris), rounding, bits
        )
        return data, content

    def _lattice(
        self,
        i: int,
        points: np.ndarray,
        center: np.ndarray,
        faces: np.ndarray,
        surface: np.ndarray,
        geo: np.ndarray | None,
    ) -> Lattice | None:
        """Node i's lattice (positions ``points`` (n, 3) in the tileset frame, the tile's
        ``center`` (3,), surface triangles (m, 3) of normals ``faces``, lon/lat/heights
        ``geo`` or None), or None: float32 positions (``compression`` none, or a tile the
        lattice cannot hold within reason)."""
        if self.compression == "none":
            return None
        axes = local_axes(center, self.frame.georeferenced)
        error = float(self.tree.errors[i])
        scale = max(error if np.isfinite(error) else 0.0, self.epsilon)
        normals = None if geo is None else verticals(geo)
        return fit_lattice(
            points - center,
            axes,
            bound_factor(faces, surface, axes[:, 2], normals),
            QUANTIZATION_SHARE * scale,
            scale,
            MAX_BITS[self.compression],
        )


def skirt_tops(walls: np.ndarray) -> np.ndarray:
    """(2k,) int64: the top vertex of each bottom vertex of ``add_skirts``' walls (2k, 3): its
    wall quads are (a', b', b) then (a', b, a), k of each, with the bottoms a' and b' numbered
    in that order after the patch's vertices."""
    k = len(walls) // 2
    return np.concatenate([walls[k:, 2], walls[:k, 2]]).astype(np.int64)


def merge_bottoms(
    verts: np.ndarray, tris: np.ndarray, surface: int, tops: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh with coincident skirt bottoms (same top vertex, same height) made one vertex:
    (vertices, triangles, tops)."""
    if not len(tops):
        return verts, tris, tops
    # A bottom equal to one before it (same top vertex, same height) joins that one.
    return skirt_walls.merge_mesh(
        readonly(verts, np.float64), readonly(tris, np.int64), readonly(tops, np.int64)
    )


def region(geo: np.ndarray, points: np.ndarray, surface: np.ndarray, moved: float = 0.0):
    """(west, south, min height), (east, north, max height) in radians and metres holding
    the vertices (geo: (n, 3) lon, lat degrees, height; points: (n, 3) ECEF) and the
    straight edges between them (lowered by the sagitta of the longest chord of the surface
    triangles (m, 3): a skirt's edges span no more), a float32 rounding margin and ``moved``
    metres (how far stored positions lie from ``geo``'s)."""
    low, high, chord, extreme = tile_bounds.region_extent(
        readonly(geo, np.float64),
        readonly(points, np.float64),
        readonly(np.asarray(surface).reshape(-1, 3), np.int64),
    )
    sag = chord * chord / (8.0 * MIN_RADIUS) + 1e-2 + moved
    coslat = max(float(np.cos(np.radians(extreme))), 1e-6)
    pad = np.array([sag / (MIN_RADIUS * coslat), sag / MIN_RADIUS, sag])
    low[:2] = np.radians(low[:2])
    high[:2] = np.radians(high[:2])
    low -= pad
    high[2] = high[2] + 1e-2 + moved
    high[:2] += pad[:2]
    return low, high


def float32_bound(
    points: np.ndarray, center: np.ndarray, faces: np.ndarray, georeferenced: bool
) -> float:
    """Largest height change the float32 positions (relative to ``center``) can cause at a
    point of the surface triangles (normals ``faces`` (m, 3)): max displacement × (1 +
    steepest slope), since a plane moved by d at its corners moves by at most |d_z| + slope ·
    |d_xy| (``approxtree verify`` measured 2e-5..9e-5 m over claims of 0 on full-resolution
    leaves without it)."""
    rel = points - center
    moved = float(np.linalg.norm(rel.astype(np.float32).astype(np.float64) - rel, axis=1).max())
    if moved == 0.0 or not len(faces):
        return moved
    # Up: the ellipsoid's normal at the tile (ECEF), or the local frame's z.
    if georeferenced:
        up = center / np.linalg.norm(center) * np.array([1.0, 1.0, (WGS84_A / WGS84_B) ** 2])
        up /= np.linalg.norm(up)
    else:
        up = np.array([0.0, 0.0, 1.0])
    vertical = np.abs(faces @ up)
    flat = np.linalg.norm(faces - np.outer(faces @ up, up), axis=1)
    slope = float((flat / np.maximum(vertical, 1e-300)).max())
    return moved * (1.0 + slope)
