"""The .atree file: one versioned, checksummed file holding a whole approximation tree.

Layout (all integers little-endian)::

    0   8 bytes  magic b"ATREE\\x00\\r\\n"
    8   u32      format version
    12  u32      header length H
    16  u32      CRC-32 of bytes 0–15, 20–23 and the header (version 1: of the header only)
    20  u32      reserved (0)
    24  H bytes  header: UTF-8 JSON {file_size, meta, sections: {name: [offset, length, crc]}}
    ... sections, each a *record*, 8-byte aligned: "terrain", "nodes", "patch_index"
    ... one record per node patch; "patch_index" holds their offsets, lengths and CRC-32s

Every byte is covered: the prefix and header by the header CRC (the reserved field must be 0),
then sections and patches tile the rest of the file exactly (no gap, no overlap, checked on
open), each under its own CRC-32.

A record is ``u32 manifest length M``, M bytes of JSON ``{"attrs": ..., "arrays": [[name,
dtype, shape, offset, nbytes], ...]}``, then the array bytes. No pickle: only JSON and raw
little-endian arrays are ever read. Every section and every patch has its own CRC-32, so one
node's patch can be read and verified on its own, and truncation or corruption anywhere is
reported as a StoreError. Files are written atomically.

Tree kinds: ``meta["tree_kind"]`` names what the file holds; absent (files of earlier
versions) or "approximation_tree" is an ApproximationTree as above; "point_quadtree" is a
PointQuadtree (seed 003): sections "terrain" and "quadtree" (nodes, errors, lattice heights,
insertion orders; ``tree.point_quadtree``) and no patches. ``approxtree.load_tree`` opens
either.
"""

from __future__ import annotations

import json
import mmap
import os
import struct
import zlib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import StoreError
from approxtree.io.atomic import atomic_write

MAGIC = b"ATREE\x00\r\n"
FORMAT_VERSION = 2
#: Versions this reader opens; version 1's header CRC left out the 24-byte prefix.
READ_VERSIONS = (1, 2)
_PREFIX = struct.Struct("<8sIIII")
_ALIGN = 8

Record = tuple[dict[str, Any], dict[str, np.ndarray]]


def _pad(n: int) -> int:
    return (-n) % _ALIGN


def encode_record(attrs: dict[str, Any], arrays: dict[str, np.ndarray]) -> list[memoryview]:
    """A record as a list of byte chunks (arrays are not copied when already little-endian)."""
    entries = []
    chunks: list[memoryview] = []
    offset = 0
    for name, value in arrays.items():
        a = np.asarray(value)
        a = np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<"), copy=False))
        entries.append([name, a.dtype.str, list(a.shape), offset, a.nbytes])
        # memoryview cannot cast an empty array; an empty array has no bytes to write anyway.
        if a.nbytes:
            chunks.append(memoryview(a.reshape(-1)).cast("B"))
        pad = _pad(a.nbytes)
        if pad:
            chunks.append(memoryview(bytes(pad)))
        offset += a.nbytes + pad
    manifest = json.dumps({"attrs": attrs, "arrays": entries}).encode()
    head = struct.pack("<I", len(manifest)) + manifest
    head += bytes(_pad(len(head)))
    return [memoryview(head), *chunks]


def decode_record(buf: memoryview) -> Record:
    """Attributes and arrays of a record; arrays are read-only views into ``buf``."""
    try:
        (mlen,) = struct.unpack_from("<I", buf, 0)
        manifest = json.loads(bytes(buf[4 : 4 + mlen]))
        base = 4 + mlen + _pad(4 + mlen)
        arrays = {}
        for name, dtype, shape, offset, nbytes in manifest["arrays"]:
            start = base + offset
            if start + nbytes > len(buf):
                raise StoreError("an array runs past the end of its record")
            arrays[name] = np.frombuffer(
                buf[start : start + nbytes], dtype=np.dtype(dtype)
            ).reshape(shape)
        return manifest["attrs"], arrays
    except StoreError:
        raise
    except (ValueError, KeyError, TypeError, struct.error) as exc:
        raise StoreError(f"malformed record in tree file: {exc}") from exc


def _header_crc(version: int, prefix: bytes | memoryview, header: bytes | memoryview) -> int:
    """The CRC-32 stored at offset 16: over bytes 0–15, 20–23 and the header (version 2)."""
    if version == 1:
        return zlib.crc32(header)
    return zlib.crc32(header, zlib.crc32(prefix[20:24], zlib.crc32(prefix[:16])))


