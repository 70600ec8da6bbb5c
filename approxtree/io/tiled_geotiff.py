"""Write a height source of any size as a tiled, compressed GeoTIFF (or COG), block by block.

Blocks are computed by dask (threads: the height kernels release the GIL) and written by one
writer under a lock, so memory holds a few blocks whatever the raster's size. The file is
written beside the target and renamed into place once GDAL's write is checked (``io.gdal``:
a full disk is a StoreError, never a truncated file in place of the old one).
"""

from __future__ import annotations

import math
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.geometry.windowed import HeightSource
from approxtree.io._common import MAX_WORKERS_PER_CORE, most_workers

#: Internal tile edge (cells): the COG default, and what GDAL readers expect.
TILE = 512

#: GDAL's block cache while writing: enough for a row of tiles, never a copy of the raster
#: (GDAL's default is 5 % of RAM and would hold written tiles there).
_WRITE_CACHE_MB = 64

COMPRESSIONS = ("deflate", "zstd", "lzw", "none")


def _creation_options(compress: str, dtype: np.dtype) -> dict[str, Any]:
    """GDAL creation options: 512² tiles, compression with the predictor of the data type."""
    if compress not in COMPRESSIONS:
        raise InvalidParameterError(
            f"Unknown compression {compress!r}; choose one of {', '.join(COMPRESSIONS)}."
        )
    options: dict[str, Any] = {
        "tiled": True,
        "blockxsize": TILE,
        "blockysize": TILE,
        # BigTIFF when the file might pass 4 GB (GDAL decides from the uncompressed size).
        "BIGTIFF": "IF_SAFER",
        "NUM_THREADS": "ALL_CPUS",
    }
    if compress != "none":
        options["compress"] = compress
        # Floating-point predictor (3) for floats, horizontal differencing (2) for integers.
        options["predictor"] = 3 if np.dtype(dtype).kind == "f" else 2
    if compress == "zstd":
        options["ZSTD_LEVEL"] = 3
    return options


class _BandWriter:
    """The target of ``dask.array.store``: writes each block into band 1 of an open dataset.

    dask calls ``__setitem__`` from its worker threads; the store's lock makes one writer.
    Once ``closed`` (set under that lock), a block still being computed writes nothing: an
    interrupt (Ctrl-C, SIGTERM) leaves dask's threads running while the dataset is closed, and
    their writes into it crashed the process (segfault) before the temp file was removed.
    """

    def __init__(self, dataset: Any, bar: Any) -> None:
        self.dataset = dataset
        self.bar = bar
        self.shape = (dataset.height, dataset.width)
        self.dtype = np.dtype(dataset.dtypes[0])
        self.ndim = 2
        self.closed = False

    def __setitem__(self, key: tuple[slice, slice], block: np.ndarray) -> None:
        from rasterio.windows import Window

        if self.closed:
            return
        rows, cols = key
        window = Window(cols.start, rows.start, cols.stop - cols.start, rows.stop - rows.start)
        self.dataset.write(block, 1, window=window)
        if self.bar is not None:
            self.bar.update(1)


def _dask_blocks(source: HeightSource, block: int) -> Any:
    """The source as a dask array of block × block chunks, each read on its own."""
    import dask.array as da

    rows, cols = source.shape

    def chunk(block_info: dict[Any, Any] | None = None) -> np.ndarray:
        # dask passes the chunk's place to a function that takes block_info.
        if block_info is None:
            raise TypeError("map_blocks gave no block_info")
        (r0, r1), (c0, c1) = block_info[None]["array-location"]
        return np.asarray(source.read(r0, r1, c0, c1), dtype=source.dtype)

    chunks = tuple(tuple(min(block, n - i) for i in range(0, n, block)) for n in (rows, cols))
    return da.map_blocks(
        chunk, chunks=chunks, dtype=source.dtype, meta=np.empty((0, 0), source.dtype)
    )


