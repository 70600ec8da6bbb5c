"""GLB (binary glTF 2.0) of one triangle mesh, written with pygltflib the way clients read it.

glTF is y-up (its +y is "up", +z points at the viewer): terrain is z-up, so callers either
rotate positions into glTF's axes themselves (3D Tiles content: the client applies glTF's
y-up → z-up rotation, ``Z_UP_FROM_Y_UP`` undoes ``y_up``) or keep z-up positions and put the
z-up → y-up rotation on the root node (``Y_UP_MATRIX``; a plain glTF viewer then shows the
terrain upright). One mesh, one primitive: POSITION (float32, with min/max as the spec
requires), NORMAL (unit float32), optional TEXCOORD_0 with an embedded PNG or JPEG texture,
uint32 indices; a non-metallic rough material (textured, or a plain grey).
"""

from __future__ import annotations

from typing import Any

import numpy as np

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


def vertex_normals(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n, 3) float64 unit area-weighted vertex normals of a mesh (up (0, 0, 1) where a vertex
    has no triangle). positions: (n, 3) float64; triangles: (m, 3) counter-clockwise."""
    p = np.asarray(positions, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    face = np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])
    out = np.zeros_like(p)
    # Sum each face's normal onto its three corners: one bincount per axis.
    corners = t.ravel()
    for axis in range(3):
        out[:, axis] = np.bincount(corners, np.repeat(face[:, axis], 3), minlength=len(p))
    length = np.linalg.norm(out, axis=1)
    bad = ~(length > 0)
    out[bad] = (0.0, 0.0, 1.0)
    length[bad] = 1.0
    return out / length[:, None]


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
    counter-clockwise (front faces); uvs: (n, 2) texture coordinates (origin top-left) and
    image: the encoded texture (``mime``), both or neither; matrix: 16 floats, column-major,
    of the root node; extras: JSON facts stored in the scene's extras.
    """
    import pygltflib as g

    pos = np.ascontiguousarray(positions, dtype=np.float32).reshape(-1, 3)
    nrm = np.ascontiguousarray(normals, dtype=np.float32).reshape(-1, 3)
    idx = np.ascontiguousarray(triangles, dtype=np.uint32).reshape(-1)
    blobs: list[tuple[bytes, int | None]] = [
        (idx.tobytes(), g.ELEMENT_ARRAY_BUFFER),
        (pos.tobytes(), g.ARRAY_BUFFER),
        (nrm.tobytes(), g.ARRAY_BUFFER),
    ]
    accessors = [
        g.Accessor(bufferView=0, componentType=g.UNSIGNED_INT, count=len(idx), type=g.SCALAR),
        g.Accessor(
            bufferView=1,
            componentType=g.FLOAT,
            count=len(pos),
            type=g.VEC3,
            min=[float(v) for v in pos.min(axis=0)],
            max=[float(v) for v in pos.max(axis=0)],
        ),
        g.Accessor(bufferView=2, componentType=g.FLOAT, count=len(nrm), type=g.VEC3),
    ]
    attributes = g.Attributes(POSITION=1, NORMAL=2)
    pbr = g.PbrMetallicRoughness(
        baseColorFactor=[0.8, 0.8, 0.8, 1.0], metallicFactor=0.0, roughnessFactor=1.0
    )
    textures: list[Any] = []
    images: list[Any] = []
    samplers: list[Any] = []
    if uvs is not None and image is not None:
        uv = np.ascontiguousarray(uvs, dtype=np.float32).reshape(-1, 2)
        blobs.append((uv.tobytes(), g.ARRAY_BUFFER))
        accessors.append(
            g.Accessor(bufferView=3, componentType=g.FLOAT, count=len(uv), type=g.VEC2)
        )
        attributes.TEXCOORD_0 = 3
        blobs.append((bytes(image), None))
        images.append(g.Image(bufferView=4, mimeType=mime))
        samplers.append(
            g.Sampler(
                magFilter=g.LINEAR,
                minFilter=g.LINEAR_MIPMAP_LINEAR,
                wrapS=g.CLAMP_TO_EDGE,
                wrapT=g.CLAMP_TO_EDGE,
            )
        )
        textures.append(g.Texture(sampler=0, source=0))
        pbr.baseColorFactor = [1.0, 1.0, 1.0, 1.0]
        pbr.baseColorTexture = g.TextureInfo(index=0)
    # One binary buffer; every view starts on a 4-byte boundary.
    views, chunks, offset = [], [], 0
    for data, target in blobs:
        views.append(g.BufferView(buffer=0, byteOffset=offset, byteLength=len(data), target=target))
        pad = (-len(data)) % 4
        chunks.append(data + b"\0" * pad)
        offset += len(data) + pad
    blob = b"".join(chunks)
    node = g.Node(mesh=0, matrix=list(matrix) if matrix is not None else None)
    gltf = g.GLTF2(
        asset=g.Asset(version="2.0", generator="approxtree"),
        scene=0,
        scenes=[g.Scene(nodes=[0], extras=dict(extras or {}))],
        nodes=[node],
        meshes=[
            g.Mesh(
                primitives=[
                    g.Primitive(attributes=attributes, indices=0, material=0, mode=g.TRIANGLES)
                ]
            )
        ],
        materials=[g.Material(pbrMetallicRoughness=pbr, doubleSided=False)],
        textures=textures,
        images=images,
        samplers=samplers,
        accessors=accessors,
        bufferViews=views,
        buffers=[g.Buffer(byteLength=len(blob))],
    )
    gltf.set_binary_blob(blob)
    return b"".join(gltf.save_to_bytes())


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
    # Exact x, y match: sort the surface vertices by (x, y), search each skirt vertex.
    keys = np.ascontiguousarray(xy[top], dtype=np.float64)
    order = np.lexsort((keys[:, 1], keys[:, 0]))
    sx, sy = keys[order, 0], keys[order, 1]
    lo = np.searchsorted(sx, xy[low, 0], side="left")
    hi = np.searchsorted(sx, xy[low, 0], side="right")
    found = np.full(len(low), -1, dtype=np.int64)
    # Runs of equal x are short (a few vertices): step through them all at once.
    for j in range(int((hi - lo).max(initial=0))):
        k = np.minimum(lo + j, len(sx) - 1)
        hit = (found < 0) & (lo + j < hi) & (sy[k] == xy[low, 1])
        found[hit] = k[hit]
    ok = found >= 0
    normals[low[ok]] = normals[top[order[found[ok]]]]
    return normals
