"""GLB (binary glTF 2.0) of one triangle mesh, written the way clients read it.

glTF is y-up (its +y is "up", +z points at the viewer): terrain is z-up, so callers either
rotate positions into glTF's axes themselves (3D Tiles content: the client applies glTF's
y-up → z-up rotation, ``Z_UP_FROM_Y_UP`` undoes ``y_up``) or keep z-up positions and put the
z-up → y-up rotation on the root node (``Y_UP_MATRIX``; a plain glTF viewer then shows the
terrain upright). One mesh, one primitive: POSITION (float32, with min/max as the spec
requires), NORMAL (unit float32), optional TEXCOORD_0 with an embedded PNG or JPEG texture,
uint32 indices; a non-metallic rough material (textured, or a plain grey).
"""

from __future__ import annotations

import json
import struct
from typing import Any

import numpy as np

from approxtree.kernels import mesh_normals
from approxtree.kernels._jit import readonly
from approxtree.kernels.tile_bounds import column_bounds as _column_bounds

#: Column-major 4 × 4 matrix of the z-up → y-up rotation (x, y, z) → (x, z, −y), for a root node.
Y_UP_MATRIX = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]


def y_up(points: np.ndarray) -> np.ndarray:
    """(n, 3) z-up points or vectors in glTF's y-up axes: (x, y, z) → (x, z, −y)."""
    p = np.asarray(points)
    return np.column_stack([p[:, 0], p[:, 2], -p[:, 1]])


def z_up(points: np.ndarray) -> np.ndarray:
    """The inverse of ``y_up`` (what a 3D Tiles client applies): (x, y, z) → (x, −z, y)."""
    p = np.asarray(points)
    return np.column_stack([p[:, 0], -p[:, 2], p[:, 1]])


def face_normals(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m, 3) float64 cross products (b − a) × (c − a) of the triangles (m, 3): normals of
    twice the triangles' areas. positions: (n, 3) float64."""
    return mesh_normals.face_normals(
        readonly(np.asarray(positions).reshape(-1, 3), np.float64),
        readonly(np.asarray(triangles).reshape(-1, 3), np.int64),
    )


def vertex_normals(
    positions: np.ndarray, triangles: np.ndarray, faces: np.ndarray | None = None
) -> np.ndarray:
    """(n, 3) float64 unit area-weighted vertex normals of a mesh (up (0, 0, 1) where a vertex
    has no triangle). positions: (n, 3) float64; triangles: (m, 3) counter-clockwise; faces:
    their ``face_normals`` when already computed."""
    face = face_normals(positions, triangles) if faces is None else faces
    return mesh_normals.vertex_normals(
        len(np.asarray(positions).reshape(-1, 3)),
        readonly(np.asarray(triangles).reshape(-1, 3), np.int64),
        readonly(face, np.float64),
    )


