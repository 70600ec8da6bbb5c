"""LAS/LAZ layout checks: every size and offset of the file is validated before laspy reads it.

laspy and its LAZ backend lazrs trust the header: a VLR count of 808 million in a 2 KB file
makes laspy loop for ever, and a chunk table (or a layer size of a LAS 1.4 chunk) asking for
tens of GB makes lazrs abort the whole process (a Rust allocation failure, SIGABRT, which no
``except`` can catch). ``check_las_layout`` reads the header, the VLR and EVLR headers, the
LAZ chunk table and the chunk layer sizes with plain ``struct`` reads bounded by the file size,
and raises TerrainFormatError for anything that does not fit, so that laspy only ever sees
files whose every allocation is bounded by the file size or by the memory the points need.

Layout (ASPRS LAS 1.0-1.4, LASzip): a public header (227, 235, 375 or 393 bytes by version),
VLRs (54-byte header + payload), point records (record_length bytes each; LAZ: an int64 offset
to the chunk table, then the compressed chunks), the chunk table, then EVLRs (60-byte header +
payload, LAS 1.4).
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from approxtree.errors import TerrainFormatError
from approxtree.io._common import available_memory

#: Public header size of each LAS version (laspy reads these).
HEADER_SIZES = {(1, 0): 227, (1, 1): 227, (1, 2): 227, (1, 3): 235, (1, 4): 375, (1, 5): 393}
#: Size of one point record of each point format, without extra bytes.
POINT_SIZES = (20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67)

_VLR_HEADER = 54
_EVLR_HEADER = 60
_LASZIP_USER_ID = b"laszip encoded"
_LASZIP_RECORD_ID = 22204
#: LASzip compressors: 2 = point-wise chunked, 3 = layered chunked (LAS 1.4 formats 6-10).
_POINTWISE_CHUNKED, _LAYERED_CHUNKED = 2, 3
#: A chunk size of 2^32 - 1 means "variable": each chunk's point count is in the chunk table.
_VARIABLE_CHUNKS = 0xFFFFFFFF
# Layers of each LASzip item type in a layered chunk (BYTE14 has one layer per byte).
_ITEM_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1}
_BYTE14 = 14
#: Bytes of memory per point beyond its record: x, y, z in float64 twice (laspy's scaled
#: arrays, then the (n, 3) stack), plus the classification and slack.
_BYTES_PER_POINT = 64


@dataclass(frozen=True)
class LasLayout:
    """What the checks found: version, sizes and offsets of a LAS/LAZ file (all in bytes)."""

    version: tuple[int, int]
    header_size: int
    point_offset: int
    vlr_count: int
    point_format: int
    compressed: bool
    record_length: int
    point_count: int
    file_size: int


def _bad(path: Path, what: str) -> TerrainFormatError:
    """The error for a malformed file, naming it and saying what to do."""
    return TerrainFormatError(
        f"{path} is not a valid LAS/LAZ point cloud: {what}. The file is corrupt or truncated; "
        "export it again (or check it with lasinfo / pdal info)."
    )


def _read_at(f: BinaryIO, offset: int, size: int) -> bytes:
    f.seek(offset)
    return f.read(size)


def check_las_layout(path: Path, memory: int | None = None) -> LasLayout:
    """Validate the header, VLRs, EVLRs, point records and (LAZ) chunk table of a LAS/LAZ file.

    memory: bytes the points may take (default: the available memory). Raises
    TerrainFormatError for any field that does not fit the file or the memory.
    """
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(393)
        if len(head) < 4 or head[:4] != b"LASF":
            raise _bad(path, "it does not start with the signature 'LASF'")
        if len(head) < 227:
            raise _bad(path, f"the file has {size} bytes, fewer than a LAS header (227)")
        version = (head[24], head[25])
        if version not in HEADER_SIZES:
            raise _bad(path, f"unknown LAS version {version[0]}.{version[1]} (1.0 to 1.5 exist)")
        layout = _check_header(path, head, size, version)
        laszip = _check_vlrs(path, f, layout)
        point_end = _check_evlrs(path, f, head, layout)
        if layout.compressed:
            if laszip is None:
                raise _bad(path, "its points are compressed (LAZ) but it has no LASzip VLR")
            _check_laz(path, f, layout, laszip, point_end)
        else:
            need = layout.point_count * layout.record_length
            if layout.point_offset + need > point_end:
                raise _bad(
                    path,
                    f"its header claims {layout.point_count} points of {layout.record_length} "
                    f"bytes ({need} bytes) but only {point_end - layout.point_offset} bytes "
                    "follow the header",
                )
    _check_memory(path, layout, available_memory() if memory is None else memory)
    return layout


def _check_header(path: Path, head: bytes, size: int, version: tuple[int, int]) -> LasLayout:
    """The public header's sizes and offsets, checked against each other and the file size."""
    header_size, point_offset, vlr_count = struct.unpack_from("<HII", head, 94)
    format_byte, record_length, legacy_count = struct.unpack_from("<BHI", head, 104)
    if header_size < HEADER_SIZES[version]:
        raise _bad(
            path,
            f"header size {header_size} is smaller than a LAS {version[0]}.{version[1]} "
            f"header ({HEADER_SIZES[version]} bytes)",
        )
    if not header_size <= point_offset <= size:
        raise _bad(
            path,
            f"the point data offset {point_offset} lies outside header end {header_size} .. "
            f"file size {size}",
        )
    count = legacy_count
    if version >= (1, 4):
        (count,) = struct.unpack_from("<Q", head, 247)
    # Bit 7 without bit 6 marks LASzip compression (as laspy reads it); bits 0-5 the format.
    compressed = bool(format_byte & 0x80) and not format_byte & 0x40
    point_format = format_byte & 0x3F
    if point_format >= len(POINT_SIZES):
        raise _bad(path, f"unknown point format {point_format} (0 to 10 exist)")
    if record_length < POINT_SIZES[point_format]:
        raise _bad(
            path,
            f"point record length {record_length} is shorter than point format {point_format} "
            f"({POINT_SIZES[point_format]} bytes)",
        )
    return LasLayout(
        version, header_size, point_offset, vlr_count, point_format, compressed,
        record_length, count, size,
    )  # fmt: skip


