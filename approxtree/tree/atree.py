"""The legacy .atree file, read only: one versioned, checksummed file holding a whole tree.

approxtree no longer writes it: trees are saved as tree stores (``tree.store``), and
``approxtree convert OLD.atree NEW.zarr`` copies an old file into one. ``TreeFile`` opens it
as the ``TreeSource`` that ``tree.store.open_store`` returns for a .atree path.

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
node's patch is read and verified on its own, and truncation or corruption anywhere is
reported as a StoreError.

Tree kinds: ``meta["tree_kind"]`` names what the file holds; absent (files of earlier
versions) or "approximation_tree" is an ApproximationTree as above; "point_quadtree" is a
PointQuadtree (seed 003): sections "terrain" and "quadtree" (nodes, errors, lattice heights,
insertion orders; ``tree.point_quadtree``) and no patches.
"""

from __future__ import annotations

import json
import mmap
import os
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.geometry import TERRAIN_TYPES
from approxtree.geometry.base import GeometryData
from approxtree.patches.records import Batch, concat_records

MAGIC = b"ATREE\x00\r\n"
#: Versions this reader opens; version 1's header CRC left out the 24-byte prefix.
READ_VERSIONS = (1, 2)
#: The first bytes of a zip file: the .npz files of point quadtrees of earlier versions.
_ZIP_MAGIC = b"PK\x03\x04"
_PREFIX = struct.Struct("<8sIIII")
_ALIGN = 8

Record = tuple[dict[str, Any], dict[str, np.ndarray]]


def _pad(n: int) -> int:
    return (-n) % _ALIGN


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


def is_legacy_path(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a legacy .atree file (by its suffix)."""
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


def refuse_legacy_target(path: str | os.PathLike) -> None:
    """InvalidParameterError when a tree is to be written to a .atree path: that format is
    read only now."""
    if is_legacy_path(path):
        raise InvalidParameterError(
            f"Cannot write {path}: approxtree no longer writes the legacy .atree tree file. "
            "Save the tree as a tree store: a folder NAME.zarr, a single file NAME.zarr.zip or "
            "an fsspec URL (`approxtree convert OLD.atree NEW.zarr` copies an old file into one)."
        )


class TreeFile:
    """A tree file opened read-only through a memory map; sections and patches on demand.

    The ``TreeSource`` of a .atree file (``tree.store``): meta, terrain, node arrays or
    quadtree arrays, and each node's patch record, every one checked against its CRC-32.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.location = str(path)
        if not self.path.is_file():
            raise StoreError(f"Tree file {self.path} does not exist.")
        size = self.path.stat().st_size
        with open(self.path, "rb") as f:
            head = f.read(len(_ZIP_MAGIC))
            if head == _ZIP_MAGIC:
                raise StoreError(
                    f"{self.path} is a zip file, such as the point quadtree .npz files of an "
                    "earlier version, which are no longer read; rebuild it with `approxtree "
                    "build POINTS --kind point-quadtree`."
                )
            if size < _PREFIX.size:
                raise StoreError(
                    f"{self.path} is not an approxtree tree file (only {size} bytes); rebuild it "
                    "with `approxtree build`."
                )
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
        #: The file's format version (1 or 2).
        self.version: int = version
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

    # -- the TreeSource of tree.store ----------------------------------------------------------

    @property
    def tree_kind(self) -> str:
        """The tree kind: "approximation_tree" (also when absent) or "point_quadtree"."""
        return str(self.meta.get("tree_kind", "approximation_tree"))

    def terrain(self) -> GeometryData:
        """The terrain of the "terrain" section."""
        return TERRAIN_TYPES[self.meta["terrain_kind"]].from_record(*self.section("terrain"))

    def node_arrays(self) -> dict[str, np.ndarray]:
        """The node table of an approximation tree (read-only (n, ...) arrays)."""
        return self.section("nodes")[1]

    def quadtree_arrays(self) -> dict[str, np.ndarray]:
        """The "quadtree" section of a point quadtree (``PointQuadtree.to_sections``)."""
        return self.section("quadtree")[1]

    def records(self, nodes: np.ndarray, strategy: str) -> Batch:
        """The patch records of ``nodes`` (one strategy) as a batch, each one verified."""
        return concat_records([self.patch_record(int(i))[1] for i in nodes])

    def verify(self) -> None:
        """Check every patch now (the sections are checked whenever they are read)."""
        self.verify_patches()