def column_bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low (3,), high (3,)) per column of ``points`` (n, 3), in its dtype (as numpy's
    ``min(axis=0)``, ``max(axis=0)``, which raise on n = 0; a loop, many times faster)."""
    if not len(points):
        return points.min(axis=0), points.max(axis=0)
    return _column_bounds(readonly(points))


#: glTF enums: component types, buffer view targets, sampler filters and wrap.
_FLOAT, _UNSIGNED_INT, _UNSIGNED_SHORT = 5126, 5125, 5123
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_LINEAR, _LINEAR_MIPMAP_LINEAR, _CLAMP_TO_EDGE = 9729, 9987, 33071


def glb_bytes(
    positions: np.ndarray,
    normals: np.ndarray,
    triangles: np.ndarray,
    uvs: np.ndarray | None = None,
    image: bytes | None = None,
    mime: str = "image/png",
    matrix: list[float] | None = None,
    extras: dict[str, Any] | None = None,
) -> bytes:
    """The GLB of one mesh.

    positions: (n, 3) float32 (glTF axes); normals: (n, 3) unit vectors; triangles: (m, 3)
    counter-clockwise (front faces), stored as uint16 when n <= 65535; uvs: (n, 2) texture
    coordinates (origin top-left) and image: the encoded texture (``mime``), both or neither;
    matrix: 16 floats, column-major, of the root node; extras: JSON facts stored in the
    scene's extras.

    The glTF JSON and the GLB container (header, JSON chunk, BIN chunk; glTF 2.0 §4.4) are
    assembled here: a generic glTF object model costs more per tile than the arrays it wraps
    (the tests read every file back with pygltflib and trimesh and run the Khronos validator).
    """
    pos = np.ascontiguousarray(positions, dtype="<f4").reshape(-1, 3)
    low, high = column_bounds(pos)
    nrm = np.ascontiguousarray(normals, dtype="<f4").reshape(-1, 3)
    # 16-bit indices when every vertex fits (a node's patch: always), else 32-bit.
    small = len(pos) <= 65535
    idx = np.ascontiguousarray(triangles, dtype="<u2" if small else "<u4").reshape(-1)
    blobs: list[tuple[bytes, int | None]] = [
        (idx.tobytes(), _ELEMENT_ARRAY_BUFFER),
        (pos.tobytes(), _ARRAY_BUFFER),
        (nrm.tobytes(), _ARRAY_BUFFER),
    ]
    accessors: list[dict[str, Any]] = [
        {
            "bufferView": 0,
            "componentType": _UNSIGNED_SHORT if small else _UNSIGNED_INT,
            "count": len(idx),
            "type": "SCALAR",
        },
        {
            "bufferView": 1,
            "componentType": _FLOAT,
            "count": len(pos),
            "type": "VEC3",
            "min": [float(v) for v in low],
            "max": [float(v) for v in high],
        },
        {"bufferView": 2, "componentType": _FLOAT, "count": len(nrm), "type": "VEC3"},
    ]
    attributes = {"POSITION": 1, "NORMAL": 2}
    pbr: dict[str, Any] = {
        "baseColorFactor": [0.8, 0.8, 0.8, 1.0],
        "metallicFactor": 0.0,
        "roughnessFactor": 1.0,
    }
    gltf: dict[str, Any] = {"asset": {"version": "2.0", "generator": "approxtree"}}
    if uvs is not None and image is not None:
        uv = np.ascontiguousarray(uvs, dtype="<f4").reshape(-1, 2)
        blobs.append((uv.tobytes(), _ARRAY_BUFFER))
        accessors.append(
            {"bufferView": 3, "componentType": _FLOAT, "count": len(uv), "type": "VEC2"}
        )
        attributes["TEXCOORD_0"] = 3
        blobs.append((bytes(image), None))
        gltf["images"] = [{"bufferView": 4, "mimeType": mime}]
        gltf["samplers"] = [
            {
                "magFilter": _LINEAR,
                "minFilter": _LINEAR_MIPMAP_LINEAR,
                "wrapS": _CLAMP_TO_EDGE,
                "wrapT": _CLAMP_TO_EDGE,
            }
        ]
        gltf["textures"] = [{"sampler": 0, "source": 0}]
        pbr["baseColorFactor"] = [1.0, 1.0, 1.0, 1.0]
        pbr["baseColorTexture"] = {"index": 0}
    # One binary buffer; every view starts on a 4-byte boundary.
    views, chunks, offset = [], [], 0
    for data, target in blobs:
        view = {"buffer": 0, "byteOffset": offset, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        views.append(view)
        pad = (-len(data)) % 4
        chunks.append(data + b"\0" * pad)
        offset += len(data) + pad
    blob = b"".join(chunks)
    node: dict[str, Any] = {"mesh": 0}
    if matrix is not None:
        node["matrix"] = [float(v) for v in matrix]
    scene: dict[str, Any] = {"nodes": [0]}
    if extras:
        scene["extras"] = extras
    primitive = {"attributes": attributes, "indices": 0, "material": 0, "mode": 4}
    gltf.update(
        scene=0,
        scenes=[scene],
        nodes=[node],
        meshes=[{"primitives": [primitive]}],
        materials=[{"pbrMetallicRoughness": pbr}],
        accessors=accessors,
        bufferViews=views,
        buffers=[{"byteLength": len(blob)}],
    )
    text = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    text += b" " * ((-len(text)) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return b"".join(
        [
            struct.pack("<4sII", b"glTF", 2, total),
            struct.pack("<I4s", len(text), b"JSON"),
            text,
            struct.pack("<I4s", len(blob), b"BIN\0"),
            blob,
        ]
    )


def surface_normals(
    points: np.ndarray, triangles: np.ndarray, surface: int, xy: np.ndarray
) -> np.ndarray:
    """(n, 3) unit vertex normals of a surface with skirts: normals of the first ``surface``
    triangles (the surface's), and each vertex outside them (a skirt's bottom vertex) takes
    the normal of the surface vertex with exactly its x, y, so walls do not tilt the border's
    shading. points: (n, 3) where normals are wanted (any frame); xy: (n, 2) map x, y."""
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)[:surface]
    normals = vertex_normals(points, t)
    used = np.zeros(len(points), dtype=bool)
    used[t.ravel()] = True
    if used.all():
        return normals
    top, low = np.flatnonzero(used), np.flatnonzero(~used)
    # Exact x, y match: one np.unique over the (x, y) pairs of both sets, as 16-byte keys.
    keys = np.ascontiguousarray(np.concatenate([xy[top], xy[low]]), dtype=np.float64)
    _, inverse = np.unique(keys.view(np.dtype((np.void, 16))).ravel(), return_inverse=True)
    owner = np.full(int(inverse.max()) + 1, -1, dtype=np.int64)
    owner[inverse[: len(top)]] = top
    found = owner[inverse[len(top) :]]
    ok = found >= 0
    normals[low[ok]] = normals[found[ok]]
    return normals