def _crc(chunks: Iterable[memoryview]) -> tuple[int, int]:
    """(CRC-32, total length) of a sequence of chunks."""
    crc, n = 0, 0
    for c in chunks:
        crc = zlib.crc32(c, crc)
        n += len(c)
    return crc, n


def write_tree_file(
    path: str | os.PathLike,
    meta: dict[str, Any],
    sections: dict[str, Record],
    patches: list[Record],
    patch_kinds: np.ndarray,
) -> int:
    """Write the file atomically; returns its size in bytes."""
    encoded = {name: encode_record(*rec) for name, rec in sections.items()}
    patch_chunks = [encode_record(*rec) for rec in patches]
    patch_sums = [_crc(c) for c in patch_chunks]
    # Offsets depend on the header's length, which depends on the offsets: the patch index
    # stores offsets relative to the start of the patch area, so one pass is enough.
    rel = np.zeros(len(patches), dtype="<i8")
    if patches:
        lengths = np.array([n for _, n in patch_sums], dtype="<i8")
        rel[1:] = np.cumsum(lengths)[:-1]
    else:
        lengths = np.zeros(0, dtype="<i8")
    encoded["patch_index"] = encode_record(
        {},
        {
            "offset": rel,
            "length": lengths,
            "crc": np.array([c for c, _ in patch_sums], dtype="<u4"),
            "kind": np.asarray(patch_kinds, dtype="<u1"),
        },
    )
    sums = {name: _crc(chunks) for name, chunks in encoded.items()}

    def header_bytes(offsets: dict[str, int], patch_base: int, file_size: int) -> bytes:
        table = {n: [offsets[n], sums[n][1], sums[n][0]] for n in encoded}
        h = json.dumps(
            {"file_size": file_size, "patch_base": patch_base, "meta": meta, "sections": table}
        ).encode()
        return h + b" " * _pad(_PREFIX.size + len(h))

    # Fixed point on the header length (its numbers change width at most a couple of times).
    header = header_bytes({n: 0 for n in encoded}, 0, 0)
    for _ in range(5):
        pos = _PREFIX.size + len(header)
        offsets = {}
        for name in encoded:
            offsets[name] = pos
            pos += sums[name][1]
        patch_base = pos
        file_size = pos + int(lengths.sum())
        new_header = header_bytes(offsets, patch_base, file_size)
        if len(new_header) == len(header):
            header = new_header
            break
        header = new_header
    else:  # pragma: no cover - the loop converges in two passes
        raise StoreError("could not lay out the tree file header")
    unsigned = _PREFIX.pack(MAGIC, FORMAT_VERSION, len(header), 0, 0)
    crc = _header_crc(FORMAT_VERSION, unsigned, header)
    prefix = _PREFIX.pack(MAGIC, FORMAT_VERSION, len(header), crc, 0)
    with atomic_write(path) as f:
        f.write(prefix)
        f.write(header)
        for name in encoded:
            for c in encoded[name]:
                f.write(c)
        for chunks in patch_chunks:
            for c in chunks:
                f.write(c)
    return file_size


def is_legacy_path(path: str | os.PathLike) -> bool:
    """Whether a tree written to ``path`` is a legacy .atree file (by its suffix)."""
    return "://" not in str(path) and str(path).lower().endswith(".atree")