def _check_vlrs(path: Path, f: BinaryIO, layout: LasLayout) -> bytes | None:
    """Walk the VLR headers between the header and the points; the LASzip VLR's payload."""
    room = layout.point_offset - layout.header_size
    if layout.vlr_count * _VLR_HEADER > room:
        raise _bad(
            path,
            f"its header claims {layout.vlr_count} VLRs, but only {room} bytes (room for "
            f"{room // _VLR_HEADER}) lie between the header and the points",
        )
    laszip = None
    pos = layout.header_size
    for i in range(layout.vlr_count):
        if pos + _VLR_HEADER > layout.point_offset:
            raise _bad(path, f"VLR {i} at offset {pos} runs past the point data offset")
        head = _read_at(f, pos, _VLR_HEADER)
        user_id = head[2:18].rstrip(b"\x00")
        record_id, length = struct.unpack_from("<HH", head, 18)
        end = pos + _VLR_HEADER + length
        if end > layout.point_offset:
            raise _bad(
                path,
                f"VLR {i} ({length} bytes at offset {pos}) runs past the point data offset "
                f"{layout.point_offset}",
            )
        if user_id == _LASZIP_USER_ID and record_id == _LASZIP_RECORD_ID:
            laszip = _read_at(f, pos + _VLR_HEADER, length)
        pos = end
    return laszip


