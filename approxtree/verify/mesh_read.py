"""Mesh files read back for verify: GLB through pygltflib, PLY and OBJ through trimesh, and the
claims approxtree records in them (GLB scene extras, a PLY ``comment approxtree {...}`` line,
an OBJ ``# approxtree {...}`` header line).

Compressed GLBs are decoded by the compressions' own libraries, never by approxtree's writer:
KHR_draco_mesh_compression by DracoPy, EXT_meshopt_compression by meshoptimizer's decoders
(filters included), and KHR_mesh_quantization's normalized integers divided by their maximum.

``read_glb`` applies the scene's node matrices (or TRS), so it returns positions in glTF's
y-up frame as a viewer places them; ``Z_UP`` takes them back to z-up (what 3D Tiles clients
do, and what undoes ``approxtree mesh``'s root rotation).
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from approxtree.errors import StoreError

#: Marker of the claims line in PLY comments and OBJ headers.
CLAIM_MARKER = "approxtree"
#: glTF component types → numpy dtypes.
_COMPONENTS = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
#: y-up (glTF) → z-up: (x, y, z) → (x, −z, y), as a 4 × 4 matrix.
Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])


#: Largest values of normalized integer components (KHR_mesh_quantization), by dtype.
_NORMALIZED = {"<i1": 127.0, "<u1": 255.0, "<i2": 32767.0, "<u2": 65535.0}
#: meshoptimizer's decoders of EXT_meshopt_compression's filters.
_FILTERS = {"OCTAHEDRAL": "decode_filter_oct", "QUATERNION": "decode_filter_quat"}


class _Views:
    """The bytes of a GLB's buffer views, decompressed once (EXT_meshopt_compression through
    meshoptimizer's decoders), and its Draco-compressed primitives (DracoPy's decoder)."""

    def __init__(self, gltf: Any, blob: bytes) -> None:
        self.gltf = gltf
        self.blob = blob
        self.cache: dict[int, bytes] = {}

    def __getitem__(self, index: int) -> bytes:
        if index not in self.cache:
            view = self.gltf.bufferViews[index]
            ext = (view.extensions or {}).get("EXT_meshopt_compression")
            if ext is None:
                if view.buffer != 0:
                    raise ValueError(f"buffer view {index} is not in the GLB's binary chunk")
                start = view.byteOffset or 0
                self.cache[index] = self.blob[start : start + view.byteLength]
            else:
                self.cache[index] = _meshopt_view(self.blob, ext)
        return self.cache[index]

    def draco(self, extension: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3) float64, triangles (m, 3) int64) of a KHR_draco_mesh_compression
        primitive, as DracoPy decodes its POSITION attribute and faces."""
        import DracoPy

        mesh = DracoPy.decode(bytes(self[extension["bufferView"]]))
        wanted = extension["attributes"]["POSITION"]
        found = [a for a in mesh.attributes if a["unique_id"] == wanted]
        if not found:
            raise ValueError(f"the Draco data holds no attribute {wanted} (POSITION)")
        points = np.asarray(found[0]["data"], dtype=np.float64).reshape(-1, 3)
        return points, np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)


def _meshopt_view(blob: bytes, ext: dict[str, Any]) -> bytes:
    """The plain bytes of an EXT_meshopt_compression buffer view (its data in buffer 0)."""
    import meshoptimizer

    if ext.get("buffer", 0) != 0:
        raise ValueError("EXT_meshopt_compression data outside the GLB's binary chunk")
    start = ext.get("byteOffset", 0)
    data = np.frombuffer(blob, dtype=np.uint8, count=ext["byteLength"], offset=start)
    count, stride, mode = int(ext["count"]), int(ext["byteStride"]), ext["mode"]
    if mode == "ATTRIBUTES":
        raw = meshoptimizer.decode_vertex_buffer(count, stride, data).view(np.uint8)
    elif mode == "TRIANGLES":
        raw = meshoptimizer.decode_index_buffer(count, stride, data).view(np.uint8)
    elif mode == "INDICES":
        raw = meshoptimizer.decode_index_sequence(count, stride, data).view(np.uint8)
    else:
        raise ValueError(f"unknown EXT_meshopt_compression mode {mode!r}")
    # The index decoders return uint32 arrays whose first count · stride bytes are the data.
    raw = np.ascontiguousarray(raw.reshape(-1)[: count * stride])
    name = ext.get("filter", "NONE")
    if name == "EXPONENTIAL":
        raw = meshoptimizer.decode_filter_exp(raw, count, stride).view(np.uint8)
    elif name in _FILTERS:
        raw = getattr(meshoptimizer, _FILTERS[name])(raw, count, stride).view(np.uint8)
    elif name != "NONE":
        raise ValueError(f"unknown EXT_meshopt_compression filter {name!r}")
    return raw.tobytes()


def _accessor(gltf: Any, views: _Views, index: int) -> np.ndarray:
    """An accessor's values; normalized integers as floats in [-1, 1] or [0, 1]."""
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    data = views[acc.bufferView]
    dtype = np.dtype(_COMPONENTS[acc.componentType])
    width = _WIDTHS[acc.type]
    start = acc.byteOffset or 0
    stride = view.byteStride or dtype.itemsize * width
    if stride == dtype.itemsize * width:
        raw = np.frombuffer(data, dtype=dtype, count=acc.count * width, offset=start)
        out = raw.reshape(acc.count, width) if width > 1 else raw
    else:
        rows = [np.frombuffer(data, dtype, width, start + i * stride) for i in range(acc.count)]
        out = np.array(rows).reshape(acc.count, width)
    if acc.normalized and dtype.str in _NORMALIZED:
        out = np.maximum(out / _NORMALIZED[dtype.str], -1.0)
    return out


