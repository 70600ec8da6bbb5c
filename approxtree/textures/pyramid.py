"""TexturePyramid: the baked texture and its successive halvings, as tiled GeoTIFFs.

Level 0 is the full-resolution texture; level k+1 halves level k (2 × 2 box filter weighted
by alpha, so transparent texels do not darken their neighbours) until a level fits the
renderer's maximum texture size. Every level is a tiled (512²), ZSTD-compressed GeoTIFF with
its last band marked as alpha (the Cloud Optimized GeoTIFF conventions) covering the domain of
level 0 (odd sizes add at most one texel at the east and south edges). A grey texture
(shading: R = G = B) is stored as 2 bands, grey and alpha; any other as 4, RGBA. Reading a
texture patch decodes only the tiles of its window (``TexturePyramid.read``) and gives RGBA
either way, so pyramids larger than memory work. ``pyramid.json`` lists the levels.

A build streams in windows of ``WINDOW_BYTES`` whatever the texture's width, so its memory
stays flat as the texture widens: the texture arrives in band-order strips as high as the
window allows across its width (``TextureData.level_strips``, ``window_shape``), stored in
level 0's spool on disk (``_Spool``: raw texels, written and read back by position, never
mapped); each level's writer (its own thread) takes a tile row of its spool as soon as it is
whole, in windows of whole tiles, writes each tile with all its bands, west to east, and
halves the window (uint8 kernels, ``kernels.rgba``) into the next level's spool. So no level,
nor a tile row of a wide one, is ever whole in memory, the coarser levels are written while
level 0 is made, and the files do not depend on the window size (tests bake one image in the
smallest windows and the default ones and compare the bytes).

A pyramid is written all or nothing: built in a temp folder beside its folder, then swapped in
(``atomic_directory``). Each build has an id, stored in pyramid.json and in every level's
GeoTIFF tags with the level's number; opening a pyramid checks every level against
pyramid.json (id, number, size, bytes, bands, alpha, halving chain), so a level of another
bake, a missing, extra or truncated level is refused instead of draped.

Every tile carries a checksum: each level entry of pyramid.json has ``tile_crc32c``, rows of
512 × 512 tiles (row-major lists), each the CRC-32C of the tile's *decoded* uint8 texels in
band-sequential C order (bands, rows, cols), edge tiles clipped to the level's size. The
writer computes them from the tiles it writes; a read decodes the
whole tiles its window touches and checks each (``_TileCache`` keeps the checked ones), so a
damaged tile is a StoreError, never texels drawn silently. A decode error (ZSTD, TIFF) is a
StoreError too.

Deltas (format 5, written by ``rebake``): a level entry may list ``deltas``, each a small
tiled GeoTIFF ``level{k}.{build}.tif`` holding a rectangle of whole tiles of the level
(``tiles``: tile rows tr0..tr1, columns tc0..tc1, half-open) tagged with its own build id;
a tile's texels are those of the last delta holding it, else the base file's (whose own
build id is the entry's ``build``, the pyramid's when absent). ``tile_crc32c`` is of the
texels as read so. A re-bake writes new files only and commits by replacing pyramid.json,
so a reader sees the old pyramid or the new one; files no pyramid.json names (a killed
re-bake's, or a replaced delta's) are ignored by readers and removed by the next re-bake.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import threading
import uuid
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.io.atomic import atomic_directory
from approxtree.io.gdal import checked_write, no_side_files
from approxtree.kernels.rgba import bands_into_rgba, halve_bands
from approxtree.progress import ProgressCallback, no_progress
from approxtree.textures.base import TextureData

#: Bytes of the windows a build works in (``window_shape``): the texture's strips and the
#: level writers' windows, whatever the texture's width.
WINDOW_BYTES = 8 << 20

#: pyramid.json format: 2 added the build id, the level tags and the level byte counts; 3
#: tiled, compressed levels (no longer memory-mapped) and grey + alpha levels for shadings;
#: 4 a CRC-32C of every tile's decoded texels (``tile_crc32c``).
PYRAMID_FORMAT = 4
#: Formats a reader takes: 5 is 4 with per-level deltas (module docstring), written by re-bakes.
READ_FORMATS = (4, 5)
#: Tile side of the level GeoTIFFs (texels), as COGs use.
_TILE = 512
#: Decoded, checked tiles a pyramid keeps for reads of neighbouring windows (bytes).
TILE_CACHE_BYTES = 32 << 20

#: Level GeoTIFF creation options: tiled, ZSTD at its fastest level (a hillshade shrinks
#: 2.4×, its alpha band to almost nothing), one plane per band (compresses better and faster
#: than interleaved grey/alpha), compressed on every core, BigTIFF past 4 GB.
_LEVEL_OPTIONS = {
    "tiled": True,
    "blockxsize": _TILE,
    "blockysize": _TILE,
    "compress": "zstd",
    "zstd_level": 1,
    "interleave": "band",
    "num_threads": "ALL_CPUS",
    "alpha": "YES",
    # A level that may pass 4 GB (classic TIFF's limit) is written as a BigTIFF.
    "bigtiff": "IF_SAFER",
}
#: GeoTIFF tags naming a level's build and its number in the pyramid.
_TAG_BUILD = "APPROXTREE_PYRAMID"
_TAG_LEVEL = "APPROXTREE_LEVEL"
_LEVEL_FILE = re.compile(r"^level\d+\.tif$")
#: Every level file approxtree writes: a bake's ``level{k}.tif``, a re-bake's deltas and
#: levels written whole again ``level{k}.{build}.tif`` (group 1: the level number).
OWN_LEVEL_FILE = re.compile(r"^level(\d+)(?:\.[0-9a-f]{32})?\.tif$")


@dataclass(frozen=True)
class PyramidDelta:
    """Tiles of a level re-baked into a file of their own: tile rows tr0..tr1 and columns
    tc0..tc1 (half-open) as ``tiles``, the file's build id and byte count."""

    path: Path
    tiles: tuple[int, int, int, int]
    build: str
    nbytes: int

    def texels(self, width: int, height: int) -> tuple[int, int, int, int]:
        """The texel rows and columns (r0, r1, c0, c1), half-open, it holds in a level of
        ``width`` × ``height`` texels."""
        tr0, tr1, tc0, tc1 = self.tiles
        return tr0 * _TILE, min(tr1 * _TILE, height), tc0 * _TILE, min(tc1 * _TILE, width)


