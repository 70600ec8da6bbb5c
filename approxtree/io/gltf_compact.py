"""Compact GLB of one triangle mesh whose positions lie on a lattice: Draco or meshopt.

Positions arrive already quantized: ``lattice`` (n, 3) non-negative integers, each standing
for ``lattice * step`` metres in the mesh's own axes, and ``placement`` (4, 4) maps those
metres into the glTF scene (the node's matrix: a rotation and a translation, glTF's y-up
included). The caller chose the lattice, so it knows exactly what the file's positions are
(and can bound what the quantization changes); the encoders here keep them exact:

- ``draco`` (KHR_draco_mesh_compression): Draco quantizes positions itself over a cube of
  ``quantization_range`` from ``quantization_origin``; with the origin at 0, the range
  ``step · (2^bits − 1)`` and ``step`` a power of two, Draco's float32 quantizer and
  dequantizer reproduce ``lattice * step`` bit for bit (every factor is a power of two and
  every value below 2^24 steps). Normals are Draco's octahedral normals (8 bits), texture
  coordinates 14 bits. Draco merges duplicate vertices and drops unused ones: the file is
  decoded once (DracoPy) for the accessors' counts and bounds.
- ``meshopt`` (EXT_meshopt_compression + KHR_mesh_quantization): positions as unsigned shorts
  (``bits`` <= 16), the node's matrix scaling them by ``step`` — or, ``normalized``, as
  normalized shorts scaled by ``65535 · step``, the only form CesiumJS's 3D Tiles terrain
  reads (the Khronos validator then reports the node matrix as not decomposable: it compares
  determinants in float32, and (65535 · step)³ is large),
  normals through the OCTAHEDRAL filter (7 bits; the wall bottoms share the
  surface's mean normal), texture coordinates as normalized unsigned
  shorts, indices through the index codec; vertices reordered for the vertex cache and
  fetch first (meshoptimizer), which is what makes the codecs compress. The uncompressed
  views live in a fallback buffer that holds no data (the extensions are required).

Skirts (``skirt_from``: the triangles from that index on) go into a second primitive marked
``"extras": {"skirt": true}``: their walls hang below the surface and claim nothing (once on
a lattice they are no longer exactly vertical, so ``approxtree verify`` leaves them out of
the error measure by that mark). With Draco it is its own compressed mesh; with meshopt it
shares the surface's vertices and has its own indices.

``edges`` (meshopt only) adds CESIUM_tile_edges: the vertex indices on each side of a tile
of a geographic tiling (what CesiumJS's Cesium3DTilesTerrainProvider reads), compressed
with meshopt's index-sequence codec.
"""

from __future__ import annotations

import functools
import json
import struct
from typing import Any

import numpy as np

from approxtree.errors import ApproxTreeError, InvalidParameterError
from approxtree.io.gltf import column_bounds
from approxtree.kernels import mesh_normals
from approxtree.kernels._jit import readonly

#: Compressions of 3D Tiles content: lattice positions compressed, or float32 positions.
COMPRESSIONS = ("draco", "meshopt", "none")
#: The default: meshopt writes as many tiles per second as float32 content did (Draco's
#: encoder, GIL held, writes about half as many; its tiles are a third smaller).
DEFAULT_COMPRESSION = "meshopt"
#: Most lattice bits per axis each compression keeps exact.
MAX_BITS = {"draco": 24, "meshopt": 16}
#: Draco's effort (0 fastest .. 10 smallest): level 4 wrote NC tiles with normals smaller
#: (4.9 KB) and faster (0.66 ms) than 7 (5.3 KB, 0.93 ms).
DRACO_LEVEL = 4
#: Triangle orders kept for reuse (``_strip_order``): a grid's tree has a few topologies.
STRIP_ORDERS = 64
DRACO_NORMAL_BITS = 8
#: meshopt's octahedral normals: 7 bits a component (±63, at most ~1° from the unit normal):
#: 235 bytes a tile smaller than 8 bits on NC (1,222 → 987), the codec's deltas a bit
#: narrower; shading differences below what 8-bit colour shows.
MESHOPT_NORMAL_BITS = 7
DRACO_UV_BITS = 14
#: glTF enums.
_BYTE, _USHORT, _UINT, _FLOAT = 5120, 5123, 5125, 5126
_LINEAR, _LINEAR_MIPMAP_LINEAR, _CLAMP_TO_EDGE = 9729, 9987, 33071
#: CESIUM_tile_edges' sides, in the order ``edges`` gives them: west, south, east, north.
EDGE_NAMES = ("left", "bottom", "right", "top")


