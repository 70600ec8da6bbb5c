"""TexturePyramid: the baked texture and its successive halvings, as tiled GeoTIFFs.

Level 0 is the full-resolution texture; level k+1 halves level k (2 × 2 box filter weighted
by alpha, so transparent texels do not darken their neighbours) until a level fits the
renderer's maximum texture size. Every level is a tiled (512²), ZSTD-compressed GeoTIFF with
its last band marked as alpha (the Cloud Optimized GeoTIFF conventions) covering the domain of
level 0 (odd sizes add at most one texel at the east and south edges). A grey texture
(shading: R = G = B) is stored as 2 bands, grey and alpha; any other as 4, RGBA. Reading a
texture patch decodes only the tiles of its window (``TexturePyramid.read``) and gives RGBA
either way, so pyramids larger than memory work. ``pyramid.json`` lists the levels. A build
streams: the texture arrives in band-order strips (``TextureData.level_strips``), each written
and halved at once (uint8 kernels, ``kernels.rgba``), and each halving goes straight on to the
next level's writer (its own thread), so no level is ever whole in memory and the coarser
levels are written while level 0 is made.

A pyramid is written all or nothing: built in a temp folder beside its folder, then swapped in
(``atomic_directory``). Each build has an id, stored in pyramid.json and in every level's
GeoTIFF tags with the level's number; opening a pyramid checks every level against
pyramid.json (id, number, size, bytes, bands, alpha, halving chain), so a level of another
bake, a missing, extra or truncated level is refused instead of draped.

Every tile carries a checksum: each level entry of pyramid.json has ``tile_crc32c``, rows of
512 × 512 tiles (row-major lists), each the CRC-32C of the tile's *decoded* uint8 texels in
band-sequential C order (bands, rows, cols), edge tiles clipped to the level's size. The
writer computes them from the strips it writes (one tile row at a time); a read decodes the
whole tiles its window touches and checks each (``_TileCache`` keeps the checked ones), so a
damaged tile is a StoreError, never texels drawn silently. A decode error (ZSTD, TIFF) is a
StoreError too.
"""

from __future__ import annotations

import json
import os
import queue
import re
import threading
import uuid
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.io.atomic import atomic_directory
from approxtree.io.gdal import checked_write, no_side_files
from approxtree.kernels.rgba import bands_into_rgba, halve_bands
from approxtree.progress import ProgressCallback, no_progress
from approxtree.textures.base import TextureData

#: Rows handled at once while halving a level, bounding memory for huge textures.
_CHUNK_ROWS = 512

#: pyramid.json format: 2 added the build id, the level tags and the level byte counts; 3
#: tiled, compressed levels (no longer memory-mapped) and grey + alpha levels for shadings;
#: 4 a CRC-32C of every tile's decoded texels (``tile_crc32c``).
PYRAMID_FORMAT = 4
#: Tile side of the level GeoTIFFs (texels), as COGs use.
_TILE = 512
#: Strips queued for the writer thread before the producer waits (each a copy of a strip).
_WRITE_AHEAD = 3
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


@dataclass(frozen=True)
class PyramidLevel:
    """One level: its file, size in texels and affine georeference."""

    path: Path
    width: int
    height: int
    transform: Affine

    @property
    def texel_size(self) -> tuple[float, float]:
        return (abs(self.transform.a), abs(self.transform.e))


