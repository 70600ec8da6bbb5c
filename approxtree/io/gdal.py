"""GDAL as approxtree uses it: reads leave nothing beside the user's files, writes are checked.

- ``no_side_files()``: GDAL's PAM writes ``X.aux.xml`` beside a raster it read when it learnt
  something (statistics, ...). Within the block PAM is off for datasets opened by this thread
  only (a thread-local GDAL config option), so a host program's own GDAL use keeps its
  settings; where the option cannot be set so (no GDAL symbols reachable), ``rasterio.Env``
  sets it for the block instead.
- ``checked_write(path)``: GDAL reports a failed write (a full disk) as log messages, not as
  an exception, and libtiff prints its own to stderr; rasterio then closes the file as if all
  went well. Within the block libtiff's printer is off and rasterio's logged errors are
  collected; the block ends in a StoreError when any was logged, when rasterio raised, or
  when the closed GeoTIFF misses a block (``check_geotiff``). (rasterio's records of GDAL
  errors are logged at INFO meanwhile: a host program logging INFO sees them too.)
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import logging
import os
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from approxtree.errors import StoreError
from approxtree.io.paths import disk_full, public_path

#: rasterio's log records of a GDAL error (CE_Failure) start with this.
_GDAL_ERROR = "GDAL signalled an error"
_RASTERIO_LOGGER = "rasterio"

_lock = threading.Lock()
#: Writes within ``checked_write`` now, and what they changed (restored by the last to leave).
_writers = 0
_saved: dict[str, Any] = {}


def _gdal() -> Any | None:
    """A ctypes handle through which GDAL's and libtiff's symbols resolve (the libraries
    rasterio's extension module is linked with), or None."""
    try:
        import rasterio._base

        return ctypes.CDLL(rasterio._base.__file__)
    except (OSError, AttributeError, ImportError):
        return None


def _symbol(name: str, restype: Any, argtypes: list[Any]) -> Any | None:
    lib = _gdal()
    try:
        fn = getattr(lib, name)
    except AttributeError:
        return None
    fn.restype, fn.argtypes = restype, argtypes
    return fn


@contextlib.contextmanager
def no_side_files() -> Iterator[None]:
    """Within the block, rasters opened by this thread write no PAM side file (.aux.xml)."""
    get = _symbol("CPLGetThreadLocalConfigOption", ctypes.c_char_p, [ctypes.c_char_p] * 2)
    put = _symbol("CPLSetThreadLocalConfigOption", None, [ctypes.c_char_p] * 2)
    if get is None or put is None:
        import rasterio

        with rasterio.Env(GDAL_PAM_ENABLED="NO"):
            yield
        return
    key = b"GDAL_PAM_ENABLED"
    before = get(key, None)
    put(key, b"NO")
    try:
        yield
    finally:
        put(key, before)


class _Collect(logging.Handler):
    """Keeps the messages of rasterio's GDAL error records logged by any thread."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if message.startswith(_GDAL_ERROR):
            self.messages.append(message)


def _enter_write() -> None:
    """The first write turns libtiff's stderr printer off and rasterio's INFO records on."""
    global _writers
    with _lock:
        _writers += 1
        if _writers > 1:
            return
        logger = logging.getLogger(_RASTERIO_LOGGER)
        _saved["level"] = logger.level
        if not logger.isEnabledFor(logging.INFO):
            logger.setLevel(logging.INFO)
        handler = _symbol("TIFFSetErrorHandler", ctypes.c_void_p, [ctypes.c_void_p])
        if handler is not None:
            _saved["tiff"] = (handler, handler(None))


def _leave_write() -> None:
    global _writers
    with _lock:
        _writers -= 1
        if _writers:
            return
        logging.getLogger(_RASTERIO_LOGGER).setLevel(_saved.pop("level"))
        if "tiff" in _saved:
            handler, before = _saved.pop("tiff")
            handler(before)


def _reason(path: Path, messages: list[str], exc: BaseException | None) -> str:
    """Why a GDAL write failed, in words: a full disk when the folder's disk has no room."""
    code = getattr(exc, "errno", None)
    try:
        nearly_full = shutil.disk_usage(path.absolute().parent).free < (1 << 20)
    except OSError:
        nearly_full = False
    if code in (errno.ENOSPC, errno.EDQUOT) or nearly_full:
        return disk_full(path)
    detail = messages[0].split("msg=", 1)[-1] if messages else str(exc)
    return f"GDAL could not write it ({detail.strip(chr(39))})"


@contextlib.contextmanager
def checked_write(
    path: str | os.PathLike, target: str | os.PathLike | None = None
) -> Iterator[None]:
    """Around a rasterio write of ``path`` (closed within the block): StoreError naming
    ``target`` (default: ``path`` without our temp names, ``paths.public_path``) when GDAL
    logged an error, rasterio raised, or the written GeoTIFF misses a block. libtiff prints
    nothing to stderr meanwhile."""
    from rasterio.errors import RasterioError

    path = Path(path)
    target = Path(target) if target is not None else public_path(path)
    collect = _Collect()
    logger = logging.getLogger(_RASTERIO_LOGGER)
    _enter_write()
    logger.addHandler(collect)
    failure: BaseException | None = None
    try:
        yield
    except (RasterioError, OSError) as exc:
        failure = exc
    finally:
        logger.removeHandler(collect)
        _leave_write()
    if failure is not None or collect.messages:
        why = _reason(path, collect.messages, failure)
        raise StoreError(f"Cannot write {target}: {why}.") from failure
    missing = check_geotiff(path)
    if missing:
        raise StoreError(f"Cannot write {target}: {_reason(path, [], None)} ({missing}).")


def check_geotiff(path: str | os.PathLike) -> str | None:
    """What a closed tiled GeoTIFF misses (a block not written, or one past the end of the
    file), or None when every block of every band is in the file."""
    import rasterio
    from rasterio.errors import RasterioError

    size = os.path.getsize(path)
    try:
        with no_side_files(), rasterio.open(path) as ds:
            for band in ds.indexes:
                for (i, j), _ in ds.block_windows(band):
                    offset = ds.get_tag_item(f"BLOCK_OFFSET_{j}_{i}", "TIFF", bidx=band)
                    nbytes = ds.get_tag_item(f"BLOCK_SIZE_{j}_{i}", "TIFF", bidx=band)
                    if not offset or not nbytes or int(offset) + int(nbytes) > size:
                        return f"block {i}, {j} of band {band} is not in the file"
    except RasterioError as exc:
        return f"it does not read back: {exc}"
    return None
