"""A writer of legacy .atree tree files (format 2), for the tests of the reader only.

approxtree reads .atree files but no longer writes them (``approxtree.tree.atree``); the tests
that check the reader (checksums, truncation, versions, conversion to a store) make their files
here, with the layout of the writer approxtree shipped until then, byte for byte, from the
trees' public API (``to_record``, ``patch``, ``to_sections``).
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from approxtree import ApproximationTree, PointQuadtree

MAGIC = b"ATREE\x00\r\n"
FORMAT_VERSION = 2
PREFIX = struct.Struct("<8sIIII")
ALIGN = 8
NODE_ARRAYS = (
    "rects",
    "errors",
    "bboxes",
    "levels",
    "parents",
    "child_start",
    "child_count",
    "strategies",
)

Record = tuple[dict[str, Any], dict[str, np.ndarray]]


def _pad(n: int) -> int:
    return (-n) % ALIGN


def encode_record(attrs: dict[str, Any], arrays: dict[str, np.ndarray]) -> bytes:
    """A record: u32 manifest length, the JSON manifest, then the little-endian arrays, each
    8-byte aligned."""
    entries = []
    chunks = []
    offset = 0
    for name, value in arrays.items():
        a = np.asarray(value)
        a = np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<"), copy=False))
        entries.append([name, a.dtype.str, list(a.shape), offset, a.nbytes])
        chunks.append(a.tobytes() + bytes(_pad(a.nbytes)))
        offset += a.nbytes + _pad(a.nbytes)
    manifest = json.dumps({"attrs": attrs, "arrays": entries}).encode()
    head = struct.pack("<I", len(manifest)) + manifest
    head += bytes(_pad(len(head)))
    return head + b"".join(chunks)


def write_tree_file(
    path: str | os.PathLike,
    meta: dict[str, Any],
    sections: dict[str, Record],
    patches: list[Record],
    patch_kinds: np.ndarray,
) -> int:
    """Write a .atree file (format 2); returns its size in bytes."""
    encoded = {name: encode_record(*rec) for name, rec in sections.items()}
    patch_bytes = [encode_record(*rec) for rec in patches]
    lengths = np.array([len(b) for b in patch_bytes], dtype="<i8")
    # Patch offsets are relative to the start of the patch area.
    rel = np.zeros(len(patches), dtype="<i8")
    if len(patches):
        rel[1:] = np.cumsum(lengths)[:-1]
    encoded["patch_index"] = encode_record(
        {},
        {
            "offset": rel,
            "length": lengths,
            "crc": np.array([zlib.crc32(b) for b in patch_bytes], dtype="<u4"),
            "kind": np.asarray(patch_kinds, dtype="<u1"),
        },
    )

    def header_bytes(offsets: dict[str, int], patch_base: int, file_size: int) -> bytes:
        table = {n: [offsets[n], len(b), zlib.crc32(b)] for n, b in encoded.items()}
        h = json.dumps(
            {"file_size": file_size, "patch_base": patch_base, "meta": meta, "sections": table}
        ).encode()
        return h + b" " * _pad(PREFIX.size + len(h))

    # Fixed point on the header length (its numbers change width at most a couple of times).
    header = header_bytes(dict.fromkeys(encoded, 0), 0, 0)
    for _ in range(5):
        pos = PREFIX.size + len(header)
        offsets = {}
        for name, b in encoded.items():
            offsets[name] = pos
            pos += len(b)
        new_header = header_bytes(offsets, pos, pos + int(lengths.sum()))
        done = len(new_header) == len(header)
        header = new_header
        if done:
            break
    # The header CRC covers bytes 0–15, the reserved bytes 20–23 and the header.
    unsigned = PREFIX.pack(MAGIC, FORMAT_VERSION, len(header), 0, 0)
    crc = zlib.crc32(header, zlib.crc32(unsigned[20:24], zlib.crc32(unsigned[:16])))
    prefix = PREFIX.pack(MAGIC, FORMAT_VERSION, len(header), crc, 0)
    data = prefix + header + b"".join(encoded.values()) + b"".join(patch_bytes)
    Path(path).write_bytes(data)
    return len(data)


def write_atree(tree: ApproximationTree | PointQuadtree, path: str | os.PathLike) -> int:
    """Write ``tree`` as the .atree file approxtree wrote before; returns its size in bytes."""
    if isinstance(tree, PointQuadtree):
        meta, arrays = tree.to_sections()
        sections = {"terrain": tree.terrain.to_record(), "quadtree": ({}, arrays)}
        return write_tree_file(path, meta, sections, [], np.zeros(0, dtype=np.uint8))
    meta = {
        "library": "approxtree (tests/atree_writer.py)",
        "terrain_kind": tree.terrain.kind,
        "params": tree.params,
        "strategy_names": tree.strategy_names,
    }
    nodes = {name: getattr(tree, name) for name in NODE_ARRAYS}
    patches = [({}, tree.patch(i).to_record()) for i in range(len(tree))]
    sections = {"terrain": tree.terrain.to_record(), "nodes": ({}, nodes)}
    return write_tree_file(path, meta, sections, patches, tree.strategies)