@dataclass(frozen=True)
class PyramidLevel:
    """One level: its file, size in texels and affine georeference; its deltas (format 5),
    oldest first, and the build id tagged in its file (None: the pyramid's)."""

    path: Path
    width: int
    height: int
    transform: Affine
    deltas: tuple[PyramidDelta, ...] = ()
    build: str | None = None

    @property
    def files(self) -> list[Path]:
        """The base file and every delta's."""
        return [self.path, *(d.path for d in self.deltas)]

    @property
    def texel_size(self) -> tuple[float, float]:
        return (abs(self.transform.a), abs(self.transform.e))


def tile_row_checksums(block: np.ndarray) -> list[int]:
    """CRC-32C of each tile of a (bands, h ≤ 512, cols) uint8 tile row, west to east (the last
    clipped to ``cols``): the tile's texels in band-sequential C order (pyramid.json's
    ``tile_crc32c``; re-bakes recompute them for the tiles they rewrite)."""
    import crc32c

    cols = block.shape[2]
    return [
        crc32c.crc32c(np.ascontiguousarray(block[:, :, c0 : c0 + _TILE]).data)
        for c0 in range(0, cols, _TILE)
    ]


def level_profile(rows: int, cols: int, bands: int, transform: Affine, crs: Any) -> dict:
    """The rasterio profile of a level file (or a re-bake's delta): uint8 GeoTIFF of ``bands``
    (grey + alpha or RGBA), the bake's tiling, compression and georeference."""
    return {
        "driver": "GTiff",
        "width": cols,
        "height": rows,
        "count": bands,
        "dtype": "uint8",
        "transform": transform,
        "crs": crs,
        "photometric": "RGB" if bands == 4 else "MINISBLACK",
        **_LEVEL_OPTIONS,
    }