def _check_evlrs(path: Path, f: BinaryIO, head: bytes, layout: LasLayout) -> int:
    """Walk the EVLR headers of a LAS 1.4 file; the end of the point data (the first EVLR)."""
    if layout.version < (1, 4):
        return layout.file_size
    start, count = struct.unpack_from("<QI", head, 235)
    if count == 0:
        return layout.file_size
    if not layout.point_offset <= start <= layout.file_size:
        raise _bad(path, f"the first EVLR's offset {start} lies outside the point data .. file end")
    if count * _EVLR_HEADER > layout.file_size - start:
        raise _bad(
            path,
            f"its header claims {count} EVLRs but only {layout.file_size - start} bytes follow "
            f"offset {start}",
        )
    pos = start
    for i in range(count):
        evlr = _read_at(f, pos, _EVLR_HEADER)
        if len(evlr) < _EVLR_HEADER:
            raise _bad(path, f"EVLR {i} at offset {pos} is cut off by the end of the file")
        (length,) = struct.unpack_from("<Q", evlr, 20)
        pos += _EVLR_HEADER + length
        if pos > layout.file_size:
            raise _bad(path, f"EVLR {i} ({length} bytes) runs past the end of the file")
    return start


@dataclass(frozen=True)
class _LasZip:
    """The fields of a LASzip VLR that size the decompression."""

    compressor: int
    chunk_size: int
    items: tuple[tuple[int, int], ...]  # (item type, item size)


def _parse_laszip(path: Path, payload: bytes, layout: LasLayout) -> _LasZip:
    """The LASzip VLR: compressor, chunk size and items, whose sizes must add up to a record."""
    if len(payload) < 34:
        raise _bad(path, f"its LASzip VLR has {len(payload)} bytes, fewer than 34")
    compressor = struct.unpack_from("<H", payload, 0)[0]
    chunk_size = struct.unpack_from("<I", payload, 12)[0]
    (n_items,) = struct.unpack_from("<H", payload, 32)
    if len(payload) < 34 + 6 * n_items:
        raise _bad(path, f"its LASzip VLR lists {n_items} items but has room for fewer")
    items = tuple(
        struct.unpack_from("<HH", payload, 34 + 6 * i) for i in range(n_items)
    )  # fmt: skip
    if compressor not in (_POINTWISE_CHUNKED, _LAYERED_CHUNKED):
        raise TerrainFormatError(
            f"{path} uses LASzip compressor {compressor}, which laspy cannot read (only the "
            "chunked compressors 2 and 3 are supported); decompress it with laszip or pdal."
        )
    item_bytes = sum(s for _, s in items)
    if item_bytes != layout.record_length:
        raise _bad(
            path,
            f"the LASzip items add up to {item_bytes} bytes per point, the header's point "
            f"record length is {layout.record_length}",
        )
    if chunk_size == 0:
        raise _bad(path, "its LASzip VLR has a chunk size of 0")
    return _LasZip(compressor, chunk_size, items)


