"""Implicit tilesets (3D Tiles 1.1 implicit tiling) read back for verify, without the writer.

A tile with ``implicitTiling`` stands for a QUADTREE of tiles named (level, x, y); binary
``.subtree`` files say which exist (availability bitstreams, least significant bit first,
bit (4^level − 1) / 3 + Morton(x, y) within a subtree) and which have content, and may hold
tile metadata (a property table, one row per available tile in bit order) whose semantics
override what the subdivision derives: TILE_GEOMETRIC_ERROR, TILE_BOUNDING_REGION / BOX /
SPHERE, TILE_MINIMUM_HEIGHT / TILE_MAXIMUM_HEIGHT (a derived region's heights).

``implicit_tiles`` lists every available tile with its derived and its declared facts.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import StoreError

#: Property component types → numpy dtypes; element types → component counts.
_DTYPES = {
    "INT8": "<i1",
    "UINT8": "<u1",
    "INT16": "<i2",
    "UINT16": "<u2",
    "INT32": "<i4",
    "UINT32": "<u4",
    "INT64": "<i8",
    "UINT64": "<u8",
    "FLOAT32": "<f4",
    "FLOAT64": "<f8",
}
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


@dataclass
class ImplicitTile:
    """One available tile: its address, the volume and error its subdivision derives, the
    facts its metadata declares (semantic → value) and its content's path (or None)."""

    level: int
    x: int
    y: int
    volume: dict[str, Any]
    error: float
    metadata: dict[str, Any]
    content: Path | None

    @property
    def declared_volume(self) -> dict[str, Any]:
        """The volume clients that read tile metadata use."""
        m = self.metadata
        for key, name in (
            ("TILE_BOUNDING_BOX", "box"),
            ("TILE_BOUNDING_REGION", "region"),
            ("TILE_BOUNDING_SPHERE", "sphere"),
        ):
            if key in m:
                return {name: [float(v) for v in np.ravel(m[key])]}
        if "region" in self.volume and ("TILE_MINIMUM_HEIGHT" in m or "TILE_MAXIMUM_HEIGHT" in m):
            region = list(self.volume["region"])
            region[4] = float(m.get("TILE_MINIMUM_HEIGHT", region[4]))
            region[5] = float(m.get("TILE_MAXIMUM_HEIGHT", region[5]))
            return {"region": region}
        return self.volume

    @property
    def declared_error(self) -> float:
        """The geometricError clients that read tile metadata use."""
        return float(self.metadata.get("TILE_GEOMETRIC_ERROR", self.error))