def _write_level(
    path: Path,
    strips: Iterable[np.ndarray],
    shape: tuple[int, int],
    bands: int,
    transform: Affine,
    crs: str | None,
    build: str,
    level: int,
    halved: list[np.ndarray] | _Handoff | None,
    on_rows: Callable[[int], None] | None = None,
) -> list[list[int]]:
    """Write the (bands, rows, cols) uint8 band-order strips of a level (RGBA, or grey and
    alpha), top to bottom, as a tiled compressed GeoTIFF tagged with the pyramid's build id and
    the level number (into the pyramid's temp folder); when ``halved`` is given (a list, or
    the next level's ``_Handoff``), append to it the strips of the level's halving, made while
    each strip is at hand (strips of even height); ``on_rows(n)`` after each strip of n rows
    is written. Returns the level's ``tile_crc32c`` (rows of tiles, ``_TileChecksums``)."""
    import rasterio

    rows, cols = shape
    profile = {
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
    r0 = 0
    # GDAL writes (and compresses) a strip and halves it on a writer thread, without the GIL,
    # while this thread makes the next ones; up to _WRITE_AHEAD strips wait in its queue.
    pending: deque[Future] = deque()
    ring: list[np.ndarray | None] = [None] * (_WRITE_AHEAD + 1)
    sums = _TileChecksums(shape, bands)
    # checked_write: GDAL's write errors (a full disk) become a StoreError once it closes.
    with (
        checked_write(path),
        rasterio.open(path, "w", **profile) as ds,
        ThreadPoolExecutor(1) as writer,
    ):
        ds.update_tags(**{_TAG_BUILD: build, _TAG_LEVEL: str(level)})
        for index, strip in enumerate(strips):
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
            if len(pending) == _WRITE_AHEAD:
                pending.popleft().result()
            # A strip is valid until the next is asked for: the writer gets its own copy, in
            # a ring of _WRITE_AHEAD + 1 buffers (reused rather than faulted in afresh; the
            # slot's last strip was written when the oldest pending write was waited for).
            slot = index % len(ring)
            buffer = ring[slot]
            if buffer is None or buffer.shape != strip.shape:
                buffer = ring[slot] = np.empty(strip.shape, dtype=np.uint8)
            np.copyto(buffer, strip)
            pending.append(writer.submit(_write_and_halve, ds, buffer, r0, halved, sums))
            if on_rows is not None:
                on_rows(n)
            r0 += n
        while pending:
            pending.popleft().result()
    if r0 != rows:
        raise InvalidParameterError(f"The texture's strips cover {r0} of its {rows} rows.")
    return sums.rows


class _TileChecksums:
    """The ``tile_crc32c`` of a level, from its band-order strips as they are written.

    A tile's checksum covers its (bands, h, w) texels in C order, so it needs the tile's whole
    height at once: a strip that is a whole tile row (the usual case: levels are written in
    512-row strips) is summed as it is; other strips are gathered in one tile-row buffer
    first. Called on the level's writer thread only, in row order.
    """

    def __init__(self, shape: tuple[int, int], bands: int) -> None:
        self.height, self.width = shape
        self.bands = bands
        #: Finished tile rows: one list of crc32c per tile row, west to east.
        self.rows: list[list[int]] = []
        self._buffer: np.ndarray | None = None
        self._filled = 0

    def add(self, strip: np.ndarray, r0: int) -> None:
        """Take the (bands, n, cols) strip written at row ``r0``."""
        n = strip.shape[1]
        if not self._filled and (n == _TILE or r0 + n == self.height) and n <= _TILE:
            self.rows.append(tile_row_checksums(strip))
            return
        at = 0
        while at < n:
            if self._buffer is None:
                self._buffer = np.empty((self.bands, _TILE, self.width), dtype=np.uint8)
            take = min(n - at, _TILE - self._filled)
            self._buffer[:, self._filled : self._filled + take] = strip[:, at : at + take]
            self._filled += take
            at += take
            if self._filled == _TILE or r0 + at == self.height:
                self.rows.append(tile_row_checksums(self._buffer[:, : self._filled]))
                self._filled = 0


def tile_row_checksums(block: np.ndarray) -> list[int]:
    """CRC-32C of each tile of a (bands, h ≤ 512, cols) uint8 tile row, west to east (the last
    clipped to ``cols``): the tile's texels in band-sequential C order."""
    import crc32c

    cols = block.shape[2]
    return [
        crc32c.crc32c(np.ascontiguousarray(block[:, :, c0 : c0 + _TILE]).data)
        for c0 in range(0, cols, _TILE)
    ]


def _write_and_halve(
    ds,
    strip: np.ndarray,
    r0: int,
    halved: list[np.ndarray] | _Handoff | None,
    sums: _TileChecksums,
) -> None:
    """Write a (bands, n, cols) strip at row ``r0`` of ``ds``, add it to the level's tile
    checksums and, if ``halved`` is given, append its (bands, ⌈n/2⌉, ⌈cols/2⌉) halving to it
    (it depends on that strip only: its rows pair up). All run on the level's writer thread
    (one, so strips and halvings come in order; GDAL and the kernel without the GIL), while
    the next strip is made; the next level gets each halving at once."""
    from rasterio.windows import Window

    bands, n, cols = strip.shape
    ds.write(strip, window=Window(0, r0, cols, n))
    sums.add(strip, r0)
    if halved is None:
        return
    half = np.empty((bands, (n + 1) // 2, (cols + 1) // 2), dtype=np.uint8)
    halve_bands(strip, half)
    halved.append(half)


#: fn(level, transform, (rows, cols)) -> (rows, cols, 4) uint8 drawn over that level, or None.
LevelOverlay = Callable[[int, Affine, tuple[int, int]], "np.ndarray | None"]


def _over(strips: Iterable[np.ndarray], rgba: np.ndarray | None) -> Iterator[np.ndarray]:
    """Band-order strips (4, n, cols) of a level with ``rgba`` (rows, cols, 4) drawn over
    them (alpha over, straight alpha), one by one; the strips unchanged without an overlay."""
    r0 = 0
    for strip in strips:
        if rgba is None:
            yield strip
            continue
        n = strip.shape[1]
        top = np.moveaxis(rgba[r0 : r0 + n], -1, 0).astype(np.float32)
        a = top[3:] / 255.0
        mixed = top * a + strip.astype(np.float32) * (1.0 - a)
        mixed[3:] = np.maximum(strip[3:], top[3:])
        yield np.clip(np.rint(mixed), 0, 255).astype(np.uint8)
        r0 += n


def _whole_tile_rows(strips: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    """Band-order strips regrouped into strips of ``_TILE`` rows (the last may be shorter):
    each write then fills whole tiles. A part of a tile written while other levels are
    written too may be flushed (compressed) before the rest of it comes, then read back,
    completed and stored again: more work, and a larger file."""
    held: list[np.ndarray] = []
    rows = 0
    for strip in strips:
        held.append(strip)
        rows += strip.shape[1]
        if rows >= _TILE:
            block = np.concatenate(held, axis=1)
            for r0 in range(0, rows - rows % _TILE, _TILE):
                yield block[:, r0 : r0 + _TILE]
            held = [block[:, rows - rows % _TILE :]] if rows % _TILE else []
            rows %= _TILE
    if rows:
        yield np.concatenate(held, axis=1)


class _Handoff:
    """The strips of a level, from the writer of the level before to its own writer: the
    finer writer ``append``s each halving, and ``close``s when done (or failed); iterating
    yields them in order until then."""

    _END = object()

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue = queue.SimpleQueue()

    def append(self, strip: np.ndarray) -> None:
        self._queue.put(strip)

    def close(self) -> None:
        self._queue.put(self._END)

    def __iter__(self) -> Iterator[np.ndarray]:
        while (strip := self._queue.get()) is not self._END:
            yield strip


def _strips(rgba: np.ndarray) -> Iterator[np.ndarray]:
    """A (rows, cols, 4) array as band-order strips of ``_CHUNK_ROWS`` rows (``_write_level``)."""
    for r0 in range(0, rgba.shape[0], _CHUNK_ROWS):
        yield np.ascontiguousarray(np.moveaxis(rgba[r0 : r0 + _CHUNK_ROWS], -1, 0))


def _pyramid_rows(shape: tuple[int, ...], max_texture_size: int) -> int:
    """Texel rows of every level of a pyramid whose level 0 has ``shape`` (rows, cols)."""
    rows, cols = int(shape[0]), int(shape[1])
    total = rows
    while max(rows, cols) > max_texture_size:
        rows, cols = -(-rows // 2), -(-cols // 2)
        total += rows
    return total


def _check_level(path: Path, level: PyramidLevel, bands: int, build: str, k: int) -> None:
    """Check a level written by ``_write_level`` against its entry in pyramid.json (build id,
    level number, size, bands, alpha, georeference)."""
    import rasterio
    from rasterio.enums import ColorInterp

    try:
        with no_side_files(), rasterio.open(path) as ds:
            rows, cols, count, dtypes = ds.height, ds.width, ds.count, set(ds.dtypes)
            tags = ds.tags()
            last_band = ds.colorinterp[-1]
            transform = ds.transform
    except rasterio.errors.RasterioError as exc:
        raise StoreError(f"{path} is not a readable GeoTIFF ({exc}); rebake the pyramid.") from exc
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
            if version != PYRAMID_FORMAT:
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
                )
                for lv in entries
            ]
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise StoreError(f"{meta_path} is malformed: {exc}") from exc
        self._check_levels(files, sizes)
        for k, lv in enumerate(self.levels):
            _check_level(lv.path, lv, self.bands, self.build_id, k)
        self._check_chain()
        self._tiles = _TileCache(TILE_CACHE_BYTES)

    def _check_levels(self, files: list[str], sizes: list[int]) -> None:
        """pyramid.json's level list against the folder: names, missing or extra files, bytes."""
        where = self.folder / "pyramid.json"
        if not self.levels:
            raise StoreError(f"{where} lists no level; rebake the pyramid.")
        if files != [f"level{k}.tif" for k in range(len(files))]:
            raise StoreError(f"{where} names its levels {files}; rebake the pyramid.")
        on_disk = {n for n in os.listdir(self.folder) if _LEVEL_FILE.match(n)}
        missing = [f for f in files if f not in on_disk]
        extra = sorted(on_disk - set(files))
        if missing or extra:
            what = f"missing {missing}" if missing else f"not listed in pyramid.json: {extra}"
            raise StoreError(f"{self.folder} has level files {what}; rebake the pyramid.")
        for lv, nbytes in zip(self.levels, sizes, strict=True):
            actual = lv.path.stat().st_size
            if actual != nbytes:
                raise StoreError(
                    f"{lv.path} has {actual} bytes, pyramid.json says {nbytes}; rebake the pyramid."
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
    ) -> TexturePyramid:
        """Write level 0 from ``texture`` and halve it until a level fits; return the pyramid.

        texture: a TextureData, or a (rows, cols, 4) uint8 array with ``transform`` and ``crs``.
        level_overlay: fn(level, transform, (rows, cols)) -> (rows, cols, 4) uint8 or None,
        drawn over every level after the first (alpha over) before it is written and halved:
        vector overlays redrawn at each level's texel size keep a least width there instead
        of fading in the averages. progress(done, total): texel rows written, all levels
        together, after each strip (``approxtree.progress``). recipe: JSON-ready bake
        parameters kept in pyramid.json (``TexturePyramid.recipe``) for re-bakes.
        """
        if max_texture_size < 1 or max_texture_size & (max_texture_size - 1):
            raise InvalidParameterError(
                f"max_texture_size must be a power of two, got {max_texture_size}."
            )
        # The texture arrives in strips, so level 0 is never whole in memory; each level is
        # halved strip by strip as it is written, and only the coarser levels (a third of
        # level 0 at most) are held.
        if isinstance(texture, TextureData):
            transform, crs = texture.transform, texture.crs
            shape = tuple(texture.shape)
            bands = texture.bands
            strips: Iterable[np.ndarray] = texture.level_strips(_CHUNK_ROWS)
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
            strips = _strips(rgba)
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
            # Levels stream: level k's writer halves each strip it writes and hands the halving
            # at once to level k + 1, written on its own thread, so the coarser levels are
            # written (and compressed) while level 0 is still being made, not after it, and
            # no level is ever held whole. Level 0 is written on this thread (it runs the
            # texture's kernels).
            handoffs = [_Handoff() for _ in plan[1:]]
            tile_sums: dict[int, list[list[int]]] = {}

            def write(k: int) -> None:
                (rows, cols), t = plan[k]
                level_strips = strips if k == 0 else _whole_tile_rows(handoffs[k - 1])
                if k and level_overlay is not None:
                    level_strips = _over(level_strips, level_overlay(k, t, (rows, cols)))
                sink = handoffs[k] if k < len(handoffs) else None
                try:
                    path = tmp / f"level{k}.tif"
                    tile_sums[k] = _write_level(
                        path, level_strips, (rows, cols), bands, t, crs, build, k, sink, on_rows
                    )
                finally:
                    if sink is not None:
                        sink.close()

            with ThreadPoolExecutor(max(1, len(handoffs))) as coarser:
                futures = [coarser.submit(write, k) for k in range(1, len(plan))]
                errors: list[BaseException] = []
                try:
                    write(0)
                except BaseException as exc:
                    errors.append(exc)
                for future in futures:
                    try:
                        future.result()
                    except BaseException as exc:
                        errors.append(exc)
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
        planes = np.ascontiguousarray(block[:, row0 - r0_ : r1 - r0_, col0 - c0_ : c1 - c0_])
        # Grey and alpha fill R, G, B and A; RGBA fills them as stored.
        bands_into_rgba(planes, out)
        return out

    def _decode(
        self, k: int, r0: int, c0: int, r1: int, c1: int, tiles: list[tuple[int, int]]
    ) -> np.ndarray:
        """(bands, r1 − r0, c1 − c0) texels of level k as GDAL decodes them; a StoreError
        naming the first of ``tiles`` that does not decode when the read fails."""
        import rasterio
        from rasterio.windows import Window

        lv = self.levels[k]
        failed = None
        try:
            with no_side_files(), rasterio.open(lv.path) as ds:
                return ds.read(window=Window(c0, r0, c1 - c0, r1 - r0))
        except rasterio.errors.RasterioError as exc:
            failed = _cause(exc)
        # Raised outside the handler: GDAL's chained errors, kept as the context, do not
        # survive pickling back from a dask worker. Tile by tile to name the damaged one.
        where = ""
        with no_side_files(), rasterio.open(lv.path) as ds:
            for tr, tc in tiles:
                a, b = tr * _TILE, tc * _TILE
                window = Window(b, a, min(_TILE, lv.width - b), min(_TILE, lv.height - a))
                try:
                    ds.read(window=window)
                except rasterio.errors.RasterioError:
                    where = f"tile ({tr}, {tc}) of "
                    break
        raise StoreError(
            f"{lv.path} is damaged: {where}level {k} does not decode ({failed}); rebake the "
            "pyramid (approxtree bake)."
        )

    def _check_tile(self, k: int, tr: int, tc: int, texels: np.ndarray) -> None:
        """StoreError unless the (bands, h, w) texels of tile (tr, tc) of level k match its
        CRC-32C in pyramid.json; a match goes into the tile cache."""
        import crc32c

        tile = np.ascontiguousarray(texels)
        if crc32c.crc32c(tile.data) != self.tile_crc32c[k][tr][tc]:
            raise StoreError(
                f"{self.levels[k].path} is damaged: tile ({tr}, {tc}) of level {k} does not "
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
        return sum(lv.path.stat().st_size for lv in self.levels)
