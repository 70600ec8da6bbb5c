"""3D Tiles 1.1 implicit tiling: quadtree addresses, availability, subtree files.

An implicit tileset names its tiles by (level, x, y) in a QUADTREE and lists which exist in
binary ``.subtree`` files (one per ``SUBTREE_LEVELS`` levels): a tile availability bitstream
(bit = (4^local level − 1) / 3 + Morton index of the tile's local x, y; least significant
bit first), a content availability bitstream and the availability of the child subtrees.
Per-tile facts the subdivision cannot derive go into a property table of the subtree (tile
metadata, one row per available tile in bit order), read through the tileset's ``schema``:
semantics ``TILE_GEOMETRIC_ERROR``, ``TILE_BOUNDING_REGION``/``BOX``, ``TILE_MINIMUM_HEIGHT``...
override what clients derive (halved errors, quadrants of the root's volume).

``quadtree_addresses`` maps an approximation tree's nodes onto a quadtree (a child's quadrant
is where its rectangle's centre lies in its parent's), ``write_subtrees`` writes the files.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from approxtree.errors import InvalidParameterError

#: Levels per subtree file: 6 levels are 1365 tiles, a 171-byte availability bitstream.
SUBTREE_LEVELS = 6
#: Where subtrees and contents live, relative to tileset.json.
SUBTREE_URI = "subtrees/{level}/{x}/{y}.subtree"
#: Component types of property values written (name in the schema → numpy dtype).
COMPONENT_TYPES = {"FLOAT64": "<f8", "FLOAT32": "<f4", "UINT32": "<u4"}


def quadtree_addresses(rects: np.ndarray, parents: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """(n, 3) int64 (level, x, y) of each node: the root (0, 0, 0); a child at (level + 1,
    2x + east, 2y + north), east/north: its rectangle's centre lies east/north of its parent's.

    rects: (n, 4) xmin, ymin, xmax, ymax; parents, levels: (n,) in the tree's node order
    (parents before children). InvalidParameterError when two children share a quadrant.
    """
    r = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    parents = np.asarray(parents, dtype=np.int64)
    cx, cy = (r[:, 0] + r[:, 2]) / 2, (r[:, 1] + r[:, 3]) / 2
    out = np.zeros((len(r), 3), dtype=np.int64)
    for level in range(1, int(np.max(levels, initial=0)) + 1):
        nodes = np.flatnonzero(levels == level)
        p = parents[nodes]
        out[nodes, 0] = level
        out[nodes, 1] = 2 * out[p, 1] + (cx[nodes] > cx[p])
        out[nodes, 2] = 2 * out[p, 2] + (cy[nodes] > cy[p])
    if len(np.unique(out, axis=0)) != len(out):
        raise InvalidParameterError(
            "Two children of a node fall in the same quadrant: implicit tiling needs a tree "
            "whose nodes split into at most 4 quadrants (build it with --fanout 4)."
        )
    return out


def morton(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n,) int64 Morton (Z-order) index of (x, y): x in the even bits, y in the odd ones."""
    x = np.asarray(x, dtype=np.int64)
    y = np.asarray(y, dtype=np.int64)
    out = np.zeros(np.broadcast(x, y).shape, dtype=np.int64)
    for bit in range(31):
        out |= ((x >> bit) & 1) << (2 * bit)
        out |= ((y >> bit) & 1) << (2 * bit + 1)
    return out


def _bitstream(bits: np.ndarray) -> dict | bytes:
    """A bitstream's bytes, or its constant when all bits are equal."""
    if bits.all() or not bits.any():
        return {"constant": int(bool(bits.all()))}
    return np.packbits(bits.astype(np.uint8), bitorder="little").tobytes()