def _morton_decode(index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of Morton indices: x from the even bits, y from the odd ones."""
    index = np.asarray(index, dtype=np.int64)
    x = np.zeros_like(index)
    y = np.zeros_like(index)
    for bit in range(31):
        x |= ((index >> (2 * bit)) & 1) << bit
        y |= ((index >> (2 * bit + 1)) & 1) << bit
    return x, y


def _subdivide(volume: dict[str, Any], level: int, x: int, y: int) -> dict[str, Any]:
    """The volume implicit QUADTREE subdivision gives tile (level, x, y) of a root's."""
    n = 2**level
    if "region" in volume:
        w, s, e, north, lo, hi = volume["region"]
        dx, dy = (e - w) / n, (north - s) / n
        return {"region": [w + x * dx, s + y * dy, w + (x + 1) * dx, s + (y + 1) * dy, lo, hi]}
    if "box" in volume:
        b = np.asarray(volume["box"], dtype=np.float64)
        c, ax, ay, az = b[:3], b[3:6], b[6:9], b[9:12]
        center = c + ax * ((2 * x + 1) / n - 1) + ay * ((2 * y + 1) / n - 1)
        return {"box": [*center, *(ax / n), *(ay / n), *az]}
    raise StoreError("implicit tiling needs a region or box root volume (spheres do not split)")


class _Subtree:
    """One parsed .subtree file (binary or JSON)."""

    def __init__(self, path: Path) -> None:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise StoreError(f"{path} (a subtree) is not readable: {exc}") from exc
        try:
            if data[:4] == b"subt":
                _, _, json_len, bin_len = struct.unpack_from("<4sIQQ", data, 0)
                self.doc = json.loads(data[24 : 24 + json_len])
                self.blob = data[24 + json_len : 24 + json_len + bin_len]
            else:
                self.doc = json.loads(data)
                self.blob = b""
        except (ValueError, struct.error) as exc:
            raise StoreError(f"{path} does not parse as a subtree: {exc}") from exc
        self.path = path

    def view(self, index: int) -> bytes:
        view = self.doc["bufferViews"][index]
        buffer = self.doc["buffers"][view["buffer"]]
        if "uri" in buffer:
            data = (self.path.parent / buffer["uri"]).read_bytes()
        else:
            data = self.blob
        start = view.get("byteOffset", 0)
        return data[start : start + view["byteLength"]]

    def bits(self, availability: dict[str, Any], count: int) -> np.ndarray:
        """(count,) bool of an availability object (bitstream or constant)."""
        if "constant" in availability:
            return np.full(count, bool(availability["constant"]))
        raw = np.frombuffer(self.view(availability["bitstream"]), dtype=np.uint8)
        return np.unpackbits(raw, bitorder="little")[:count].astype(bool)

    def table(self, schema: dict[str, Any], rows: int) -> dict[str, np.ndarray]:
        """Semantic → (rows, k) values of the tile metadata property table."""
        if "tileMetadata" not in self.doc:
            return {}
        table = self.doc["propertyTables"][self.doc["tileMetadata"]]
        klass = (schema.get("classes") or {}).get(table["class"], {})
        out = {}
        for name, prop in (table.get("properties") or {}).items():
            spec = (klass.get("properties") or {}).get(name, {})
            semantic = spec.get("semantic")
            if semantic is None:
                continue
            dtype = np.dtype(_DTYPES[spec.get("componentType", "FLOAT64")])
            width = _COMPONENTS[spec.get("type", "SCALAR")] * int(spec.get("count", 1))
            values = np.frombuffer(self.view(prop["values"]), dtype=dtype, count=rows * width)
            out[semantic] = values.reshape(rows, width).astype(np.float64)
        return out


def implicit_tiles(raw: dict[str, Any], base: Path, schema: dict[str, Any]) -> list[ImplicitTile]:
    """Every available tile of the implicit tile ``raw`` (tileset JSON, relative to ``base``),
    parents before children; StoreError naming a subtree that is missing or damaged."""
    tiling = raw["implicitTiling"]
    if tiling.get("subdivisionScheme") != "QUADTREE":
        raise StoreError(
            f"implicit subdivision {tiling.get('subdivisionScheme')!r} is not checked (QUADTREE)"
        )
    levels = int(tiling["subtreeLevels"])
    available = int(tiling["availableLevels"])
    uri = tiling["subtrees"]["uri"]
    content_uri = (raw.get("content") or {}).get("uri")
    root_volume = raw["boundingVolume"]
    root_error = float(raw["geometricError"])
    size = (4**levels - 1) // 3
    # Local (level, x, y) of every bit of a subtree.
    local: list[tuple[int, int, int]] = []
    for d in range(levels):
        xs, ys = _morton_decode(np.arange(4**d))
        local.extend((d, int(a), int(b)) for a, b in zip(xs, ys, strict=True))
    out: list[ImplicitTile] = []
    queue = [(0, 0, 0)]
    while queue:
        level0, x0, y0 = queue.pop(0)
        path = base / uri.format(level=level0, x=x0, y=y0)
        sub = _Subtree(path)
        tiles = sub.bits(sub.doc.get("tileAvailability", {"constant": 0}), size)
        contents = [sub.bits(c, size) for c in sub.doc.get("contentAvailability", [])]
        children = sub.bits(sub.doc.get("childSubtreeAvailability", {"constant": 0}), 4**levels)
        table = sub.table(schema, int(tiles.sum()))
        for row, bit in enumerate(np.flatnonzero(tiles).tolist()):
            d, lx, ly = local[bit]
            level, x, y = level0 + d, (x0 << d) + lx, (y0 << d) + ly
            if level >= available:
                raise StoreError(f"{path}: tile {level}/{x}/{y} is beyond availableLevels")
            has = bool(contents and contents[0][bit])
            metadata = {k: (v[row] if v.shape[1] > 1 else v[row, 0]) for k, v in table.items()}
            out.append(
                ImplicitTile(
                    level,
                    x,
                    y,
                    _subdivide(root_volume, level, x, y),
                    root_error / 2**level,
                    metadata,
                    base / content_uri.format(level=level, x=x, y=y)
                    if has and content_uri
                    else None,
                )
            )
        for k in np.flatnonzero(children).tolist():
            cx, cy = _morton_decode(np.array([k]))
            queue.append(
                (level0 + levels, (x0 << levels) + int(cx[0]), (y0 << levels) + int(cy[0]))
            )
    out.sort(key=lambda t: (t.level, t.x, t.y))
    return out