def _check_laz(path: Path, f: BinaryIO, layout: LasLayout, payload: bytes, point_end: int) -> None:
    """The chunk table (and a layered file's layer sizes) against the compressed bytes."""
    laszip = _parse_laszip(path, payload, layout)
    data = layout.point_offset + 8
    raw = _read_at(f, layout.point_offset, 8)
    if len(raw) < 8:
        raise _bad(path, "its compressed points end before the chunk table offset")
    (table,) = struct.unpack("<q", raw)
    # A streamed LAZ writes -1 first and the real offset in the last 8 bytes of the file.
    if table == -1:
        (table,) = struct.unpack("<q", _read_at(f, layout.file_size - 8, 8))
    if not data <= table <= point_end - 8:
        raise _bad(
            path,
            f"its chunk table offset {table} lies outside the compressed points "
            f"({data} .. {point_end - 8})",
        )
    version, n_chunks = struct.unpack("<II", _read_at(f, table, 8))
    compressed = table - data
    # Every chunk starts with one raw point record, so a chunk takes at least that much.
    most = compressed // layout.record_length
    if version != 0 or n_chunks > most:
        raise _bad(
            path,
            f"its chunk table (version {version}) lists {n_chunks} chunks, but {compressed} "
            f"compressed bytes hold at most {most}",
        )
    entries = _read_chunk_table(path, f, payload, table, n_chunks, point_end)
    if sum(b for _, b in entries) != compressed:
        raise _bad(
            path,
            f"its chunks add up to {sum(b for _, b in entries)} bytes, but {compressed} bytes "
            "of compressed points lie before the chunk table",
        )
    # Fixed-size chunks hold chunk_size points each (the last one the rest); variable-size
    # chunks state their point counts in the table.
    if laszip.chunk_size == _VARIABLE_CHUNKS:
        counts = [p for p, _ in entries]
        holds = f"hold {sum(counts)}"
        fits = sum(counts) == layout.point_count
    else:
        size = laszip.chunk_size
        counts = [min(size, layout.point_count - i * size) for i in range(n_chunks)]
        holds = f"of {size} points hold {(n_chunks - 1) * size + 1} to {n_chunks * size}"
        fits = n_chunks == -(-layout.point_count // size)
    if not fits:
        raise _bad(
            path, f"its header claims {layout.point_count} points, its {n_chunks} chunks {holds}"
        )
    if laszip.compressor == _LAYERED_CHUNKED:
        _check_layers(path, f, layout, laszip, entries, counts, data)


def _read_chunk_table(
    path: Path, f: BinaryIO, payload: bytes, table: int, n_chunks: int, end: int
) -> list[tuple[int, int]]:
    """The (point count, byte count) of each chunk, decoded by lazrs from a bounded buffer."""
    import lazrs

    # The arithmetic-coded entries take at most about 10 bytes each; the rest is not needed.
    buffer = io.BytesIO(_read_at(f, table, min(end - table, 8 + 16 * n_chunks + 64)))
    try:
        vlr = lazrs.LazVlr(payload)
        return [tuple(e) for e in lazrs.read_chunk_table_only(buffer, vlr)]
    except Exception as exc:
        raise _bad(path, f"its chunk table cannot be decoded ({exc})") from exc


def _check_layers(
    path: Path,
    f: BinaryIO,
    layout: LasLayout,
    laszip: _LasZip,
    entries: list[tuple[int, int]],
    counts: list[int],
    data: int,
) -> None:
    """Each layered chunk: raw first point, u32 point count, u32 layer sizes, then the layers.

    lazrs allocates every layer at its stated size: they must fit in the chunk.
    """
    n_layers = 0
    for kind, item_size in laszip.items:
        if kind == _BYTE14:
            n_layers += item_size
        elif kind in _ITEM_LAYERS:
            n_layers += _ITEM_LAYERS[kind]
        else:
            raise _bad(path, f"its layered LASzip VLR lists item type {kind} (10 to 14 exist)")
    pos = data
    for i, ((_, chunk_bytes), count) in enumerate(zip(entries, counts, strict=True)):
        fixed = layout.record_length + 4 + 4 * n_layers
        head = _read_at(f, pos + layout.record_length, 4 + 4 * n_layers)
        if chunk_bytes < fixed or len(head) < 4 + 4 * n_layers:
            raise _bad(path, f"chunk {i} ({chunk_bytes} bytes) is too short for its layers")
        in_chunk, *sizes = struct.unpack(f"<I{n_layers}I", head)
        if in_chunk > count or sum(sizes) > chunk_bytes - fixed:
            raise _bad(
                path,
                f"chunk {i} claims {in_chunk} points and {sum(sizes)} bytes of layers, but it "
                f"holds {count} points in {chunk_bytes - fixed} bytes",
            )
        pos += chunk_bytes


def _check_memory(path: Path, layout: LasLayout, memory: int) -> None:
    """The points must fit in memory: laspy holds every record and the scaled coordinates."""
    need = layout.point_count * (layout.record_length + _BYTES_PER_POINT)
    if need > memory:
        raise TerrainFormatError(
            f"{path} claims {layout.point_count} points, which need {need / 1e9:.1f} GB of "
            f"memory to read, more than the {memory / 1e9:.1f} GB available. If the header is "
            "right, thin or tile the cloud first (for example with pdal)."
        )