def is_legacy_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is read by this module: any file but a zip (tree stores are folders,
    zips and URLs), or a missing .atree path (so that the legacy reader reports it)."""
    if "://" in str(path):
        return False
    p = Path(path)
    if p.is_file():
        return not str(path).lower().endswith(".zip")
    return is_legacy_path(path) and not p.exists()


class TreeFile:
    """A tree file opened read-only through a memory map; sections and patches on demand."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise StoreError(f"Tree file {self.path} does not exist.")
        size = self.path.stat().st_size
        if size < _PREFIX.size:
            raise StoreError(
                f"{self.path} is not an approxtree tree file (only {size} bytes); rebuild it "
                "with `approxtree build`."
            )
        with open(self.path, "rb") as f:
            self._mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        self.buf = memoryview(self._mm)
        magic, version, hlen, hcrc, reserved = _PREFIX.unpack_from(self.buf, 0)
        if magic != MAGIC:
            raise StoreError(
                f"{self.path} is not an approxtree tree file (bad magic bytes); rebuild it with "
                "`approxtree build`."
            )
        if version not in READ_VERSIONS:
            raise StoreError(
                f"{self.path} has tree format version {version}; this approxtree reads versions "
                f"{', '.join(map(str, READ_VERSIONS))}. Convert it to a tree store with "
                "`approxtree convert OLD.atree NEW.zarr` (using the approxtree that wrote it), "
                "or rebuild the tree with this version."
            )
        raw = self.buf[_PREFIX.size : _PREFIX.size + hlen]
        prefix = self.buf[: _PREFIX.size]
        if len(raw) != hlen or _header_crc(version, prefix, raw) != hcrc:
            raise StoreError(f"{self.path} is corrupted: header checksum mismatch. Rebuild it.")
        # Version 1 left the reserved field out of every checksum: it must hold its zeros.
        if reserved != 0:
            raise StoreError(f"{self.path} is corrupted: reserved header bytes set. Rebuild it.")
        try:
            header = json.loads(bytes(raw))
            file_size = int(header["file_size"])
            self.meta: dict[str, Any] = header["meta"]
            self._sections: dict[str, list[int]] = header["sections"]
            self._patch_base: int = int(header["patch_base"])
        except (ValueError, KeyError, TypeError) as exc:
            raise StoreError(f"{self.path} is corrupted: malformed header ({exc}).") from exc
        if file_size != size:
            raise StoreError(
                f"{self.path} is truncated or padded: {size} bytes, expected "
                f"{file_size}. Rebuild it."
            )
        self.patch_index = self.section("patch_index")[1]
        self._check_tiling(_PREFIX.size + hlen, size)

    def _check_tiling(self, start: int, size: int) -> None:
        """Sections, then patches, must cover bytes ``start``..``size`` exactly, so that no
        byte of the file escapes every checksum."""
        try:
            spans = sorted((int(o), int(n)) for o, n, _ in self._sections.values())
        except (ValueError, TypeError) as exc:
            raise StoreError(f"{self.path} is corrupted: malformed section table.") from exc
        pos = start
        for offset, length in spans:
            if offset != pos or length < 0:
                raise StoreError(
                    f"{self.path} is corrupted: sections leave a gap or overlap at byte {pos}. "
                    "Rebuild it."
                )
            pos += length
        offsets = np.asarray(self.patch_index["offset"], dtype=np.int64)
        lengths = np.asarray(self.patch_index["length"], dtype=np.int64)
        ends = np.cumsum(lengths)
        tiled = (
            pos == self._patch_base
            and offsets.shape == lengths.shape
            and not (lengths < 0).any()
            and (offsets[1:] == ends[:-1]).all()
            and (len(offsets) == 0 or offsets[0] == 0)
            and self._patch_base + int(ends[-1] if len(ends) else 0) == size
        )
        if not tiled:
            raise StoreError(
                f"{self.path} is corrupted: patch records do not tile the patch area. Rebuild it."
            )

    def section(self, name: str) -> Record:
        """A verified section record."""
        if name not in self._sections:
            raise StoreError(f"{self.path} has no section {name!r}.")
        offset, length, crc = self._sections[name]
        return decode_record(self._checked(offset, length, crc, f"section {name!r}"))

    def _checked(self, offset: int, length: int, crc: int, what: str) -> memoryview:
        chunk = self.buf[offset : offset + length]
        if len(chunk) != length or zlib.crc32(chunk) != crc:
            raise StoreError(f"{self.path} is corrupted: checksum mismatch in {what}. Rebuild it.")
        return chunk

    def section_span(self, name: str) -> tuple[int, int]:
        """(offset, length) in bytes of a section inside the file."""
        offset, length, _ = self._sections[name]
        return offset, length

    def patch_span(self, i: int) -> tuple[int, int]:
        """(offset, length) in bytes of node i's patch record inside the file."""
        pi = self.patch_index
        return self._patch_base + int(pi["offset"][i]), int(pi["length"][i])

    def patch_record(self, i: int) -> Record:
        """The verified record of node i's patch."""
        pi = self.patch_index
        offset = self._patch_base + int(pi["offset"][i])
        return decode_record(
            self._checked(offset, int(pi["length"][i]), int(pi["crc"][i]), f"patch of node {i}")
        )

    def verify_patches(self) -> None:
        """Check the CRC of every patch record (one pass over the patch area)."""
        pi = self.patch_index
        for i in range(len(pi["offset"])):
            offset = self._patch_base + int(pi["offset"][i])
            self._checked(offset, int(pi["length"][i]), int(pi["crc"][i]), f"patch of node {i}")
