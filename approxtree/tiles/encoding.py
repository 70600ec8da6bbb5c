"""Encode one quantized-mesh-1.0 tile (bytes before gzip): header, vertices, triangles, edge
lists and the extensions (oct-encoded vertex normals, water mask, metadata).

Written here rather than with quantized-mesh-encoder because that package casts positions to
float32 (a longitude of −72° then moves by up to 4 µ° ≈ 0.4 m) and truncates instead of
rounding when it quantizes; here vertices arrive already quantized (u, v any integer positions
in 0..QMAX, heights rounded by ``quantize_heights``), so the tile's error is measured on
exactly what is written. Layout and algorithms follow the
format's specification (github.com/CesiumGS/quantized-mesh) and CesiumJS's decoder
(CesiumTerrainProvider, EllipsoidalOccluder, AttributeCompression.octEncode).
"""

from __future__ import annotations

import json
import struct

import numpy as np

#: WGS84 ellipsoid: semi-major and semi-minor axes in metres.
WGS84_A = 6378137.0
WGS84_B = 6356752.3142451793
_E2 = 1.0 - (WGS84_B / WGS84_A) ** 2
#: Quantized coordinates run over 0..QMAX.
QMAX = 32767
#: Extension ids of the format.
EXT_NORMALS, EXT_WATER_MASK, EXT_METADATA = 1, 2, 4


def float32_outward(lo: float, hi: float) -> tuple[float, float]:
    """lo, hi rounded to float32 (the header's type) outward, so they still enclose the data."""
    lo32, hi32 = np.float32(lo), np.float32(hi)
    if lo32 > lo:
        lo32 = np.nextafter(lo32, np.float32(-np.inf))
    if hi32 < hi:
        hi32 = np.nextafter(hi32, np.float32(np.inf))
    return float(lo32), float(hi32)