def _node_matrix(node: Any) -> np.ndarray:
    """(4, 4) local matrix of a glTF node (matrix, or translation · rotation · scale)."""
    if node.matrix:
        return np.array(node.matrix, dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    if node.scale:
        m = np.diag([*node.scale, 1.0]) @ m
    if node.rotation:
        x, y, z, w = node.rotation
        r = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        rot = np.eye(4)
        rot[:3, :3] = r
        m = rot @ m
    if node.translation:
        t = np.eye(4)
        t[:3, 3] = node.translation
        m = t @ m
    return m


def read_glb(data: bytes, where: str) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """(positions (n, 3) float64 in the glTF scene frame, triangles (m, 3) int64, scene
    extras) of a GLB's triangle primitives; StoreError when it does not parse."""
    positions, triangles, _, extras = read_glb_parts(data, where)
    return positions, triangles, extras


def read_glb_parts(
    data: bytes, where: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """``read_glb`` with (m,) bool flags of the triangles of skirt primitives (marked
    ``"extras": {"skirt": true}``: walls hung below the surface, which claim nothing):
    (positions, triangles, skirt, extras)."""
    import pygltflib

    try:
        gltf = pygltflib.GLTF2.load_from_bytes(data)
        views = _Views(gltf, gltf.binary_blob() or b"")
        scene = gltf.scenes[gltf.scene or 0]
        extras = dict(scene.extras or {})
        points, tris, skirts = [], [], []
        count = 0
        stack = [(i, np.eye(4)) for i in scene.nodes]
        while stack:
            i, parent = stack.pop()
            node = gltf.nodes[i]
            m = parent @ _node_matrix(node)
            stack.extend((c, m) for c in node.children or [])
            if node.mesh is None:
                continue
            for prim in gltf.meshes[node.mesh].primitives:
                if prim.mode not in (None, 4):
                    continue
                draco = (prim.extensions or {}).get("KHR_draco_mesh_compression")
                if draco is not None:
                    pos, idx = views.draco(draco)
                    idx = idx.ravel()
                else:
                    pos = _accessor(gltf, views, prim.attributes.POSITION).astype(np.float64)
                    if prim.indices is None:
                        idx = np.arange(len(pos))
                    else:
                        idx = _accessor(gltf, views, prim.indices).astype(np.int64).ravel()
                if len(idx) % 3 or (len(idx) and (idx.min() < 0 or idx.max() >= len(pos))):
                    raise ValueError(f"indices of a primitive do not make triangles of {len(pos)}")
                world = pos @ m[:3, :3].T + m[:3, 3]
                points.append(world)
                tris.append(idx.reshape(-1, 3) + count)
                skirt = bool((prim.extras or {}).get("skirt", False))
                skirts.append(np.full(len(idx) // 3, skirt))
                count += len(pos)
    except Exception as exc:  # pygltflib, struct, numpy: a damaged file in any way
        raise StoreError(f"{where} does not parse as GLB: {exc}") from exc
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, bool), extras
    return np.concatenate(points), np.concatenate(tris), np.concatenate(skirts), extras


def z_up(points: np.ndarray, matrix: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) y-up glTF points → z-up, then through ``matrix`` (4, 4) when given."""
    m = Z_UP if matrix is None else matrix @ Z_UP
    return points @ m[:3, :3].T + m[:3, 3]


def _ply_claims(path: str | os.PathLike) -> dict[str, Any]:
    with open(path, "rb") as f:
        header = f.read(65536).split(b"end_header", 1)[0].decode("ascii", "replace")
    for line in header.splitlines():
        if line.startswith(f"comment {CLAIM_MARKER} "):
            return json.loads(line[len(f"comment {CLAIM_MARKER} ") :])
    return {}


def _obj_claims(path: str | os.PathLike) -> dict[str, Any]:
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if not line.startswith("#"):
                break
            if line.startswith(f"# {CLAIM_MARKER} "):
                return json.loads(line[len(f"# {CLAIM_MARKER} ") :])
    return {}


def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, dict[str, Any], str]:
    """(world vertices (n, 3) float64 z-up, triangles (m, 3), claims, format) of a mesh file
    written by ``approxtree mesh``. GLB positions are taken through the root rotation back to
    z-up and offset by the extras' ``origin``."""
    with open(path, "rb") as f:
        head = f.read(4)
    if head == b"glTF":
        with open(path, "rb") as f:
            pos, tris, extras = read_glb(f.read(), str(path))
        origin = np.asarray(extras.get("origin", (0.0, 0.0, 0.0)), dtype=np.float64)
        return z_up(pos) + origin, tris, extras, "glb"
    import trimesh

    kind = "ply" if head.startswith(b"ply") else "obj"
    try:
        claims = _ply_claims(path) if kind == "ply" else _obj_claims(path)
        mesh = trimesh.load(str(path), file_type=kind, process=False, force="mesh")
    except Exception as exc:
        raise StoreError(f"{path} does not parse as {kind.upper()}: {exc}") from exc
    # force="mesh" concatenates whatever the file holds into one Trimesh.
    if not isinstance(mesh, trimesh.Trimesh):
        raise StoreError(f"{path} does not hold a triangle mesh.")
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    return verts, np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3), claims, kind