def write_tiled_geotiff(
    path: str | os.PathLike,
    source: HeightSource,
    transform: Any,
    *,
    crs: str | None = None,
    nodata: float | None = None,
    compress: str = "deflate",
    cog: bool = False,
    workers: int | None = None,
    block: int = 2048,
    progress: bool | None = None,
    tags: dict[str, str] | None = None,
) -> Path:
    """Write ``source`` (rows, cols) as band 1 of a GeoTIFF with 512 × 512 tiles.

    transform: the affine georeference; crs: any CRS rasterio understands (None: none);
    nodata: the nodata value written in the file (NaN for float sources with holes);
    compress: deflate, zstd, lzw or none (with the predictor of the data type); cog: a Cloud
    Optimized GeoTIFF with overviews (GDAL's COG driver copies the tiled file, tile by tile);
    workers: dask threads (default: the core count); block: cells per dask block edge, a
    multiple of 512; progress: a tqdm bar of blocks written (None = when over 16 blocks);
    tags: dataset tags written in the file. Returns the path written.
    """
    import rasterio
    from rasterio.errors import RasterioError
    from tqdm.auto import tqdm

    from approxtree.io.atomic import atomic_path, scratch_path
    from approxtree.io.gdal import checked_write

    options = _creation_options(compress, source.dtype)
    if isinstance(block, bool) or not isinstance(block, int) or block < TILE or block % TILE:
        raise InvalidParameterError(
            f"block must be a multiple of {TILE} cells (the tile size), got {block!r}."
        )
    if workers is not None and (isinstance(workers, bool) or not 1 <= workers <= most_workers()):
        raise InvalidParameterError(
            f"workers must be a number of threads from 1 to at most {most_workers()} "
            f"({MAX_WORKERS_PER_CORE} a core here), got {workers!r}."
        )
    crs = _check_crs(crs)
    rows, cols = source.shape
    target = Path(path)
    # Known before the first block: what the file will take, and whether the disk has it.
    needed = estimated_bytes(source, options, cog)
    check_room(target, needed, source.shape)
    blocks = _dask_blocks(source, block)
    nblocks = math.prod(len(c) for c in blocks.chunks)
    profile = dict(
        driver="GTiff",
        width=cols,
        height=rows,
        count=1,
        dtype=source.dtype,
        crs=crs,
        transform=transform,
        nodata=nodata,
        **options,
    )
    show = nblocks > 16 if progress is None else progress
    with (
        atomic_path(target) as tmp,
        tqdm(
            total=nblocks,
            unit="block",
            desc=f"GeoTIFF blocks (~{_human(needed)} on disk)",
            disable=not show,
        ) as bar,
        rasterio.Env(GDAL_CACHEMAX=_WRITE_CACHE_MB << 20),
    ):
        try:
            if cog:
                # The COG driver copies a finished raster: tiles first, then the COG beside.
                with scratch_path(target) as tiled:
                    with checked_write(tiled, target):
                        _write_blocks(tiled, profile, blocks, bar, workers, tags)
                    with checked_write(tmp, target):
                        _copy_as_cog(tiled, tmp, compress)
            else:
                with checked_write(tmp, target):
                    _write_blocks(tmp, profile, blocks, bar, workers, tags)
        except RasterioError as exc:
            raise StoreError(f"Cannot write {target}: {exc}") from exc
    return target


def estimated_bytes(source: HeightSource, options: dict[str, Any], cog: bool) -> int:
    """Bytes the GeoTIFF of ``source`` will need on disk while it is written: one 512 × 512
    tile from the middle of the raster, compressed as the file will be, scaled to the whole
    (plus a tenth), times 7/3 for a COG (the tiled file and the COG with its overviews exist
    together for a moment)."""
    from rasterio.io import MemoryFile

    rows, cols = source.shape
    h, w = min(TILE, rows), min(TILE, cols)
    r0, c0 = (rows - h) // 2, (cols - w) // 2
    sample = np.asarray(source.read(r0, r0 + h, c0, c0 + w), dtype=source.dtype)
    from affine import Affine

    profile = dict(driver="GTiff", width=w, height=h, count=1, dtype=source.dtype, **options)
    # Any georeference but the identity (GDAL warns of that one); compressed on one thread.
    north_up = Affine.translation(0.0, float(h)) @ Affine.scale(1.0, -1.0)
    profile.update(transform=north_up, NUM_THREADS=1)
    with MemoryFile() as mem:
        with mem.open(**profile) as ds:
            ds.write(sample, 1)
        ratio = len(mem.getbuffer()) / sample.nbytes
    nbytes = int(1.1 * ratio * rows * cols * np.dtype(source.dtype).itemsize) + (1 << 16)
    return nbytes * 7 // 3 if cog else nbytes