def compact_glb(
    lattice: np.ndarray,
    step: float,
    bits: int,
    placement: np.ndarray,
    normals: np.ndarray,
    triangles: np.ndarray,
    compression: str,
    *,
    skirt_from: int | None = None,
    uvs: np.ndarray | None = None,
    image: bytes | None = None,
    mime: str = "image/png",
    extras: dict[str, Any] | None = None,
    edges: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
    normalized: bool = False,
) -> bytes:
    """The GLB of one mesh with lattice positions (see the module docstring).

    lattice: (n, 3) int, 0 <= values < 2**bits; step: metres per lattice unit, a power of two;
    placement: (4, 4) float64, lattice metres → glTF scene; normals: (n, 3) unit vectors in
    the lattice's axes; triangles: (m, 3) counter-clockwise, skirts from ``skirt_from`` on;
    uvs: (n, 2) texture coordinates (origin top-left) with ``image`` (encoded, ``mime``);
    extras: the scene's extras; edges: 4 arrays of vertex indices (west, south, east, north),
    meshopt only; normalized: meshopt positions as normalized shorts.
    """
    q = np.asarray(lattice, dtype=np.int64).reshape(-1, 3)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if compression not in MAX_BITS:
        raise InvalidParameterError(
            f"compression must be one of {', '.join(MAX_BITS)} for lattice positions, "
            f"got {compression!r}."
        )
    if not 1 <= bits <= MAX_BITS[compression] or (len(q) and (q.min() < 0 or q.max() >= 2**bits)):
        raise InvalidParameterError(
            f"lattice positions must be integers in [0, 2^{bits}) with bits <= "
            f"{MAX_BITS[compression]} for {compression}."
        )
    if step <= 0 or np.frexp(step)[0] != 0.5:
        raise InvalidParameterError(f"step must be a positive power of two, got {step!r}.")
    if (uvs is None) != (image is None):
        raise InvalidParameterError("uvs and image come together (a textured mesh) or not at all.")
    if edges is not None and compression != "meshopt":
        raise InvalidParameterError("tile edges (CESIUM_tile_edges) are written with meshopt only.")
    # Vertices no triangle uses (nodata holes) are left out: the codecs number the used ones.
    used, new = _used(tris, len(q))
    if len(used) < len(q):
        q, tris, normals = q[used], new[tris], np.asarray(normals)[used]
        uvs = None if uvs is None else np.asarray(uvs)[used]
        if edges is not None:
            edges = tuple(new[np.asarray(e, dtype=np.int64)] for e in edges)  # type: ignore[assignment]
    cut = len(tris) if skirt_from is None else int(skirt_from)
    parts = [tris[:cut], tris[cut:]] if cut < len(tris) else [tris]
    doc = _Document(extras)
    if compression == "draco":
        primitives = [_draco_primitive(doc, q, step, bits, normals, t, uvs) for t in parts]
        matrix = np.asarray(placement, dtype=np.float64)
    else:
        primitives = _meshopt_primitives(doc, q, normals, parts, uvs, edges, normalized)
        # Shorts decode to q (q / 65535 normalized): the node scales them back to metres.
        scale = 65535.0 * step if normalized else step
        matrix = np.asarray(placement, dtype=np.float64) @ np.diag([scale] * 3 + [1.0])
    if len(primitives) > 1:
        primitives[1]["extras"] = {"skirt": True}
    if image is not None:
        doc.texture(image, mime)
    for primitive in primitives:
        texcoord = primitive.pop("_texcoord", None)
        if image is not None:
            primitive["attributes"]["TEXCOORD_0"] = texcoord
    return doc.glb(primitives, matrix)