def _write_level(
    path: Path,
    spool: _Spool,
    shape: tuple[int, int],
    bands: int,
    transform: Affine,
    crs: str | None,
    build: str,
    level: int,
    halved: _Spool | None,
    overlay: np.ndarray | None = None,
    on_rows: Callable[[int], None] | None = None,
    block_cols: int = _TILE,
) -> list[list[int]]:
    """Write a level from its spool as a tiled compressed GeoTIFF tagged with the pyramid's
    build id and the level number (into the pyramid's temp folder), one tile row as soon as
    the spool holds it, in windows of that tile row ``block_cols`` texels wide (whole tiles);
    each window gets ``overlay`` (rows, cols, 4) drawn over it (alpha over), its tiles
    written west to east, all bands of a tile at once (so the file's bytes do not depend on
    the window width), and its halving written to ``halved`` (the next level's spool), told
    when a tile row's halving is whole. ``on_rows(n)`` after each tile row of n rows. Returns
    the level's ``tile_crc32c`` (rows of tiles, each the CRC-32C of the tile's texels in
    band-sequential C order)."""
    import rasterio
    from rasterio.windows import Window

    rows, cols = shape
    profile = level_profile(rows, cols, bands, transform, crs)
    sums: list[list[int]] = []
    # checked_write: GDAL's write errors (a full disk) become a StoreError once it closes.
    with checked_write(path), rasterio.open(path, "w", **profile) as ds:
        ds.update_tags(**{_TAG_BUILD: build, _TAG_LEVEL: str(level)})
        for r0, n in spool.tile_rows():
            row_sums: list[int] = []
            for c0 in range(0, cols, block_cols):
                m = min(block_cols, cols - c0)
                block = spool.read(r0, n, c0, m)
                if overlay is not None:
                    block = _over(block, overlay[r0 : r0 + n, c0 : c0 + m])
                for t0 in range(0, m, _TILE):
                    tile = np.ascontiguousarray(block[:, :, t0 : t0 + _TILE])
                    ds.write(tile, window=Window(c0 + t0, r0, tile.shape[2], n))
                    row_sums.extend(tile_row_checksums(tile))
                if halved is not None:
                    half = np.empty((bands, (n + 1) // 2, (m + 1) // 2), dtype=np.uint8)
                    halve_bands(block, half)
                    halved.write(r0 // 2, c0 // 2, half)
            sums.append(row_sums)
            if halved is not None:
                halved.completed((r0 + n + 1) // 2)
            if on_rows is not None:
                on_rows(n)
    if len(sums) != -(-rows // _TILE):
        raise InvalidParameterError(
            f"The texture's strips cover {min(len(sums) * _TILE, rows)} of its {rows} rows."
        )
    return sums


class _Spool:
    """A level's texels on disk while the pyramid is built: a raw (rows, cols, bands) uint8
    file in the temp folder, written by rows or windows (``write``), read back by windows
    (``read``) once its writer said which rows are whole (``completed``). Memory then holds a
    window, never a row of the level's whole width; the file is never mapped (reads and
    writes are positional), so it does not count in the process's memory either. Written by
    one thread, read by another (``tile_rows`` waits for each tile row)."""

    def __init__(self, path: Path, shape: tuple[int, ...], bands: int) -> None:
        self.path = path
        self.rows, self.cols = shape
        self.bands = bands
        self._row_bytes = self.cols * bands
        self._fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
        self._done = 0
        self._closed = False
        self._changed = threading.Condition()

    def write(self, r0: int, c0: int, block: np.ndarray) -> None:
        """Store a (bands, n, m) uint8 window whose top-left texel is (r0, c0)."""
        pixels = np.ascontiguousarray(np.moveaxis(block, 0, -1))
        n, m = pixels.shape[:2]
        at = r0 * self._row_bytes + c0 * self.bands
        if m == self.cols:
            _pwrite_all(self._fd, pixels.reshape(-1), at)
            return
        for i in range(n):
            _pwrite_all(self._fd, pixels[i].reshape(-1), at + i * self._row_bytes)

    def read(self, r0: int, n: int, c0: int, m: int) -> np.ndarray:
        """(bands, n, m) uint8: the window of n rows and m columns at (r0, c0)."""
        pixels = np.empty((n, m, self.bands), dtype=np.uint8)
        at = r0 * self._row_bytes + c0 * self.bands
        if m == self.cols:
            _pread_all(self._fd, pixels.reshape(-1), at)
        else:
            for i in range(n):
                _pread_all(self._fd, pixels[i].reshape(-1), at + i * self._row_bytes)
        return np.ascontiguousarray(np.moveaxis(pixels, -1, 0))

    def completed(self, rows: int) -> None:
        """The rows above ``rows`` are whole: their tile rows may be read."""
        with self._changed:
            self._done = max(self._done, rows)
            self._changed.notify_all()

    def close(self) -> None:
        """No more rows come (done, or the writer failed)."""
        with self._changed:
            self._closed = True
            self._changed.notify_all()

    def tile_rows(self) -> Iterator[tuple[int, int]]:
        """(r0, n) of each tile row, top to bottom, as soon as it is whole; ends early when
        the spool is closed before (the level's writer then reports the missing rows)."""
        for r0 in range(0, self.rows, _TILE):
            n = min(_TILE, self.rows - r0)
            with self._changed:
                while self._done < r0 + n and not self._closed:
                    self._changed.wait()
                if self._done < r0 + n:
                    return
            yield r0, n

    def remove(self) -> None:
        """Close and delete the file."""
        os.close(self._fd)
        self.path.unlink(missing_ok=True)


def _pwrite_all(fd: int, data: np.ndarray, offset: int) -> None:
    """Write all of a 1-D uint8 array at ``offset`` (os.pwrite may write less at once)."""
    view = data.data
    while len(view):
        done = os.pwrite(fd, view, offset)
        view, offset = view[done:], offset + done


def _pread_all(fd: int, out: np.ndarray, offset: int) -> None:
    """Fill a 1-D uint8 array from ``offset`` (os.preadv may read less at once)."""
    view = out.data
    while len(view):
        done = os.preadv(fd, [view], offset)
        if done == 0:
            raise StoreError("A texture level's spool ended early; rebake the pyramid.")
        view, offset = view[done:], offset + done


def _spool_strips(strips: Iterable[np.ndarray], spool: _Spool) -> None:
    """Store a level's (bands, rows, cols) uint8 band-order strips, top to bottom, in its
    spool, telling its writer after each; InvalidParameterError for a strip of another shape
    or dtype, or strips that do not cover the level (each of an even number of rows but the
    last, so that halvings pair rows within a strip)."""
    rows, cols, bands = spool.rows, spool.cols, spool.bands
    r0 = 0
    for strip in strips:
        n = strip.shape[1] if strip.ndim == 3 else 0
        if strip.ndim != 3 or strip.shape[::2] != (bands, cols) or strip.dtype != np.uint8:
            raise InvalidParameterError(
                f"A texture must be ({rows}, {cols}, {bands}) uint8, got a strip of "
                f"{strip.shape} {strip.dtype} (bands first)."
            )
        if r0 + n > rows or (n % 2 and r0 + n < rows):
            raise InvalidParameterError(
                f"Texture strips must have an even number of rows and cover {rows} rows."
            )
        spool.write(r0, 0, strip)
        r0 += n
        spool.completed(r0)
    if r0 != rows:
        raise InvalidParameterError(f"The texture's strips cover {r0} of its {rows} rows.")


#: fn(level, transform, (rows, cols)) -> (rows, cols, 4) uint8 drawn over that level, or None.
LevelOverlay = Callable[[int, Affine, tuple[int, int]], "np.ndarray | None"]


def _over(block: np.ndarray, rgba: np.ndarray) -> np.ndarray:
    """A (4, n, m) band-order window with the (n, m, 4) window ``rgba`` drawn over it (alpha
    over, straight alpha)."""
    top = np.moveaxis(rgba, -1, 0).astype(np.float32)
    a = top[3:] / 255.0
    mixed = top * a + block.astype(np.float32) * (1.0 - a)
    mixed[3:] = np.maximum(block[3:], top[3:])
    return np.clip(np.rint(mixed), 0, 255).astype(np.uint8)


def _strips(rgba: np.ndarray, rows: int) -> Iterator[np.ndarray]:
    """A (rows, cols, 4) array as band-order strips of ``rows`` rows (``_spool_strips``)."""
    for r0 in range(0, rgba.shape[0], rows):
        yield np.ascontiguousarray(np.moveaxis(rgba[r0 : r0 + rows], -1, 0))


def window_shape(cols: int, bands: int, window_bytes: int) -> tuple[int, int]:
    """(strip rows, window cols) of a level ``cols`` texels wide within ``window_bytes``: the
    texture's strips span the width in an even number of rows (2 to a tile's 512), the
    writers' windows span a tile row in whole tiles (one at least)."""
    rows = min(_TILE, max(2, window_bytes // max(1, cols * bands) // 2 * 2))
    tiles = max(1, window_bytes // (_TILE * _TILE * bands))
    return rows, tiles * _TILE


def _pyramid_rows(shape: tuple[int, ...], max_texture_size: int) -> int:
    """Texel rows of every level of a pyramid whose level 0 has ``shape`` (rows, cols)."""
    rows, cols = int(shape[0]), int(shape[1])
    total = rows
    while max(rows, cols) > max_texture_size:
        rows, cols = -(-rows // 2), -(-cols // 2)
        total += rows
    return total


def _check_level(
    path: Path,
    level: PyramidLevel,
    bands: int,
    build: str,
    k: int,
    region: tuple[int, int, int, int] | None = None,
    opened: Any = None,
) -> None:
    """Check a level written by ``_write_level`` against its entry in pyramid.json (build id,
    level number, size, bands, alpha, georeference); with ``region`` (r0, r1, c0, c1), a
    delta file holding those texels of the level; ``opened``: the file's rasterio dataset
    when the caller has it open."""
    import rasterio
    from rasterio.enums import ColorInterp

    try:
        with contextlib.ExitStack() as stack:
            ds = opened or stack.enter_context(_opened(path))
            rows, cols, count, dtypes = ds.height, ds.width, ds.count, set(ds.dtypes)
            tags = ds.tags()
            last_band = ds.colorinterp[-1]
            transform = ds.transform
    except rasterio.errors.RasterioError as exc:
        raise StoreError(f"{path} is not a readable GeoTIFF ({exc}); rebake the pyramid.") from exc
    if region is not None:
        r0, r1, c0, c1 = region
        level = PyramidLevel(path, c1 - c0, r1 - r0, level.transform @ Affine.translation(c0, r0))
    if tags.get(_TAG_BUILD) != build or tags.get(_TAG_LEVEL) != str(k):
        raise StoreError(
            f"{path} belongs to another bake than {path.parent / 'pyramid.json'} (level {k} "
            "of a different pyramid); the folder is inconsistent: rebake the pyramid."
        )
    if (cols, rows) != (level.width, level.height) or count != bands or dtypes != {"uint8"}:
        raise StoreError(
            f"{path} is {cols} × {rows} × {count} {sorted(dtypes)}, but pyramid.json lists "
            f"{level.width} × {level.height} × {bands} uint8; rebake the pyramid."
        )
    if last_band != ColorInterp.alpha:
        raise StoreError(f"{path} has no alpha band; rebake the pyramid.")
    if not transform.almost_equals(level.transform):
        raise StoreError(f"{path} is georeferenced unlike pyramid.json says; rebake the pyramid.")


@contextlib.contextmanager
def _opened(path: Path) -> Iterator[Any]:
    """A level file open for reading (rasterio, without GDAL's side files)."""
    import rasterio

    with no_side_files(), rasterio.open(path) as ds:
        yield ds


def _dump_meta(meta: dict) -> str:
    """pyramid.json's text: indented, each level's ``tile_crc32c`` one tile row a line."""
    rows_text = {}
    for k, lv in enumerate(meta["levels"]):
        rows_text[k] = lv["tile_crc32c"]
        lv = lv | {"tile_crc32c": f"@tiles{k}@"}
        meta = meta | {"levels": [*meta["levels"][:k], lv, *meta["levels"][k + 1 :]]}
    text = json.dumps(meta, indent=2)
    for k, rows in rows_text.items():
        inner = ",\n".join("        " + json.dumps(r, separators=(",", ":")) for r in rows)
        text = text.replace(f'"@tiles{k}@"', "[\n" + inner + "\n      ]")
    return text


def _tile_sums(entry: dict, width: int, height: int) -> list[list[int]]:
    """A level entry's ``tile_crc32c``, checked to hold one int per tile of the level."""
    sums = entry["tile_crc32c"]
    shape = (-(-height // _TILE), -(-width // _TILE))
    if not isinstance(sums, list) or len(sums) != shape[0]:
        raise ValueError(f"tile_crc32c of {entry['file']} is not {shape[0]} rows of tiles")
    out = []
    for row in sums:
        if not isinstance(row, list) or len(row) != shape[1]:
            raise ValueError(f"tile_crc32c of {entry['file']} is not rows of {shape[1]} tiles")
        out.append([int(v) for v in row])
    return out


class _TileCache:
    """Decoded tiles that passed their checksum, least recently used first, bounded in bytes;
    shared by the threads reading a pyramid."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self._tiles: OrderedDict[tuple[int, int, int], np.ndarray] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, key: tuple[int, int, int]) -> np.ndarray | None:
        with self._lock:
            tile = self._tiles.get(key)
            if tile is not None:
                self._tiles.move_to_end(key)
            return tile

    def put(self, key: tuple[int, int, int], tile: np.ndarray) -> None:
        tile.flags.writeable = False
        with self._lock:
            if key in self._tiles:
                return
            self._tiles[key] = tile
            self._bytes += tile.nbytes
            while self._bytes > self.limit and len(self._tiles) > 1:
                _, old = self._tiles.popitem(last=False)
                self._bytes -= old.nbytes


def check_pyramid_target(folder: str | os.PathLike) -> None:
    """Refuse, before any work, a folder that a new pyramid cannot replace whole: a file, a
    symbolic link, or a folder holding anything besides a texture pyramid approxtree baked
    (the swap would delete it), unless ``own_output.overwriting`` allows it."""
    from approxtree.io.own_output import check_replaceable

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise StoreError(f"Cannot bake into {folder}: it is a file, not a folder.")
    check_replaceable(folder, "texture pyramid")


def _holds(tiles: tuple[int, int, int, int], tr: int, tc: int) -> bool:
    """Whether the tile rectangle (tr0, tr1, tc0, tc1), half-open, holds tile (tr, tc)."""
    return tiles[0] <= tr < tiles[1] and tiles[2] <= tc < tiles[3]


def _delta(folder: Path, entry: dict, k: int, level: dict) -> PyramidDelta:
    """A level entry's delta, its name and tile rectangle checked (ValueError if not)."""
    name = str(entry["file"])
    match = OWN_LEVEL_FILE.match(name)
    tr0, tr1, tc0, tc1 = (int(v) for v in entry["tiles"])
    rows, cols = -(-int(level["height"]) // _TILE), -(-int(level["width"]) // _TILE)
    if match is None or int(match.group(1)) != k or name == f"level{k}.tif":
        raise ValueError(f"level {k} lists a delta named {name!r}")
    if not (0 <= tr0 < tr1 <= rows and 0 <= tc0 < tc1 <= cols):
        raise ValueError(f"delta {name} of level {k} holds tiles {entry['tiles']}")
    return PyramidDelta(folder / name, (tr0, tr1, tc0, tc1), str(entry["build"]),
                        int(entry["bytes"]))  # fmt: skip


def _damaged(k: int, path: Path, origin: tuple[int, int], tiles: list, failed: str) -> NoReturn:
    """StoreError naming the first of ``tiles`` that ``path`` (holding the level's texels
    from ``origin``) does not decode."""
    import rasterio
    from rasterio.windows import Window

    # Raised outside the handler: GDAL's chained errors, kept as the context, do not
    # survive pickling back from a dask worker. Tile by tile to name the damaged one.
    where = ""
    with no_side_files(), rasterio.open(path) as ds:
        for tr, tc in tiles:
            a, b = tr * _TILE - origin[0], tc * _TILE - origin[1]
            if not (0 <= a < ds.height and 0 <= b < ds.width):
                continue
            window = Window(b, a, min(_TILE, ds.width - b), min(_TILE, ds.height - a))
            try:
                ds.read(window=window)
            except rasterio.errors.RasterioError:
                where = f"tile ({tr}, {tc}) of "
                break
    raise StoreError(
        f"{path} is damaged: {where}level {k} does not decode ({failed}); rebake the "
        "pyramid (approxtree bake)."
    )


def _cause(exc: BaseException) -> str:
    """The innermost message of a chained GDAL error (ZSTD's, not "Read failed")."""
    while exc.__cause__ is not None:
        exc = exc.__cause__
    return str(exc).strip()


class TexturePyramid:
    """A list of levels with one domain; level 0 finest, the last fits ``max_texture_size``."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        meta_path = self.folder / "pyramid.json"
        if not meta_path.is_file():
            raise StoreError(
                f"{self.folder} holds no pyramid.json; bake a texture pyramid into it first "
                "(approxtree bake)."
            )
        try:
            meta = json.loads(meta_path.read_text())
            version = meta.get("format", 1)
            if version not in READ_FORMATS:
                raise StoreError(
                    f"{self.folder} is a texture pyramid of format {version}; this approxtree "
                    f"reads format {PYRAMID_FORMAT} (tiled, compressed levels checked against "
                    "pyramid.json, a checksum per tile). Rebake it (approxtree bake)."
                )
            self.build_id: str = str(meta["build"])
            self.crs: str | None = meta["crs"]
            self.max_texture_size: int = int(meta["max_texture_size"])
            #: Bands of every level: 4 (RGBA) or 2 (grey and alpha).
            self.bands: int = int(meta["bands"])
            #: How the pyramid was baked (``bake``'s layers, shading and its options, texel
            #: size), which a re-bake repeats; None for a pyramid built from an array.
            self.recipe: dict | None = meta.get("recipe")
            if self.bands not in (2, 4):
                raise ValueError(f"bands is {self.bands}, not 2 or 4")
            entries = meta["levels"]
            files = [str(lv["file"]) for lv in entries]
            sizes = [int(lv["bytes"]) for lv in entries]
            #: Per level, rows of tiles: the CRC-32C of each tile's decoded texels.
            self.tile_crc32c = [
                _tile_sums(lv, int(lv["width"]), int(lv["height"])) for lv in entries
            ]
            self.levels = [
                PyramidLevel(
                    self.folder / lv["file"],
                    int(lv["width"]),
                    int(lv["height"]),
                    Affine(*lv["transform"]),
                    tuple(_delta(self.folder, d, k, lv) for d in lv.get("deltas", ())),
                    None if lv.get("build") is None else str(lv["build"]),
                )
                for k, lv in enumerate(entries)
            ]
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise StoreError(f"{meta_path} is malformed: {exc}") from exc
        self._check_levels(files, sizes)
        for k, lv in enumerate(self.levels):
            _check_level(lv.path, lv, self.bands, lv.build or self.build_id, k)
        self._check_chain()
        self._tiles = _TileCache(TILE_CACHE_BYTES)
        # Deltas are checked like levels when first read (``_decode``), not all on open: a
        # level may hold many, and each read tile is checked against its checksum anyway.
        self._checked: set[Path] = set()

    @property
    def files(self) -> set[str]:
        """Names of every file this pyramid reads (levels and deltas), pyramid.json aside."""
        return {p.name for lv in self.levels for p in lv.files}

    def _check_levels(self, files: list[str], sizes: list[int]) -> None:
        """pyramid.json's level list against the folder: names, missing or extra files, bytes."""
        where = self.folder / "pyramid.json"
        if not self.levels:
            raise StoreError(f"{where} lists no level; rebake the pyramid.")
        numbers = [OWN_LEVEL_FILE.match(f) for f in files]
        if [m and int(m.group(1)) for m in numbers] != list(range(len(files))):
            raise StoreError(f"{where} names its levels {files}; rebake the pyramid.")
        on_disk = set(os.listdir(self.folder))
        listed = self.files
        missing = sorted(f for f in listed if f not in on_disk)
        # A bake's level file beyond the listed levels is refused; level{k}.tif of a listed
        # level written whole again by a re-bake killed before its clean-up is a leftover.
        extra = sorted(
            n for n in on_disk - listed
            if _LEVEL_FILE.match(n) and int(n[5:-4]) >= len(files)
        )  # fmt: skip
        if missing or extra:
            what = f"missing {missing}" if missing else f"not listed in pyramid.json: {extra}"
            raise StoreError(f"{self.folder} has level files {what}; rebake the pyramid.")
        expected = [(lv.path, nbytes) for lv, nbytes in zip(self.levels, sizes, strict=True)] + [
            (d.path, d.nbytes) for lv in self.levels for d in lv.deltas
        ]
        for path, nbytes in expected:
            actual = path.stat().st_size
            if actual != nbytes:
                raise StoreError(
                    f"{path} has {actual} bytes, pyramid.json says {nbytes}; rebake the pyramid."
                )

    def _check_chain(self) -> None:
        """Each level halves the one before (rounding up) until one fits the texture limit."""
        where = self.folder / "pyramid.json"
        for fine, coarse in zip(self.levels, self.levels[1:], strict=False):
            if (coarse.width, coarse.height) != (-(-fine.width // 2), -(-fine.height // 2)):
                raise StoreError(f"{where} lists levels that do not halve; rebake the pyramid.")
        last = self.levels[-1]
        fits = [max(lv.width, lv.height) <= self.max_texture_size for lv in self.levels]
        if not fits[-1] or any(fits[:-1]):
            raise StoreError(
                f"{where} lists levels that do not end at the first one fitting "
                f"{self.max_texture_size} texels (last {last.width} × {last.height}); "
                "rebake the pyramid."
            )

    @classmethod
    def build(
        cls,
        texture: TextureData | np.ndarray,
        folder: str | os.PathLike,
        max_texture_size: int = 4096,
        transform: Affine | None = None,
        crs: str | None = None,
        level_overlay: LevelOverlay | None = None,
        progress: ProgressCallback | None = None,
        recipe: dict | None = None,
        window_bytes: int = WINDOW_BYTES,
    ) -> TexturePyramid:
        """Write level 0 from ``texture`` and halve it until a level fits; return the pyramid.

        texture: a TextureData, or a (rows, cols, 4) uint8 array with ``transform`` and ``crs``.
        level_overlay: fn(level, transform, (rows, cols)) -> (rows, cols, 4) uint8 or None,
        drawn over every level after the first (alpha over) before it is written and halved:
        vector overlays redrawn at each level's texel size keep a least width there instead
        of fading in the averages. progress(done, total): texel rows written, all levels
        together, after each tile row (``approxtree.progress``). recipe: JSON-ready bake
        parameters kept in pyramid.json (``TexturePyramid.recipe``) for re-bakes.
        window_bytes: the size of the windows the build works in (``window_shape``); any size
        writes the same files.
        """
        if max_texture_size < 1 or max_texture_size & (max_texture_size - 1):
            raise InvalidParameterError(
                f"max_texture_size must be a power of two, got {max_texture_size}."
            )
        if window_bytes < 1:
            raise InvalidParameterError(f"window_bytes must be >= 1, got {window_bytes}.")
        # The texture arrives in strips as high as the window allows for its width, so no
        # level is ever whole in memory, nor a tile row of a wide one (module docstring).
        if isinstance(texture, TextureData):
            transform, crs = texture.transform, texture.crs
            shape = tuple(texture.shape)
            bands = texture.bands
            strip_rows, block_cols = window_shape(shape[1], bands, window_bytes)
            strips: Iterable[np.ndarray] = texture.level_strips(strip_rows)
        else:
            rgba = texture
            if transform is None:
                raise InvalidParameterError("An RGBA array needs its transform.")
            if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.dtype != np.uint8:
                raise InvalidParameterError(
                    f"A texture must be (rows, cols, 4) uint8, got {rgba.shape} {rgba.dtype}."
                )
            shape = rgba.shape[:2]
            bands = 4
            strip_rows, block_cols = window_shape(shape[1], bands, window_bytes)
            strips = _strips(rgba, strip_rows)
        folder = Path(folder)
        check_pyramid_target(folder)
        folder.absolute().parent.mkdir(parents=True, exist_ok=True)
        build = uuid.uuid4().hex
        # Progress in texel rows over every level (the level sizes are known beforehand).
        report = progress or no_progress
        total = _pyramid_rows(shape, max_texture_size)
        written = [0]
        # Levels are written on several threads at once: one count, one report at a time.
        progress_lock = threading.Lock()

        def on_rows(n: int) -> None:
            with progress_lock:
                written[0] += n
                report(min(written[0], total), total)

        report(0, total)
        # Every level's shape and georeference: texels exactly twice as large keep every level
        # registered on level 0; an odd size repeats its last texel, so a coarser level may
        # reach one finer texel further. The last level is the first that fits.
        plan = [(tuple(shape), transform)]
        while max(plan[-1][0]) > max_texture_size:
            (rows, cols), t = plan[-1]
            plan.append(((-(-rows // 2), -(-cols // 2)), t @ Affine.scale(2.0)))
        # All or nothing: the levels and pyramid.json go to a temp folder swapped in at the end.
        with atomic_directory(folder) as tmp:
            # Levels stream through spools on disk: this thread stores the texture's strips in
            # level 0's; level k's writer (its own thread) writes each tile row of its spool
            # as soon as it is whole, window by window, and stores the windows' halvings in
            # level k + 1's spool. So the coarser levels are written (and compressed) while
            # level 0 is still being made, and memory holds windows, never a level's width:
            # level k's windows are half as wide as level k - 1's (one tile at least), so all
            # levels together hold two windows' worth however many there are.
            spools = [
                _Spool(tmp / f"level{k}.raw", lv_shape, bands)
                for k, (lv_shape, _) in enumerate(plan)
            ]
            tile_sums: dict[int, list[list[int]]] = {}

            def write(k: int) -> None:
                (rows, cols), t = plan[k]
                overlay = level_overlay(k, t, (rows, cols)) if k and level_overlay else None
                sink = spools[k + 1] if k + 1 < len(spools) else None
                try:
                    path = tmp / f"level{k}.tif"
                    tile_sums[k] = _write_level(
                        path, spools[k], (rows, cols), bands, t, crs, build, k, sink,
                        overlay, on_rows, max(1, block_cols // _TILE >> k) * _TILE,
                    )  # fmt: skip
                finally:
                    if sink is not None:
                        sink.close()

            try:
                with ThreadPoolExecutor(len(plan)) as writers:
                    futures = [writers.submit(write, k) for k in range(len(plan))]
                    errors: list[BaseException] = []
                    try:
                        _spool_strips(strips, spools[0])
                    except BaseException as exc:
                        errors.append(exc)
                    finally:
                        spools[0].close()
                    for future in futures:
                        try:
                            future.result()
                        except BaseException as exc:
                            errors.append(exc)
            finally:
                for spool in spools:
                    spool.remove()
            # A finer level's failure starves the coarser ones: the first is the cause.
            if errors:
                raise errors[0]
            levels = [
                {
                    "file": f"level{k}.tif",
                    "width": cols,
                    "height": rows,
                    "transform": list(t)[:6],
                    "bytes": (tmp / f"level{k}.tif").stat().st_size,
                    "tile_crc32c": tile_sums[k],
                }
                for k, ((rows, cols), t) in enumerate(plan)
            ]
            meta = {
                "format": PYRAMID_FORMAT,
                "build": build,
                "crs": crs,
                "max_texture_size": max_texture_size,
                "bands": bands,
                "levels": levels,
            }
            if recipe is not None:
                meta["recipe"] = recipe
            # Indented, but each level's tile_crc32c rows one per line (a level has thousands).
            (tmp / "pyramid.json").write_text(_dump_meta(meta))
        return cls(folder)

    def __getstate__(self) -> dict:
        """Pickled (a dask task's job) without its tile cache and lock."""
        state = dict(self.__dict__)
        del state["_tiles"]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._tiles = _TileCache(TILE_CACHE_BYTES)

    def __len__(self) -> int:
        return len(self.levels)

    def read(self, k: int, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        """A (rows, cols, 4) uint8 RGBA window of level k from texel (row0, col0); texels past
        the level's edge are transparent (0). Decodes only the tiles the window touches, each
        whole and checked against its checksum (StoreError when damaged); grey levels come
        back with R = G = B = grey. Opens the file per call, so threads may read at once."""
        lv = self.levels[k]
        out = np.zeros((rows, cols, 4), dtype=np.uint8)
        r1, c1 = min(row0 + rows, lv.height), min(col0 + cols, lv.width)
        if r1 <= row0 or c1 <= col0:
            return out
        planes = self.read_bands(k, row0, col0, r1 - row0, c1 - col0)
        # Grey and alpha fill R, G, B and A; RGBA fills them as stored.
        bands_into_rgba(planes, out)
        return out

    def read_bands(self, k: int, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        """(bands, rows, cols) uint8 texels of level k as stored (grey and alpha, or RGBA),
        the window inside the level; every tile it touches checked (``read``)."""
        lv = self.levels[k]
        r1, c1 = row0 + rows, col0 + cols
        if not (0 <= row0 < r1 <= lv.height and 0 <= col0 < c1 <= lv.width):
            raise InvalidParameterError(
                f"Texels {row0}..{r1} × {col0}..{c1} are not inside level {k} "
                f"({lv.height} × {lv.width})."
            )
        tiles = [
            (tr, tc)
            for tr in range(row0 // _TILE, (r1 - 1) // _TILE + 1)
            for tc in range(col0 // _TILE, (c1 - 1) // _TILE + 1)
        ]
        # The whole tiles the window touches: block rows R0..R1, columns C0..C1.
        r0_, c0_ = tiles[0][0] * _TILE, tiles[0][1] * _TILE
        r1_ = min(lv.height, (tiles[-1][0] + 1) * _TILE)
        c1_ = min(lv.width, (tiles[-1][1] + 1) * _TILE)
        held = {t: self._tiles.get((k, *t)) for t in tiles}
        cached = {t: tile for t, tile in held.items() if tile is not None}
        if len(cached) == len(held):
            block = np.empty((self.bands, r1_ - r0_, c1_ - c0_), dtype=np.uint8)
            for (tr, tc), tile in cached.items():
                a, b = tr * _TILE - r0_, tc * _TILE - c0_
                block[:, a : a + tile.shape[1], b : b + tile.shape[2]] = tile
        else:
            # One read of the whole tiles (GDAL decodes whole tiles anyway), then each tile
            # not checked yet is checked (a contiguous copy, kept in the cache).
            block = self._decode(k, r0_, c0_, r1_, c1_, tiles)
            for (tr, tc), kept in held.items():
                if kept is None:
                    a, b = tr * _TILE - r0_, tc * _TILE - c0_
                    self._check_tile(k, tr, tc, block[:, a : a + _TILE, b : b + _TILE])
        return np.ascontiguousarray(block[:, row0 - r0_ : r1 - r0_, col0 - c0_ : c1 - c0_])

    def _decode(
        self, k: int, r0: int, c0: int, r1: int, c1: int, tiles: list[tuple[int, int]]
    ) -> np.ndarray:
        """(bands, r1 − r0, c1 − c0) texels of level k as GDAL decodes them; a StoreError
        naming the first of ``tiles`` that does not decode when the read fails."""
        import rasterio
        from rasterio.windows import Window

        lv = self.levels[k]
        # The base file's texels, then each delta's over them, oldest first (the last wins).
        parts = [(lv.path, (0, lv.height, 0, lv.width))]
        parts += [(d.path, d.texels(lv.width, lv.height)) for d in lv.deltas]
        block = None
        for path, (a, b, c, d) in parts:
            ra, rb, ca, cb = max(r0, a), min(r1, b), max(c0, c), min(c1, d)
            if ra >= rb or ca >= cb:
                continue
            failed = None
            try:
                with no_side_files(), rasterio.open(path) as ds:
                    if path != lv.path and path not in self._checked:
                        build = next(x.build for x in lv.deltas if x.path == path)
                        _check_level(path, lv, self.bands, build, k, (a, b, c, d), ds)
                        self._checked.add(path)
                    texels = ds.read(window=Window(ca - c, ra - a, cb - ca, rb - ra))
            except rasterio.errors.RasterioError as exc:
                failed = _cause(exc)
            if failed is not None:
                _damaged(k, path, (a, c), tiles, failed)
            if block is None:
                block = texels
            else:
                block[:, ra - r0 : rb - r0, ca - c0 : cb - c0] = texels
        assert block is not None  # the base file covers the level
        return block

    def _check_tile(self, k: int, tr: int, tc: int, texels: np.ndarray) -> None:
        """StoreError unless the (bands, h, w) texels of tile (tr, tc) of level k match its
        CRC-32C in pyramid.json; a match goes into the tile cache."""
        import crc32c

        tile = np.ascontiguousarray(texels)
        if crc32c.crc32c(tile.data) != self.tile_crc32c[k][tr][tc]:
            # The file the tile was read from: the last delta holding it, else the base.
            lv = self.levels[k]
            held = [d.path for d in lv.deltas if _holds(d.tiles, tr, tc)]
            raise StoreError(
                f"{(held or [lv.path])[-1]} is damaged: tile ({tr}, {tc}) of level {k} does not "
                "match its checksum in pyramid.json; rebake the pyramid (approxtree bake)."
            )
        self._tiles.put((k, tr, tc), tile if tile is not texels else tile.copy())

    def level(self, k: int) -> np.ndarray:
        """Level k whole, as a (rows, cols, 4) uint8 RGBA array in memory (``read`` reads a
        window of it)."""
        lv = self.levels[k]
        return self.read(k, 0, 0, lv.height, lv.width)

    @property
    def nbytes(self) -> int:
        """Bytes of all level files."""
        return sum(p.stat().st_size for lv in self.levels for p in lv.files)
