"""Mesh writers: a terrain approximation as PLY, OBJ or GLB, through trimesh.

PLY and OBJ hold world coordinates (x east, y north, z up) as written: PLY as float64
(``ply_bytes``; trimesh's PLY writer would round them to float32), OBJ as decimal text with 15
decimals (trimesh). GLB (glTF) stores float32 positions, too coarse for map coordinates such as
UTM eastings, so GLB positions are relative to a local origin (the centre of the mesh's x, y
extent and its lowest z) and the origin is recorded in the scene's extras as ``origin``
(trimesh reads it back as ``scene.metadata["origin"]``); world = position + origin.

PLY and OBJ are z-up. GLB follows glTF: y-up. Its positions stay z-up (float32, relative to
the origin, as stored before) and the root node carries the z-up → y-up rotation
(x, y, z) → (x, z, −y), so any glTF viewer shows the terrain upright; a reader applying the
node's matrix gets y-up coordinates (``io.gltf.z_up`` turns them back). GLB also holds vertex
normals, and optionally texture coordinates with an embedded texture. Files are written
atomically. The figures ``approxtree mesh`` measured (max and RMS error, the source's name)
travel in the file: GLB scene extras, a PLY ``comment approxtree {...}`` header line, an OBJ
``# approxtree {...}`` first line, so ``approxtree verify`` can check them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.io.atomic import atomic_write
from approxtree.io.output_path import check_output_file
from approxtree.io.own_output import marked_mesh

#: Marker of the claims line in PLY comments and OBJ headers.
CLAIMS_MARKER = "approxtree"

#: Extension → trimesh file type.
MESH_FORMATS = {".ply": "ply", ".obj": "obj", ".glb": "glb"}


def mesh_format(path: str | os.PathLike) -> str:
    """The trimesh file type of ``path`` from its extension; checks a file can be written there."""
    target = Path(path)
    kind = MESH_FORMATS.get(target.suffix.lower())
    if kind is None:
        raise InvalidParameterError(
            f"Cannot write a mesh to {target}: unknown extension {target.suffix!r}; "
            f"use one of {', '.join(MESH_FORMATS)}."
        )
    check_output_file(target, "mesh file")
    return kind


def local_origin(vertices: np.ndarray) -> np.ndarray:
    """(3,) float64 centre of the x, y extent and lowest z of ``vertices`` (n, 3)."""
    lo = vertices.min(axis=0)
    hi = vertices.max(axis=0)
    return np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], dtype=np.float64)


def _claims_line(metadata: dict[str, Any] | None) -> str | None:
    """``approxtree {...}``: the claims (max and RMS error, source, ...) as one JSON line."""
    if not metadata:
        return None
    return f"{CLAIMS_MARKER} {json.dumps(metadata, separators=(',', ':'), default=str)}"


def ply_bytes(vertices: np.ndarray, triangles: np.ndarray, comment: str | None) -> bytes:
    """Binary little-endian PLY of a mesh with float64 (``double``) vertices, so world
    coordinates are stored as they are (trimesh's PLY writer rounds them to float32: 0.06 m
    at a northing of 849 000 ft, 0.6 m in degrees); ``comment`` as a header comment."""
    header = ["ply", "format binary_little_endian 1.0"]
    if comment:
        header.append(f"comment {comment}")
    header += [
        f"element vertex {len(vertices)}",
        "property double x",
        "property double y",
        "property double z",
        f"element face {len(triangles)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    faces = np.empty(len(triangles), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"] = 3
    faces["v"] = triangles
    text = ("\n".join(header) + "\n").encode("ascii")
    return text + np.ascontiguousarray(vertices, dtype="<f8").tobytes() + faces.tobytes()


def stored_vertices(vertices: np.ndarray, kind: str) -> np.ndarray:
    """(n, 3) float64 world coordinates as a file of ``kind`` holds them: GLB's float32
    positions relative to the local origin, plus the origin; PLY and OBJ as given."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if kind != "glb":
        return v
    origin = local_origin(v)
    return (v - origin).astype(np.float32).astype(np.float64) + origin


def write_mesh(
    path: str | os.PathLike,
    vertices: np.ndarray,
    triangles: np.ndarray,
    metadata: dict[str, Any] | None = None,
    surface: int | None = None,
    texture: tuple[np.ndarray, bytes, str] | None = None,
) -> dict[str, Any]:
    """Write a mesh atomically; returns {"out": path, "format": kind} (+ "origin" for GLB).

    vertices: (n, 3) float64 world coordinates; triangles: (m, 3) int, counter-clockwise seen
    from above; metadata: JSON-serializable facts stored in the GLB scene extras. GLB only:
    surface: how many leading triangles are the surface (the rest are skirts; None: all),
    for the normals; texture: (uvs (n, 2), encoded image, MIME type) to embed.
    """
    import trimesh

    kind = mesh_format(path)
    if texture is not None and kind != "glb":
        raise InvalidParameterError(f"Only GLB embeds a texture; {path} is {kind.upper()}.")
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(v) == 0:
        raise InvalidParameterError("The mesh has no vertex to write.")
    out: dict[str, Any] = {"out": str(path), "format": kind}
    if kind == "glb":
        from approxtree.io.gltf import Y_UP_MATRIX, glb_bytes, surface_normals

        origin = local_origin(v)
        normals = surface_normals(v, t, len(t) if surface is None else surface, v[:, :2])
        uvs, image, mime = texture if texture is not None else (None, None, "image/png")
        extras = {**(metadata or {}), "origin": origin.tolist()}
        data = glb_bytes(v - origin, normals, t, uvs, image, mime, Y_UP_MATRIX, extras)
        out["origin"] = origin.tolist()
    elif kind == "ply":
        data = ply_bytes(v, t, _claims_line(metadata))
    else:
        # 15 decimals: the coordinates as parsed back are the float64 ones (8 would be 1 mm
        # off in degrees).
        from trimesh.exchange.obj import export_obj

        data = export_obj(
            trimesh.Trimesh(v, t, process=False),
            digits=15,
            header=_claims_line(metadata) or "approxtree",
        )
    if isinstance(data, str):
        data = data.encode("utf-8")
    # The mark that lets a later write recognise the file as approxtree's (own_output).
    data = marked_mesh(data, kind)
    with atomic_write(path) as f:
        f.write(data)
    return out
