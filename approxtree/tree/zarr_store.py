"""The tree store: one zarr v3 hierarchy holding a tree, its patches and its terrain.

Locations: a folder ``NAME.zarr`` (directory store), a single file ``NAME.zarr.zip`` /
``NAME.zip`` (zip store, entries stored uncompressed: the chunks are compressed already), or
an fsspec URL (``memory://...``, ``s3://...``; anything with ``://``).

Every array is chunked and encoded as blosc(zstd, shuffle) then a crc32c checksum
(``zarr.codecs.Crc32cCodec``), so a flipped byte in any chunk fails its read. Every chunk is
written (``write_empty_chunks``), so a missing chunk file is found when the store is opened
(zarr alone would read it as its fill value). The root group's attributes hold the format
name and version, the tree's meta data (JSON, no pickle) and a CRC-32C of every array's and
group's metadata document (``zarr.json``), checked when it is opened. Any error of zarr or
numcodecs reading a store becomes a StoreError naming the store and what to do.

Atomic writes (``writing``): a folder store is written into a hidden temp folder beside the
target (``.NAME.PID.TOKEN.tmp``, ``io.atomic``) and renamed into place, replacing an
existing store only once the new one is complete; a zip store is written as such a folder,
then zipped into a temp file renamed over the target. A URL cannot be renamed: there the
root ``zarr.json`` is written without the format name first and rewritten with it last, as
the commit marker; a store whose root lacks it does not open ("incomplete"). Writing to a
URL removes what was there first (object stores cannot swap prefixes).
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import shutil
import threading
import zipfile
from collections import OrderedDict
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, Literal

import numpy as np

from approxtree.errors import StoreError

#: Name and version in the root attributes; a reader opens only the versions it knows.
FORMAT = "approxtree-tree-store"
FORMAT_VERSION = 1
#: Terrain heights chunk (rows, cols); written block by block, never as a whole band.
HEIGHT_CHUNK = 512
#: Column blocks written per call when copying heights in (one band of 512 × 4096 at most).
_HEIGHT_BLOCK_COLS = HEIGHT_CHUNK * 8
#: Target raw bytes of one chunk of a 1-D (or row-chunked) array.
CHUNK_BYTES = 1 << 18
#: Decoded chunks kept by a reader for patch reads (bytes).
CHUNK_CACHE_BYTES = 64 << 20


# -- locations ---------------------------------------------------------------------------------


def is_url(path: str | os.PathLike) -> bool:
    return "://" in str(path)


def is_zip(path: str | os.PathLike) -> bool:
    return not is_url(path) and str(path).lower().endswith(".zip")


def is_store(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a tree store (rather than a legacy ``.atree`` file or a terrain
    file): a URL, a ``.zarr`` path, a folder with a zarr.json, or a zip holding a zarr.json
    (other zips, such as zipped SRTM tiles, are terrain files)."""
    text = str(path).rstrip("/")
    if is_url(text) or text.lower().endswith(".zarr"):
        return True
    if is_zip(text) and Path(text).is_file():
        try:
            with zipfile.ZipFile(text) as z:
                return "zarr.json" in z.namelist()
        except (OSError, zipfile.BadZipFile):
            return False
    return Path(text).is_dir() and (Path(text) / "zarr.json").is_file()


def _open_zarr_store(path: str | os.PathLike, read_only: bool) -> Any:
    """The zarr Store object of a location (StoreError when it cannot be opened)."""
    from zarr.storage import FsspecStore, LocalStore, ZipStore

    text = str(path)
    try:
        if is_url(text):
            return FsspecStore.from_url(text, read_only=read_only)
        if is_zip(text):
            if not Path(text).is_file():
                raise FileNotFoundError(text)
            return ZipStore(text, mode="r")
        if not Path(text).is_dir():
            raise FileNotFoundError(text)
        return LocalStore(text, read_only=read_only)
    except FileNotFoundError as exc:
        raise StoreError(f"Tree store {text} does not exist.") from exc
    except (OSError, ValueError, ImportError, zipfile.BadZipFile) as exc:
        raise StoreError(f"Cannot open the tree store {text}: {exc}.") from exc


# -- encoding ----------------------------------------------------------------------------------