def quantize_heights(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(hq, decoded, lo, hi) of (n,) float64 heights: hq (n,) int64 quantized to 0..QMAX
    between the float32 header bounds lo, hi, and decoded (n,) float64 the heights CesiumJS
    decodes from them (lerp(lo, hi, hq / QMAX))."""
    lo, hi = float32_outward(float(z.min()), float(z.max()))
    span = hi - lo
    if span <= 0.0:
        return np.zeros(len(z), dtype=np.int64), np.full(len(z), lo), lo, hi
    hq = np.clip(np.rint((z - lo) / span * QMAX), 0, QMAX).astype(np.int64)
    return hq, lo + span * (hq / QMAX), lo, hi


def ecef(lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(n, 3) float64 earth-centred earth-fixed x, y, z of WGS84 lon, lat (degrees), h (m)."""
    lo, la = np.radians(lon), np.radians(lat)
    n = WGS84_A / np.sqrt(1.0 - _E2 * np.sin(la) ** 2)
    return np.column_stack(
        [
            (n + h) * np.cos(la) * np.cos(lo),
            (n + h) * np.cos(la) * np.sin(lo),
            (n * (1.0 - _E2) + h) * np.sin(la),
        ]
    )


def vertex_normals(xyz: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n, 3) unit normals: area-weighted sums of the ECEF face normals around each vertex.

    xyz: (n, 3) float64 ECEF; triangles (m, 3) counter-clockwise seen from above.
    """
    a, b, c = xyz[triangles[:, 0]], xyz[triangles[:, 1]], xyz[triangles[:, 2]]
    # The cross product's length is twice the area: the sum weights faces by area.
    face = np.cross(b - a, c - a)
    acc = np.zeros_like(xyz)
    for k in range(3):
        np.add.at(acc, triangles[:, k], face)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    # A vertex of zero-area triangles only (never in a greedy TIN): the ellipsoid's up.
    up = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    return np.where(norm > 0.0, acc / np.where(norm > 0.0, norm, 1.0), up)


def oct_encode(normals: np.ndarray) -> np.ndarray:
    """(n, 2) uint8 oct-encoding of unit vectors (AttributeCompression.octEncodeInRange, 255)."""
    n = normals / np.abs(normals).sum(axis=1, keepdims=True)
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    sx = np.where(x >= 0.0, 1.0, -1.0)
    sy = np.where(y >= 0.0, 1.0, -1.0)
    ox = np.where(z < 0.0, (1.0 - np.abs(y)) * sx, x)
    oy = np.where(z < 0.0, (1.0 - np.abs(x)) * sy, y)
    enc = np.round((np.clip(np.column_stack([ox, oy]), -1.0, 1.0) * 0.5 + 0.5) * 255.0)
    return enc.astype(np.uint8)


def oct_decode(enc: np.ndarray) -> np.ndarray:
    """(n, 3) unit vectors of (n, 2) uint8 oct-encoded normals (CesiumJS's octDecode)."""
    v = enc.astype(np.float64) / 255.0 * 2.0 - 1.0
    x, y = v[:, 0], v[:, 1]
    z = 1.0 - np.abs(x) - np.abs(y)
    sx = np.where(x >= 0.0, 1.0, -1.0)
    sy = np.where(y >= 0.0, 1.0, -1.0)
    x2 = np.where(z < 0.0, (1.0 - np.abs(y)) * sx, x)
    y2 = np.where(z < 0.0, (1.0 - np.abs(x)) * sy, y)
    out = np.column_stack([x2, y2, z])
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def bounding_sphere(xyz: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (3,) and radius: the centre of the points' box and the largest distance to it."""
    centre = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
    return centre, float(np.sqrt(((xyz - centre) ** 2).sum(axis=1).max()))


def horizon_occlusion_point(xyz: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The horizon occlusion point in ellipsoid-scaled ECEF (EllipsoidalOccluder's
    computeHorizonCullingPoint towards the bounding sphere's centre).

    When no such point exists (a tile wider than a hemisphere's horizon, levels 0–1), a point
    1000 radii out along the centre's direction: hidden only when the camera is in the
    globe's shadow on the far side, from where (argued, not tested in a browser) no part of
    so wide a tile shows; elsewhere the tile is drawn, at worst needlessly.
    """
    scale = np.array([WGS84_A, WGS84_A, WGS84_B])
    p = xyz / scale
    d = centre / scale
    d = d / np.linalg.norm(d)
    mag = np.linalg.norm(p, axis=1)
    direction = p / mag[:, None]
    mag = np.maximum(mag, 1.0)
    cos_alpha = direction @ d
    sin_alpha = np.linalg.norm(np.cross(direction, d), axis=1)
    cos_beta = 1.0 / mag
    sin_beta = np.sqrt(mag * mag - 1.0) * cos_beta
    denom = cos_alpha * cos_beta - sin_alpha * sin_beta
    if np.any(denom <= 1e-12):
        return d * 1000.0
    return d * float((1.0 / denom).max())


def _zigzag_deltas(q: np.ndarray) -> np.ndarray:
    """(n,) uint16 zig-zag encoded differences of (n,) quantized values (first from 0)."""
    d: np.ndarray = np.diff(q.astype(np.int32), prepend=0)
    return ((d << 1) ^ (d >> 31)).astype(np.uint16)


def first_use_order(triangles: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(order, triangles'): vertices renumbered in the order the index list first uses them,
    as the high-water-mark encoding requires. order (n,): old index of each new vertex."""
    flat = triangles.ravel()
    uniq, first = np.unique(flat, return_index=True)
    order = uniq[np.argsort(first)]
    if len(order) != n:
        raise ValueError(f"{n - len(order)} vertices are in no triangle.")
    new = np.empty(n, dtype=np.int64)
    new[order] = np.arange(n)
    return order, new[triangles]


def high_water_mark(flat: np.ndarray) -> np.ndarray:
    """(3m,) codes of an index list whose vertices appear in order of first use."""
    seen = np.maximum.accumulate(flat)
    highest = np.concatenate([[0], seen[:-1] + 1])
    return highest - flat


def encode_tile(
    u: np.ndarray,
    v: np.ndarray,
    hq: np.ndarray,
    heights: np.ndarray,
    triangles: np.ndarray,
    bounds: tuple[float, float, float, float],
    *,
    normals: bool = True,
    water_mask: np.ndarray | int | None = None,
    metadata: dict | None = None,
) -> bytes:
    """One tile's bytes (not gzipped).

    u, v, hq: (n,) int quantized positions 0..QMAX (u from west, v from south); heights (n,)
    float64 the heights hq stands for (min maps to 0, max to QMAX); triangles (m, 3)
    counter-clockwise seen from above; bounds (west, south, east, north) degrees; water_mask:
    (256, 256) uint8 (row 0 north, 255 = water) or one uint8 for the whole tile.
    Vertices are reordered by first use; the edge lists hold the vertices with u = 0
    (west), v = 0 (south), u = QMAX (east), v = QMAX (north), sorted along the edge.
    """
    n = len(u)
    order, tri = first_use_order(np.asarray(triangles, dtype=np.int64), n)
    u, v, hq, heights = u[order], v[order], hq[order], heights[order]
    west, south, east, north = bounds
    lon = west + (east - west) * u / QMAX
    lat = south + (north - south) * v / QMAX
    xyz = ecef(lon, lat, heights)
    centre = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
    sphere_c, radius = bounding_sphere(xyz)
    hop = horizon_occlusion_point(xyz, sphere_c)
    parts = [
        struct.pack(
            "<3d2f4d3d",
            *centre,
            float(heights.min()),
            float(heights.max()),
            *sphere_c,
            radius,
            *hop,
        ),
        struct.pack("<I", n),
        _zigzag_deltas(u).tobytes(),
        _zigzag_deltas(v).tobytes(),
        _zigzag_deltas(hq).tobytes(),
    ]
    wide = n > 65536
    itype = np.dtype("<u4") if wide else np.dtype("<u2")
    offset = sum(len(p) for p in parts)
    if offset % itype.itemsize:
        parts.append(b"\0" * (itype.itemsize - offset % itype.itemsize))
    parts.append(struct.pack("<I", len(tri)))
    parts.append(high_water_mark(tri.ravel()).astype(itype).tobytes())
    # Edge lists: the vertices on each side, sorted along it (CesiumJS sorts them too).
    for on_edge, along in ((u == 0, v), (v == 0, u), (u == QMAX, v), (v == QMAX, u)):
        idx = np.flatnonzero(on_edge)
        idx = idx[np.argsort(along[idx], kind="stable")]
        parts.append(struct.pack("<I", len(idx)))
        parts.append(idx.astype(itype).tobytes())
    if normals:
        data = oct_encode(vertex_normals(xyz, tri)).tobytes()
        parts.append(struct.pack("<BI", EXT_NORMALS, len(data)) + data)
    if water_mask is not None:
        data = np.asarray(water_mask, dtype=np.uint8).tobytes()
        parts.append(struct.pack("<BI", EXT_WATER_MASK, len(data)) + data)
    if metadata is not None:
        # The extension holds a uint32 length, then the JSON text (CesiumJS reads both).
        text = json.dumps(metadata, separators=(",", ":")).encode()
        data = struct.pack("<I", len(text)) + text
        parts.append(struct.pack("<BI", EXT_METADATA, len(data)) + data)
    return b"".join(parts)