#: Rows and columns a GeoTIFF can hold (GDAL's raster sizes are C ints).
MAX_SIDE = 2**31 - 1


def check_room(target: Path, needed: int, shape: tuple[int, int]) -> None:
    """StoreError before any work when a raster of ``shape`` is beyond what a GeoTIFF holds,
    or when its ``needed`` bytes do not fit in the free space of ``target``'s disk."""
    import shutil

    if max(shape) > MAX_SIDE:
        raise InvalidParameterError(
            f"A GeoTIFF holds at most {MAX_SIDE:,} rows and columns; {shape[0]:,} × "
            f"{shape[1]:,} cells asked. Give a smaller size."
        )
    folder = target.absolute().parent
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if needed > free:
        raise StoreError(
            f"Cannot write {target}: {shape[0]:,} × {shape[1]:,} cells need about "
            f"{_human(needed)} on disk ({needed:,} bytes), and the disk at {folder} has "
            f"{_human(free)} free. Give a smaller size, more compression, or another folder."
        )


def _human(nbytes: int) -> str:
    """1234567 → '1.2 MB'."""
    size = float(nbytes)
    for unit in ("bytes", "kB", "MB", "GB", "TB"):
        if size < 1000 or unit == "TB":
            return f"{size:.0f} {unit}" if unit == "bytes" else f"{size:.1f} {unit}"
        size /= 1000
    return f"{size:.1f} PB"  # pragma: no cover


def _write_blocks(
    path: Path,
    profile: dict,
    blocks: Any,
    bar: Any,
    workers: int | None,
    tags: dict[str, str] | None = None,
) -> None:
    """Compute the dask blocks in threads and write them into a new GeoTIFF at ``path``."""
    import dask.array as da
    import rasterio

    with rasterio.open(path, "w", **profile) as ds:
        if tags:
            ds.update_tags(**tags)
        # One lock: blocks are computed in parallel, written one at a time.
        lock = threading.Lock()
        writer = _BandWriter(ds, bar)
        try:
            # dask annotates targets as arrays, though it documents (and needs) only __setitem__.
            da.store(
                blocks,
                writer,  # type: ignore[arg-type]
                lock=lock,
                scheduler="threads",
                num_workers=workers or os.cpu_count() or 1,
            )
        finally:
            # Before the dataset closes: no write from a thread dask left running.
            with lock:
                writer.closed = True


def _copy_as_cog(src: Path, dst: Path, compress: str) -> None:
    """GDAL's COG driver: tiles, overviews (average) before the full-resolution data."""
    from rasterio.shutil import copy

    options: dict[str, Any] = {
        "BLOCKSIZE": TILE,
        "BIGTIFF": "IF_SAFER",
        "NUM_THREADS": "ALL_CPUS",
        "OVERVIEWS": "AUTO",
        "RESAMPLING": "AVERAGE",
        "COMPRESS": compress.upper() if compress != "none" else "NONE",
    }
    if compress != "none":
        options["PREDICTOR"] = "YES"
    copy(src, dst, driver="COG", **options)


def _check_crs(crs: str | None) -> Any:
    """A CRS rasterio understands, or an error saying how to name one."""
    if crs is None:
        return None
    import pyproj
    from rasterio.crs import CRS
    from rasterio.errors import CRSError

    # pyproj first: it refuses an unknown CRS without GDAL printing "ERROR 1: PROJ" lines.
    try:
        pyproj.CRS.from_user_input(crs)
        return CRS.from_user_input(crs)
    except (pyproj.exceptions.CRSError, CRSError, ValueError, TypeError) as exc:
        raise InvalidParameterError(
            f"Unknown CRS {crs!r}; give it as EPSG:NNNN, a WKT string or a PROJ string."
        ) from exc