def codecs(dtype: np.dtype) -> list[Any]:
    """Compression then the crc32c checksum (the checksum covers the compressed bytes)."""
    from zarr.codecs import BloscCodec, Crc32cCodec

    shuffle: Literal["bitshuffle", "shuffle"] = (
        "bitshuffle" if np.dtype(dtype).itemsize == 1 else "shuffle"
    )
    return [BloscCodec(cname="zstd", clevel=5, shuffle=shuffle), Crc32cCodec()]


def _row_chunks(shape: tuple[int, ...], itemsize: int) -> tuple[int, ...]:
    """Chunks of an array split along axis 0 into about CHUNK_BYTES each."""
    row = max(1, math.prod(shape[1:])) * itemsize
    rows = max(1, min(max(shape[0], 1), CHUNK_BYTES // row))
    return (rows, *shape[1:]) if len(shape) else ()


class ChunkReuse:
    """The chunks of a 2-D array that a new folder store takes from an old one by hard link.

    old: the old store's array folder (e.g. STORE/terrain/heights); changed: (r0, r1, c0, c1)
    inclusive elements that differ from the old array. A chunk that meets them is written; any
    other is linked (``os.link``) to the old chunk file, which both stores then share: the
    old store is never written through such a link (a later write makes a new store beside
    it). Nothing is linked when the old array's metadata (shape, chunks, dtype, codecs; its
    attributes aside) differs from the new one's, or across file systems. An empty ``changed``
    (r1 < r0) links every chunk.
    """

    def __init__(self, old: str | os.PathLike, changed: tuple[int, int, int, int]) -> None:
        self.old = Path(old)
        self.changed = changed
        #: Chunks linked by the last write.
        self.linked = 0

    def linker(self, arr: Any, chunks: tuple[int, ...]) -> Any:
        """fn(i, j) -> bool: link chunk (i, j) of the new ``arr`` and say so, or False for a
        chunk to write; None when nothing can be linked."""
        root = getattr(arr.store, "root", None)
        if root is None:
            return None
        new = Path(root) / arr.path
        try:
            same = _array_doc(self.old) == _array_doc(new)
        except (OSError, ValueError):
            return None
        if not same:
            return None
        r0, r1, c0, c1 = self.changed
        lock = threading.Lock()

        def link(i: int, j: int) -> bool:
            if i * chunks[0] <= r1 and r0 < (i + 1) * chunks[0]:
                if j * chunks[1] <= c1 and c0 < (j + 1) * chunks[1]:
                    return False
            source = self.old / "c" / str(i) / str(j)
            target = new / "c" / str(i) / str(j)
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                os.link(source, target)
            except OSError:
                return False
            with lock:
                self.linked += 1
            return True

        return link


def _chunk_bytes(path: Path, size: int) -> bytes | None:
    """The first ``size`` decoded bytes of a chunk file written with ``codecs`` (blosc frame,
    then its crc32c), None when it cannot be read or its checksum fails."""
    import crc32c
    from numcodecs import blosc

    try:
        data = path.read_bytes()
        if len(data) < 4 or crc32c.crc32c(data[:-4]) != int.from_bytes(data[-4:], "little"):
            return None
        return bytes(blosc.decompress(data[:-4]))[:size]
    except (OSError, RuntimeError, ValueError):
        return None


def _array_doc(folder: Path) -> dict[str, Any]:
    """An array's metadata document without its attributes (set after the chunks are written,
    and not part of the chunks' encoding)."""
    doc = json.loads((folder / "zarr.json").read_bytes())
    doc.pop("attributes", None)
    return dict(doc)


class EqualChunks:
    """The chunks of an array (split along axis 0 only) that a new folder store takes from an
    old one's array of the same name by hard link, where they hold the same bytes.

    old: the old store's array folder (e.g. STORE/nodes/errors). A chunk is linked when the
    old array's metadata (its shape and attributes aside) is the new one's and its rows of
    the old array are bitwise the new rows (a partial last chunk only at the same length);
    the old array is read whole to compare. Nothing is linked across file systems, or when
    the old array is missing or unreadable.
    """

    def __init__(self, old: str | os.PathLike) -> None:
        self.old = Path(old)
        #: Chunks linked by the last write.
        self.linked = 0

    def linked_chunks(self, arr: Any, values: np.ndarray) -> np.ndarray | None:
        """(chunks,) bool: the chunks of the new ``arr`` (holding ``values``) now linked to
        the old array's files; None when nothing can be."""
        root = getattr(arr.store, "root", None)
        if root is None or not len(values):
            return None
        new = Path(root) / arr.path
        try:
            old_doc, new_doc = _array_doc(self.old), _array_doc(new)
        except (OSError, ValueError):
            return None
        n_old = int(old_doc.pop("shape", [0])[0])
        new_doc.pop("shape", None)
        if old_doc != new_doc:
            return None
        rows = int(arr.chunks[0])
        n_new = len(values)
        out = np.zeros(-(-n_new // rows), dtype=bool)
        key = "/".join("0" for _ in values.shape[1:])
        for i in range(len(out)):
            a = i * rows
            b = min(n_new, a + rows)
            if b != min(n_old, a + rows) or a >= n_old:
                continue
            name = f"{i}/{key}" if key else str(i)
            mine = values[a:b].tobytes()
            if _chunk_bytes(self.old / "c" / name, len(mine)) != mine:
                continue
            target = new / "c" / name
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                os.link(self.old / "c" / name, target)
            except OSError:
                continue
            out[i] = True
        self.linked += int(out.sum())
        return out


def new_array(
    group: Any, name: str, shape: tuple[int, ...], dtype: np.dtype, chunks: tuple[int, ...]
) -> Any:
    """Create the empty array ``group/name`` as ``write_array`` does (same metadata, so the
    same bytes once filled): little-endian, the store's codecs, every chunk written."""
    dtype = np.dtype(dtype).newbyteorder("<")
    return group.create_array(
        name,
        shape=shape,
        chunks=tuple(max(1, c) for c in chunks) if shape else None,
        dtype=dtype,
        compressors=codecs(dtype),
        fill_value=0,
        config={"write_empty_chunks": True},
    )


def write_array(
    group: Any,
    name: str,
    data: Any,
    chunks: tuple[int, ...] | None = None,
    tap: Any = None,
    reuse: ChunkReuse | EqualChunks | None = None,
) -> Any:
    """Create ``group/name`` and fill it from ``data`` (an ndarray, or any 2-D array-like with
    ``shape``, ``dtype`` and slicing when ``chunks`` is given: then written block by block).

    tap: called as ``tap(r0, r1, c0, c1, values)`` with every 2-D slab written (half-open
    ranges), for a caller that wants to see the data once as it streams past. reuse: the
    chunks of a 2-D array that are hard links to an old store's chunk files instead of being
    written (``ChunkReuse``; a folder store only), or the chunks of an array chunked along
    axis 0 that hold the old array's bytes (``EqualChunks``).
    """
    shape = tuple(int(s) for s in data.shape)
    dtype = np.dtype(data.dtype).newbyteorder("<")
    if chunks is None:
        data = np.asarray(data)
        chunks = _row_chunks(shape, dtype.itemsize)
    arr = new_array(group, name, shape, dtype, chunks)
    if not math.prod(shape):
        return arr
    if isinstance(reuse, EqualChunks):
        _write_unlinked(arr, np.asarray(data, dtype=dtype), reuse)
        return arr
    if (isinstance(data, np.ndarray) and tap is None and reuse is None) or len(shape) != 2:
        arr[...] = np.asarray(data)
        return arr
    linker = reuse.linker(arr, chunks) if reuse is not None else None
    # Block by block: the source may be a lazy windowed array that never holds the band.
    rows, cols = shape
    rstep = chunks[0]
    cstep = max(chunks[1], (_HEIGHT_BLOCK_COLS // chunks[1]) * chunks[1])
    slabs = [
        (r0, min(rows, r0 + rstep), c0, min(cols, c0 + cstep))
        for r0 in range(0, rows, rstep)
        for c0 in range(0, cols, cstep)
    ]

    def copy(slab: tuple[int, int, int, int]) -> None:
        r0, r1, c0, c1 = slab
        if linker is not None and tap is None:
            # Chunk by chunk: an unchanged chunk is a hard link to the old store's file, and
            # only the others are read from the source.
            for a in range(r0, r1, chunks[0]):
                for b in range(c0, c1, chunks[1]):
                    if not linker(a // chunks[0], b // chunks[1]):
                        a1, b1 = min(r1, a + chunks[0]), min(c1, b + chunks[1])
                        arr[a:a1, b:b1] = np.asarray(data[a:a1, b:b1])
            return
        values = np.asarray(data[r0:r1, c0:c1])
        if tap is not None:
            tap(r0, r1, c0, c1, values)
        if linker is None:
            arr[r0:r1, c0:c1] = values
            return
        for a in range(r0, r1, chunks[0]):
            for b in range(c0, c1, chunks[1]):
                if not linker(a // chunks[0], b // chunks[1]):
                    block = values[a - r0 : a - r0 + chunks[0], b - c0 : b - c0 + chunks[1]]
                    arr[a : a + block.shape[0], b : b + block.shape[1]] = block

    # Slabs cover whole, disjoint chunks, so they are read (a raster decoded) and compressed
    # on a thread per core; at most two slabs per thread are in flight, bounding memory.
    threads = min(os.cpu_count() or 1, len(slabs))
    if threads <= 1:
        for slab in slabs:
            copy(slab)
        return arr
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(threads, thread_name_prefix="store-write") as pool:
        for start in range(0, len(slabs), 2 * threads):
            list(pool.map(copy, slabs[start : start + 2 * threads]))
    return arr


def _write_unlinked(arr: Any, values: np.ndarray, reuse: EqualChunks) -> None:
    """Fill ``arr`` (chunked along axis 0) from ``values``: the chunks equal to the old
    array's are links, each run of the others one write."""
    linked = reuse.linked_chunks(arr, values)
    if linked is None:
        arr[...] = values
        return
    rows = int(arr.chunks[0])
    todo = np.flatnonzero(~linked)
    if not len(todo):
        return
    breaks = np.flatnonzero(np.diff(todo) > 1)
    for first, last in zip(
        todo[np.concatenate([[0], breaks + 1])],
        todo[np.concatenate([breaks, [len(todo) - 1]])],
        strict=True,
    ):
        a, b = int(first) * rows, min(len(values), (int(last) + 1) * rows)
        arr[a:b] = values[a:b]


def _metadata_crc(node: Any) -> int:
    """CRC-32C of a node's metadata document as zarr parsed it (key order normalised)."""
    import crc32c

    doc = json.dumps(node.metadata.to_dict(), sort_keys=True, default=str)
    return crc32c.crc32c(doc.encode())


def _commit(root: Any, meta: dict[str, Any]) -> None:
    """Write the root attributes last: format, version, meta, metadata checksums."""
    # Sorted by path: zarr lists members in no fixed order, and a store should be byte-stable.
    sums = {path: _metadata_crc(node) for path, node in root.members(max_depth=None)}
    sums = dict(sorted(sums.items()))
    root.attrs.update(
        {"format": FORMAT, "format_version": FORMAT_VERSION, "meta": meta, "metadata_crc32c": sums}
    )


# -- atomic writing ----------------------------------------------------------------------------


@contextlib.contextmanager
def writing(path: str | os.PathLike, meta: dict[str, Any]) -> Iterator[Any]:
    """The root group of a new store at ``path``, committed (root attributes written, then
    the store renamed into place) when the block finishes cleanly; see the module docstring."""
    import zarr
    from zarr.storage import LocalStore

    from approxtree.io.atomic import (
        _registered,
        _sigterm_unwinds,
        _temp_path,
        atomic_directory,
        atomic_write,
        why_not_written,
    )

    text = str(path)
    try:
        if is_url(text):
            store = _open_zarr_store(text, read_only=False)
            root = zarr.open_group(store, mode="w")
            yield root
            _commit(root, meta)
        elif is_zip(text):
            # The path itself, never a link's target (atomic_write refuses a link).
            target = Path(text)
            if not target.parent.is_dir():
                raise StoreError(f"Cannot write {text}: the folder {target.parent} does not exist.")
            tmp = _temp_path(target)
            # SIGTERM unwinds too (the temp folder was left behind by a killed convert).
            with _sigterm_unwinds(), _registered(tmp):
                try:
                    os.mkdir(tmp)
                    root = zarr.open_group(LocalStore(str(tmp)), mode="w")
                    with _settled():
                        yield root
                        _commit(root, meta)
                    with atomic_write(target) as f:
                        _zip_folder(tmp, f)
                finally:
                    shutil.rmtree(tmp, ignore_errors=True)
        else:
            with atomic_directory(text) as tmp:
                root = zarr.open_group(LocalStore(str(tmp)), mode="w")
                with _settled():
                    yield root
                    _commit(root, meta)
    except StoreError:
        raise
    except OSError as exc:  # a full disk, a read-only folder, an unreachable URL...
        raise StoreError(
            f"Cannot write the tree store {text}: {why_not_written(text, exc)}."
        ) from exc


#: Seconds a failed write waits for zarr's writes still in flight (local writes end at once).
_SETTLE_SECONDS = 60.0


@contextlib.contextmanager
def _settled() -> Iterator[None]:
    """On failure, wait for the chunk writes zarr still has in flight before the temp store
    is removed: when one write fails (a full disk) zarr raises at once while its other writes
    go on, recreating the removed temp folder and, at exit, printing "Task was destroyed but
    it is pending" for each."""
    import asyncio

    from zarr.core.sync import sync

    async def rest() -> None:
        others = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        if others:
            await asyncio.wait(others, timeout=_SETTLE_SECONDS)

    try:
        yield
    except BaseException:
        with contextlib.suppress(Exception):
            sync(rest())
        raise


def _zip_folder(folder: Path, f: Any) -> None:
    """Every file below ``folder`` into the zip file object ``f`` (stored, not deflated)."""
    with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as z:
        for dirpath, _, files in os.walk(folder):
            for name in sorted(files):
                full = Path(dirpath) / name
                z.write(full, full.relative_to(folder).as_posix())


# -- reading -----------------------------------------------------------------------------------


def _json_object(value: object) -> dict[str, Any]:
    """A JSON attribute that must be an object, as a dict (TypeError when it is not)."""
    if not isinstance(value, Mapping):
        raise TypeError(f"expected a JSON object, got {type(value).__name__}")
    return dict(value)


def _wrap(location: str, what: str, exc: BaseException) -> StoreError:
    return StoreError(
        f"Tree store {location} is corrupted or incomplete ({what}: {exc}). Rebuild it with "
        "`approxtree build`, or restore it from a copy."
    )


class StoreReader:
    """A tree store opened read-only: checked root attributes, arrays on demand.

    Every read goes through the crc32c codec; zarr's and numcodecs' errors become
    StoreErrors naming the store. Opening checks that every chunk of every array is there
    (``check_chunks``): zarr reads a missing chunk as its fill value without a word, so a
    deleted chunk file would otherwise pass as zeros.

    check: False only where a checked reader is reopened (a pickled copy in a dask worker).
    """

    def __init__(self, path: str | os.PathLike, check: bool = True) -> None:
        import zarr

        self.location = str(path)
        self._store = _open_zarr_store(self.location, read_only=True)
        try:
            self.root = zarr.open_group(self._store, mode="r")
            attrs = dict(self.root.attrs)
        except Exception as exc:  # zarr raises many kinds: JSON, KeyError, NodeNotFound...
            raise _wrap(self.location, "root zarr.json", exc) from exc
        if attrs.get("format") != FORMAT:
            raise StoreError(
                f"{self.location} is not a complete approxtree tree store (its root attributes "
                "lack the format name: an interrupted write, or another zarr store). Rebuild it "
                "with `approxtree build`."
            )
        version = attrs.get("format_version")
        if version != FORMAT_VERSION:
            raise StoreError(
                f"{self.location} has tree store version {version!r}; this approxtree reads "
                f"version {FORMAT_VERSION}. Rebuild it with this version."
            )
        try:
            self.meta: dict[str, Any] = _json_object(attrs["meta"])
            sums = _json_object(attrs["metadata_crc32c"])
            self._sums: dict[str, int] = {k: int(v) for k, v in sums.items()}
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise _wrap(self.location, "root attributes", exc) from exc
        self._nodes: dict[str, Any] = {}
        if check:
            self.check_chunks()
        self._cache: OrderedDict[tuple[str, int], np.ndarray] = OrderedDict()
        self._cache_bytes = 0
        # Background loaders (the paging renderer) read patches from several threads.
        self._lock = threading.Lock()

    def __getstate__(self) -> dict[str, Any]:
        """Pickled (a dask task's tree, web tiles) without the lock and the caches: the
        receiver reopens the store at the same location."""
        return {"location": self.location}

    def __setstate__(self, state: dict[str, Any]) -> None:
        # The sender checked the chunks when it opened the store; a worker need not list it.
        self.__init__(state["location"], check=False)  # type: ignore[misc]

    def node(self, path: str) -> Any:
        """The zarr array or group at ``path``, its metadata checksum verified."""
        found = self._nodes.get(path)
        if found is not None:
            return found
        if path not in self._sums:
            raise StoreError(f"Tree store {self.location} has no {path!r}; rebuild it.")
        try:
            found = self.root[path]
            ok = _metadata_crc(found) == self._sums[path]
        except Exception as exc:
            raise _wrap(self.location, f"{path}/zarr.json", exc) from exc
        if not ok:
            raise StoreError(
                f"Tree store {self.location} is corrupted: {path}/zarr.json does not match its "
                "checksum. Rebuild it with `approxtree build`, or restore it from a copy."
            )
        self._nodes[path] = found
        return found

    def has(self, path: str) -> bool:
        return path in self._sums

    def attrs(self, path: str) -> dict[str, Any]:
        return dict(self.node(path).attrs)

    def children(self, path: str) -> list[str]:
        """Names of the direct members of group ``path`` (from the checksum table)."""
        prefix = f"{path}/"
        return sorted({p[len(prefix) :].split("/")[0] for p in self._sums if p.startswith(prefix)})

    def read(self, path: str, selection: Any = Ellipsis) -> np.ndarray:
        """``array[selection]`` of the array at ``path`` (checksummed chunks)."""
        arr = self.node(path)
        try:
            return np.asarray(arr[selection])
        except Exception as exc:
            raise _wrap(self.location, f"chunk {_bad_chunk(arr, selection)}of {path}", exc) from exc

    def read_rows(self, path: str, start: int, stop: int) -> np.ndarray:
        """Rows start..stop of a row-chunked array through a small LRU cache of decoded
        chunks, so patch reads of one subtree decode each chunk once."""
        arr = self.node(path)
        rows = int(arr.chunks[0])
        first, last = start // rows, max(start, stop - 1) // rows
        parts = []
        for c in range(first, last + 1):
            key = (path, c)
            with self._lock:
                chunk = self._cache.get(key)
                if chunk is not None:
                    self._cache.move_to_end(key)
            if chunk is None:
                chunk = self.read(path, slice(c * rows, (c + 1) * rows))
                chunk.flags.writeable = False
                with self._lock:
                    if key not in self._cache:
                        self._cache[key] = chunk
                        self._cache_bytes += chunk.nbytes
                    while self._cache_bytes > CHUNK_CACHE_BYTES and len(self._cache) > 1:
                        _, old = self._cache.popitem(last=False)
                        self._cache_bytes -= old.nbytes
            parts.append(chunk)
        block = parts[0] if len(parts) == 1 else np.concatenate(parts)
        # A copy: a patch must not keep a whole cached chunk alive.
        return block[start - first * rows : stop - first * rows].copy()

    def arrays(self) -> list[str]:
        """Paths of every array in the store."""
        return [p for p in self._sums if self._is_array(p)]

    def _is_array(self, path: str) -> bool:
        import zarr

        return isinstance(self.node(path), zarr.Array)

    def check_chunks(self) -> None:
        """StoreError naming the first array and chunk key whose chunk is not in the store.

        One listing of the store's keys against each array's chunk grid (every chunk is
        written, ``write_empty_chunks``): no chunk is read, so it is cheap enough for every
        open.
        """
        from zarr.core.sync import sync

        async def keys() -> set[str]:
            return {k async for k in self._store.list()}

        try:
            listed = sync(keys())
        except Exception as exc:
            raise _wrap(self.location, "listing", exc) from exc
        for path in sorted(self.arrays()):
            arr = self.node(path)
            grid = [range(n) for n in arr.cdata_shape]
            missing = [
                key
                for key in (arr.metadata.encode_chunk_key(c) for c in itertools.product(*grid))
                if f"{path}/{key}" not in listed
            ]
            if missing:
                raise StoreError(
                    f"Tree store {self.location} is incomplete: chunk {missing[0]} of {path} "
                    f"is missing ({len(missing)} of its {arr.nchunks} chunks absent). "
                    "Rebuild it with `approxtree build`, or restore it from a copy."
                )

    def verify(self, read_skip: tuple[str, ...] = ()) -> None:
        """Check each chunk's checksum by reading it (except arrays under the ``read_skip``
        path prefixes); that every chunk is present was checked when the store was opened."""
        for path in self.arrays():
            if path.startswith(read_skip):
                continue
            arr = self.node(path)
            for block in _blocks(arr.shape, arr.chunks):
                self.read(path, block)

    def sizes(self) -> dict[str, int]:
        """Bytes of the store: "stored" (chunks and metadata as written) and "raw" (arrays
        decoded)."""
        from zarr.core.sync import sync

        async def total() -> int:
            n = 0
            async for key in self._store.list():
                n += await self._store.getsize(key)
            return n

        try:
            stored = int(sync(total()))
        except Exception as exc:
            raise _wrap(self.location, "listing", exc) from exc
        raw = sum(int(self.node(p).nbytes) for p in self.arrays())
        return {"stored": stored, "raw": raw}

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._store.close()


def _bad_chunk(arr: Any, selection: Any) -> str:
    """The key of the first chunk under ``selection`` (slices, an Ellipsis) that fails to
    decode, followed by a space; "" when none is found alone (or the selection is another
    kind). Only called once a read has failed, to name the chunk in the error."""
    sel = selection if isinstance(selection, tuple) else (selection,)
    if any(s is not Ellipsis and not isinstance(s, slice) for s in sel):
        return ""
    sel = tuple(s for s in sel if s is not Ellipsis)
    sel = sel + (slice(None),) * (len(arr.shape) - len(sel))
    ranges = []
    for s, n, c in zip(sel, arr.shape, arr.chunks, strict=False):
        start, stop, _ = s.indices(n)
        ranges.append(range(start // c, -(-stop // c)) if stop > start else range(0))
    for coords in itertools.islice(itertools.product(*ranges), 4096):
        try:
            arr.blocks[coords]
        except Exception:
            return f"{arr.metadata.encode_chunk_key(coords)} "
    return ""


def _blocks(shape: tuple[int, ...], chunks: tuple[int, ...]) -> Iterator[tuple[slice, ...]]:
    """Selections of a few chunks at a time along axis 0 (bounded memory when verifying)."""
    if not shape or not math.prod(shape):
        yield tuple(slice(None) for _ in shape)
        return
    step = chunks[0] * max(1, (16 << 20) // max(1, math.prod(chunks[1:]) * chunks[0] * 8))
    for r0 in range(0, shape[0], step):
        yield (slice(r0, r0 + step), *(slice(None) for _ in shape[1:]))


class ZarrHeightSource:
    """A HeightSource over the terrain heights of a tree store: ``read(r0, r1, c0, c1)`` reads
    the half-open window [r0, r1) × [c0, c1) as float (NaN = nodata), chunk by chunk.

    Pickles by location and path (the array is reopened on first read), never by the data.
    """

    def __init__(
        self, location: str, path: str = "terrain/heights", reader: StoreReader | None = None
    ) -> None:
        self.location = location
        self.path = path
        self._reader = reader
        self._check = True
        arr = self._open().node(path)
        # Checked now (or by the reader passed in): a reopened copy after pickling need not be.
        self._check = False
        self.shape: tuple[int, int] = (int(arr.shape[0]), int(arr.shape[1]))
        self.dtype = np.dtype(arr.dtype).newbyteorder("=")
        #: The array's chunks: the blocks a WindowedHeights over this source reads whole.
        self.block_shape: tuple[int, int] = (int(arr.chunks[0]), int(arr.chunks[1]))

    def _open(self) -> StoreReader:
        if self._reader is None:
            self._reader = StoreReader(self.location, check=self._check)
        return self._reader

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """(r1 − r0, c1 − c0) heights of the window (native byte order)."""
        out = self._open().read(self.path, (slice(r0, r1), slice(c0, c1)))
        return out.astype(self.dtype, copy=False)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_reader"] = None
        return state

    def __repr__(self) -> str:
        return f"ZarrHeightSource({self.location!r}, {self.path!r}, shape={self.shape})"