def _used(tris: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(used (k,): the vertices the triangles (m, 3) use, in order; new (n,): each vertex's
    index among them, −1 for an unused one)."""
    mask = np.zeros(n, dtype=bool)
    mask[tris.ravel()] = True
    used = np.flatnonzero(mask)
    new = np.full(n, -1, dtype=np.int64)
    new[used] = np.arange(len(used))
    return used, new


def _number(value: float) -> float | int:
    """A float as its JSON number, whole ones without the ".0" (the same number, fewer bytes
    in every tile's JSON chunk)."""
    value = float(value)
    return int(value) if value.is_integer() else value


class _Document:
    """The glTF JSON and the BIN chunk being assembled (views 4-byte aligned)."""

    def __init__(self, extras: dict[str, Any] | None) -> None:
        self.json: dict[str, Any] = {
            "asset": {"version": "2.0"},
            "accessors": [],
            "bufferViews": [],
        }
        self.extras = extras
        self.chunks: list[bytes] = []
        self.offset = 0
        self.used: list[str] = []
        self.material: dict[str, Any] = {
            "baseColorFactor": [0.8, 0.8, 0.8, 1],
            "metallicFactor": 0,
        }

    def bin(self, data: bytes) -> tuple[int, int]:
        """Append data to the BIN chunk; (offset, length)."""
        at = self.offset
        self.chunks.append(data + b"\0" * ((-len(data)) % 4))
        self.offset += len(self.chunks[-1])
        return at, len(data)

    def view(self, view: dict[str, Any]) -> int:
        self.json["bufferViews"].append(view)
        return len(self.json["bufferViews"]) - 1

    def accessor(self, accessor: dict[str, Any]) -> int:
        self.json["accessors"].append(accessor)
        return len(self.json["accessors"]) - 1

    def texture(self, image: bytes, mime: str) -> None:
        at, length = self.bin(bytes(image))
        view = self.view({"buffer": 0, "byteOffset": at, "byteLength": length})
        self.json["images"] = [{"bufferView": view, "mimeType": mime}]
        self.json["samplers"] = [
            {
                "magFilter": _LINEAR,
                "minFilter": _LINEAR_MIPMAP_LINEAR,
                "wrapS": _CLAMP_TO_EDGE,
                "wrapT": _CLAMP_TO_EDGE,
            }
        ]
        self.json["textures"] = [{"sampler": 0, "source": 0}]
        self.material["baseColorFactor"] = [1, 1, 1, 1]
        self.material["baseColorTexture"] = {"index": 0}

    def glb(self, primitives: list[dict[str, Any]], matrix: np.ndarray) -> bytes:
        """The GLB container (header, JSON chunk, BIN chunk; glTF 2.0 §4.4)."""
        blob = b"".join(self.chunks)
        buffers: list[dict[str, Any]] = [{"byteLength": len(blob)}]
        buffers.extend(self.json.pop("_more_buffers", []))
        for primitive in primitives:
            primitive.setdefault("material", 0)
        scene: dict[str, Any] = {"nodes": [0]}
        if self.extras:
            scene["extras"] = self.extras
        self.json.update(
            scene=0,
            scenes=[scene],
            nodes=[{"mesh": 0, "matrix": [_number(v) for v in matrix.T.ravel()]}],
            meshes=[{"primitives": primitives}],
            materials=[{"pbrMetallicRoughness": self.material}],
            buffers=buffers,
            extensionsUsed=sorted(set(self.used)),
            extensionsRequired=sorted(set(self.used) - {"CESIUM_tile_edges"}),
        )
        text = json.dumps(self.json, separators=(",", ":")).encode("utf-8")
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


# Draco


def _draco_primitive(
    doc: _Document,
    q: np.ndarray,
    step: float,
    bits: int,
    normals: np.ndarray,
    tris: np.ndarray,
    uvs: np.ndarray | None,
) -> dict[str, Any]:
    """The primitive of a Draco-compressed mesh of the vertices ``tris`` (m, 3) use (its
    data appended to ``doc``)."""
    import DracoPy

    used, new = _used(tris, len(q))
    tris = new[tris]
    q, normals = q[used], np.asarray(normals)[used]
    uvs = None if uvs is None else np.asarray(uvs)[used]
    # Lattice metres, exact in float32 (q < 2^24, step a power of two).
    points = (q * step).astype(np.float32)
    data = DracoPy.encode(
        points,
        tris,
        quantization_bits=bits,
        compression_level=DRACO_LEVEL,
        quantization_range=step * (2**bits - 1),
        quantization_origin=[0.0, 0.0, 0.0],
        normals=np.asarray(normals, dtype=np.float64),
        normal_quantization_bits=DRACO_NORMAL_BITS,
        tex_coord=None if uvs is None else np.asarray(uvs, dtype=np.float64),
        tex_coord_quantization_bits=DRACO_UV_BITS if uvs is not None else None,
    )
    # Draco merged and reordered vertices: the accessors describe what it decodes to.
    mesh = DracoPy.decode(data)
    ids = {a["attribute_type"]: a["unique_id"] for a in mesh.attributes}
    decoded = np.asarray(mesh.points, dtype=np.float64).reshape(-1, 3)
    count = len(decoded)
    low, high = column_bounds(decoded)
    faces = np.asarray(mesh.faces).reshape(-1, 3)
    at, length = doc.bin(data)
    view = doc.view({"buffer": 0, "byteOffset": at, "byteLength": length})
    doc.used.append("KHR_draco_mesh_compression")
    position = doc.accessor(
        {
            "componentType": _FLOAT,
            "count": count,
            "type": "VEC3",
            "min": [float(v) for v in low],
            "max": [float(v) for v in high],
        }
    )
    normal = doc.accessor({"componentType": _FLOAT, "count": count, "type": "VEC3"})
    indices = doc.accessor(
        {
            "componentType": _USHORT if count <= 65535 else _UINT,
            "count": int(faces.size),
            "type": "SCALAR",
        }
    )
    attributes = {"POSITION": position, "NORMAL": normal}
    draco_ids = {"POSITION": ids[0], "NORMAL": ids[1]}
    primitive: dict[str, Any] = {"attributes": attributes, "indices": indices}
    if uvs is not None:
        primitive["_texcoord"] = doc.accessor(
            {"componentType": _FLOAT, "count": count, "type": "VEC2"}
        )
        draco_ids["TEXCOORD_0"] = ids[3]
    primitive["extensions"] = {
        "KHR_draco_mesh_compression": {"bufferView": view, "attributes": draco_ids}
    }
    return primitive


# meshopt


def _meshopt_order(parts: list[np.ndarray], n: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """(remap (n,): new index of each vertex, each part's triangles (m, 3) in new indices),
    both int64 and read-only: each part's triangles in strip order, vertices in order of
    first use (meshoptimizer).

    Strip order (what gltfpack uses for compressed output) rather than the vertex-cache
    order: the index codec and the vertex deltas compress better and it is quicker (NC:
    10.5 KB per tile against 11.6, 0.61 s against 0.64 for 341 tiles). It depends on the
    triangles alone, and the patches of a grid's tree share a few of them (lattices of the
    same rows × columns, the same walls): each is ordered once (``_strip_order``)."""
    flats = tuple(np.ascontiguousarray(t.ravel(), dtype=np.uint32).tobytes() for t in parts)
    return _strip_order(flats, n)


@functools.lru_cache(maxsize=STRIP_ORDERS)
def _strip_order(flats: tuple[bytes, ...], n: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """``_meshopt_order`` of the parts' uint32 indices ``flats`` over n vertices; a
    meshoptimizer strip order costs about 0.1 ms a tile, this cache's lookup a hash of the
    indices (its arrays are read-only: every caller shares them)."""
    import meshoptimizer

    cached = []
    for flat in flats:
        indices = np.frombuffer(flat, dtype=np.uint32)
        out = np.zeros_like(indices)
        meshoptimizer.optimize_vertex_cache_strip(out, indices, len(indices), n)
        cached.append(out)
    every = np.concatenate(cached)
    remap = np.zeros(n, dtype=np.uint32)
    meshoptimizer.optimize_vertex_fetch_remap(remap, every, len(every), n)
    wide = remap.astype(np.int64)
    faces = [wide[c].reshape(-1, 3) for c in cached]
    for a in (wide, *faces):
        a.flags.writeable = False
    return wide, faces


def _meshopt_view(
    doc: _Document,
    encoded: bytes,
    count: int,
    stride: int,
    mode: str,
    filter_name: str = "NONE",
) -> int:
    """A buffer view whose data is meshopt-encoded in the BIN chunk; its plain bytes would sit
    in the fallback buffer (buffer 1, which holds none). No ``target``: it is optional (the
    validator's hint), clients infer it from the accessors' use, and it cost 60 bytes a tile."""
    at, length = doc.bin(encoded)
    fallback = doc.json.setdefault(
        "_more_buffers",
        [{"byteLength": 0, "extensions": {"EXT_meshopt_compression": {"fallback": True}}}],
    )[0]
    # Offsets of 0 and the filter NONE are the schemas' defaults: left out of the JSON.
    ext: dict[str, Any] = {"buffer": 0, "byteOffset": at}
    ext.update(byteLength=length, byteStride=stride, count=count, mode=mode)
    if filter_name != "NONE":
        ext["filter"] = filter_name
    view: dict[str, Any] = {"buffer": 1, "byteOffset": fallback["byteLength"]}
    view.update(byteLength=count * stride, extensions={"EXT_meshopt_compression": ext})
    for entry in (ext, view):
        if not entry["byteOffset"]:
            del entry["byteOffset"]
    if mode == "ATTRIBUTES":
        view["byteStride"] = stride
    fallback["byteLength"] += count * stride + (-(count * stride)) % 4
    return doc.view(view)


def _meshopt_primitives(
    doc: _Document,
    q: np.ndarray,
    normals: np.ndarray,
    parts: list[np.ndarray],
    uvs: np.ndarray | None,
    edges: tuple[np.ndarray, ...] | None,
    normalized: bool,
) -> list[dict[str, Any]]:
    """The primitives (one per part of the triangles, sharing the vertices) of a
    meshopt-compressed, quantized mesh (its data appended to ``doc``)."""
    import meshoptimizer

    n = len(q)
    remap, faces_of = _meshopt_order(parts, n)
    order = np.empty(n, dtype=np.int64)
    order[remap] = np.arange(n)
    doc.used.extend(["EXT_meshopt_compression", "KHR_mesh_quantization"])
    # Wall bottoms (vertices of the skirts alone) share one normal, the surface's mean: the
    # codec stores a repeated value in a few bits (their tops' normals, scattered along the
    # border, cost ~110 bytes a tile on NC); walls only fill cracks below the neighbours.
    if len(parts) > 1:
        normals = _bottom_normals(np.asarray(normals, dtype=np.float64), parts[0])
    # Positions: unsigned shorts padded to 8 bytes (the codec wants strides of 4).
    pos, octs, low, high = mesh_normals.meshopt_vertices(
        readonly(q, np.int64),
        readonly(np.asarray(normals), np.float64),
        readonly(order),
        2 ** (MESHOPT_NORMAL_BITS - 1) - 1,
    )
    view = _meshopt_view(doc, _vertex_codec(pos), n, 8, "ATTRIBUTES")
    position = doc.accessor(
        {
            "bufferView": view,
            "componentType": _USHORT,
            "count": n,
            "type": "VEC3",
            "min": [int(v) for v in low],
            "max": [int(v) for v in high],
        }
        | ({"normalized": True} if normalized else {})
    )
    view = _meshopt_view(
        doc,
        _vertex_codec(octs.view(np.uint8)),
        n,
        4,
        "ATTRIBUTES",
        "OCTAHEDRAL",
    )
    normal = doc.accessor(
        {"bufferView": view, "componentType": _BYTE, "normalized": True, "count": n, "type": "VEC3"}
    )
    wide = n > 65535
    itype, icomp = ("<u4", _UINT) if wide else ("<u2", _USHORT)
    attributes = {"POSITION": position, "NORMAL": normal}
    primitives: list[dict[str, Any]] = []
    for faces in faces_of:
        # The index codec decodes to 2- or 4-byte indices; it encodes 32-bit input.
        view = _meshopt_view(
            doc,
            meshoptimizer.encode_index_buffer(faces.ravel().astype(np.uint32), faces.size, n),
            int(faces.size),
            np.dtype(itype).itemsize,
            "TRIANGLES",
        )
        indices = doc.accessor(
            {"bufferView": view, "componentType": icomp, "count": int(faces.size), "type": "SCALAR"}
        )
        primitives.append({"attributes": dict(attributes), "indices": indices})
    if uvs is not None:
        uv = np.rint(np.clip(np.asarray(uvs, dtype=np.float64)[order], 0.0, 1.0) * 65535.0)
        view = _meshopt_view(
            doc,
            _vertex_codec(uv.astype("<u2")),
            n,
            4,
            "ATTRIBUTES",
        )
        texcoord = doc.accessor(
            {
                "bufferView": view,
                "componentType": _USHORT,
                "normalized": True,
                "count": n,
                "type": "VEC2",
            }
        )
        for primitive in primitives:
            primitive["_texcoord"] = texcoord
    if edges is not None:
        sides = {}
        for name, side in zip(EDGE_NAMES, edges, strict=True):
            idx = remap[np.asarray(side, dtype=np.int64)].astype(np.uint32)
            view = _meshopt_view(
                doc,
                meshoptimizer.encode_index_sequence(idx, len(idx), n),
                len(idx),
                np.dtype(itype).itemsize,
                "INDICES",
            )
            sides[name] = doc.accessor(
                {"bufferView": view, "componentType": icomp, "count": len(idx), "type": "SCALAR"}
            )
        primitives[0]["extensions"] = {"CESIUM_tile_edges": sides}
        doc.used.append("CESIUM_tile_edges")
    return primitives


def _bottom_normals(normals: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """``normals`` (n, 3) with the vertices no ``surface`` triangle (m, 3) uses given the
    unit mean of the surface vertices' normals (up when they sum to zero)."""
    used = np.zeros(len(normals), dtype=bool)
    used[surface.ravel()] = True
    mean = normals[used].sum(axis=0)
    length = float(np.sqrt(mean @ mean))
    out = normals.copy()
    out[~used] = mean / length if length > 0 else (0.0, 0.0, 1.0)
    return out


def _vertex_codec(data: np.ndarray) -> bytes:
    """meshopt's vertex codec of (n, k) rows (k · itemsize a multiple of 4), checked to be
    format version 0, the one EXT_meshopt_compression defines."""
    import meshoptimizer

    encoded = meshoptimizer.encode_vertex_buffer(np.ascontiguousarray(data))
    if encoded[:1] != b"\xa0":
        raise ApproxTreeError(
            f"meshoptimizer wrote vertex codec version {encoded[0] & 15}; "
            "EXT_meshopt_compression reads version 0: leave meshoptimizer's encode version "
            "at its default (0)."
        )
    return encoded