def subtree_bytes(
    tiles: np.ndarray,
    contents: np.ndarray,
    children: np.ndarray,
    table: dict[str, np.ndarray] | None = None,
    types: dict[str, str] | None = None,
) -> bytes:
    """One binary subtree file.

    tiles, contents: (k,) bool availability over the subtree's tile indices; children:
    (4^levels,) bool availability of the child subtrees; table: property name → (rows, c)
    values of the available tiles in bit order (tile metadata), typed by ``types`` (name →
    component type, FLOAT64 by default).
    """
    views: list[dict] = []
    chunks: list[bytes] = []
    offset = 0

    def view(data: bytes) -> int:
        nonlocal offset
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data)})
        # Buffer views start on 8-byte boundaries.
        chunks.append(data + b"\0" * ((-len(data)) % 8))
        offset += len(chunks[-1])
        return len(views) - 1

    def availability(bits: np.ndarray) -> dict:
        stream = _bitstream(bits)
        if isinstance(stream, dict):
            return stream
        return {"bitstream": view(stream), "availableCount": int(bits.sum())}

    doc: dict = {
        "tileAvailability": availability(tiles),
        "contentAvailability": [availability(contents)],
        "childSubtreeAvailability": availability(children),
    }
    if table:
        rows = int(tiles.sum())
        properties = {}
        for name, values in table.items():
            dtype = COMPONENT_TYPES[(types or {}).get(name, "FLOAT64")]
            v = np.ascontiguousarray(values, dtype=dtype).reshape(rows, -1)
            properties[name] = {"values": view(v.tobytes())}
        doc["propertyTables"] = [{"class": "tile", "count": rows, "properties": properties}]
        doc["tileMetadata"] = 0
    if chunks:
        doc["buffers"] = [{"byteLength": offset}]
        doc["bufferViews"] = views
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * ((-len(text)) % 8)
    blob = b"".join(chunks)
    return struct.pack("<4sIQQ", b"subt", 1, len(text), len(blob)) + text + blob


def write_subtrees(
    folder: Path,
    addresses: np.ndarray,
    has_content: np.ndarray,
    table: dict[str, np.ndarray] | None = None,
    types: dict[str, str] | None = None,
    levels: int = SUBTREE_LEVELS,
) -> int:
    """Write the subtree files of the tiles at ``addresses`` (n, 3) (level, x, y) under
    ``folder`` (``SUBTREE_URI``); has_content: (n,) bool; table: property name → (n, c) values
    per tile (tile metadata). Returns the number of files. Every tile's parent must be there."""
    addresses = np.asarray(addresses, dtype=np.int64).reshape(-1, 3)
    level, x, y = addresses.T
    # Each tile's subtree: the root of its block of levels.
    depth = level % levels
    root_level = level - depth
    sx, sy = x >> depth, y >> depth
    index = (4**depth - 1) // 3 + morton(x - (sx << depth), y - (sy << depth))
    size = (4**levels - 1) // 3
    key = np.stack([root_level, sx, sy], axis=1)
    roots, owner = np.unique(key, axis=0, return_inverse=True)
    owner = owner.ravel()
    # A subtree's child subtrees: the subtree roots one block of levels below it.
    child_of: dict[tuple[int, int, int], list[tuple[int, int]]] = {}
    for rl, rx, ry in roots.tolist():
        if rl > 0:
            parent = (rl - levels, rx >> levels, ry >> levels)
            child_of.setdefault(parent, []).append(
                (rx - (parent[1] << levels), ry - (parent[2] << levels))
            )
    for k, (rl, rx, ry) in enumerate(roots.tolist()):
        mine = np.flatnonzero(owner == k)
        order = mine[np.argsort(index[mine], kind="stable")]
        tiles = np.zeros(size, dtype=bool)
        contents = np.zeros(size, dtype=bool)
        tiles[index[order]] = True
        contents[index[order]] = has_content[order]
        children = np.zeros(4**levels, dtype=bool)
        for cx, cy in child_of.get((rl, rx, ry), []):
            children[int(morton(np.array([cx]), np.array([cy]))[0])] = True
        rows = None if table is None else {n: v[order] for n, v in table.items()}
        path = folder / SUBTREE_URI.format(level=rl, x=rx, y=ry)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(subtree_bytes(tiles, contents, children, rows, types))
    return len(roots)


def implicit_tiling(available_levels: int, levels: int = SUBTREE_LEVELS) -> dict:
    """A tile's ``implicitTiling`` object (QUADTREE, subtrees at ``SUBTREE_URI``)."""
    return {
        "subdivisionScheme": "QUADTREE",
        "subtreeLevels": levels,
        "availableLevels": available_levels,
        "subtrees": {"uri": SUBTREE_URI},
    }
