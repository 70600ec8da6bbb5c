"""The model a GeoTIFF's own GeoKeys declare, read from the file's bytes without GDAL.

GDAL builds a raster's CRS from its GeoKeys (through libgeotiff and PROJ) and reports one it
could not build as no CRS at all: rasterio's ``crs`` is then None, exactly as for a file that
has none. ``declared_model`` is the second witness ``raster.check_crs_read`` asks when GDAL
gave none: the first image's GeoKeyDirectoryTag (34735) and, in it, GTModelTypeGeoKey (1024).

Only what locates that one key is parsed (the header, the first IFD, the key directory), in
classic TIFF and BigTIFF, either byte order. Anything else (not a TIFF, no GeoKeys, a
user-defined model, a damaged header) answers None: the witness only ever adds an error.
"""

from __future__ import annotations

import os
import struct
import zipfile
from typing import IO

#: TIFF tag of the GeoKey directory (SHORT values: a 4-value header, then 4 per key).
GEO_KEY_DIRECTORY_TAG = 34735
#: GeoKey of the model: 1 projected, 2 geographic, 3 geocentric (GeoTIFF 1.1, 7.3.1).
GT_MODEL_TYPE_GEO_KEY = 1024
MODELS = {1: "projected", 2: "geographic", 3: "geocentric"}
#: The TIFF SHORT type code (the key directory's type).
_SHORT = 3
#: IFD entries read at most (a first IFD holds a few dozen tags; more is a damaged file).
_MOST_ENTRIES = 4096


def declared_model(path: str | os.PathLike, member: str | None = None) -> str | None:
    """The model ("projected", "geographic" or "geocentric") the TIFF at ``path`` (or the
    zip archive ``path``'s ``member``) declares in its first image's GeoKeys; else None."""
    try:
        if member is not None:
            with zipfile.ZipFile(path) as archive, archive.open(member) as f:
                return _model_of(f)
        with open(path, "rb") as f:
            return _model_of(f)
    except (OSError, zipfile.BadZipFile, KeyError, struct.error, ValueError):
        return None


def _model_of(f: IO[bytes]) -> str | None:
    """The declared model of the TIFF read from the seekable binary file ``f``, or None."""
    head = f.read(16)
    if head[:2] not in (b"II", b"MM"):
        return None
    order = "<" if head[:2] == b"II" else ">"
    (magic,) = struct.unpack(order + "H", head[2:4])
    # Classic TIFF: 4-byte offsets, 12-byte entries; BigTIFF (43): 8-byte ones, 20-byte entries.
    if magic == 42:
        (ifd,) = struct.unpack(order + "I", head[4:8])
        count_fmt, entry_fmt, inline = "H", "HHII", 4
    elif magic == 43:
        (ifd,) = struct.unpack(order + "Q", head[8:16])
        count_fmt, entry_fmt, inline = "Q", "HHQQ", 8
    else:
        return None
    directory = _geokey_directory(f, order, ifd, count_fmt, entry_fmt, inline)
    if directory is None or len(directory) < 4:
        return None
    # Header (version, revision, minor, key count), then (key, location, count, value) each;
    # location 0 means the value is the SHORT itself.
    keys = min(directory[3], (len(directory) - 4) // 4)
    for k in range(keys):
        key, location, _count, value = directory[4 + 4 * k : 8 + 4 * k]
        if key == GT_MODEL_TYPE_GEO_KEY and location == 0:
            return MODELS.get(value)
    return None


def _geokey_directory(
    f: IO[bytes], order: str, ifd: int, count_fmt: str, entry_fmt: str, inline: int
) -> tuple[int, ...] | None:
    """The SHORT values of the first IFD's GeoKeyDirectoryTag, or None when it has none."""
    f.seek(ifd)
    count_size = struct.calcsize(order + count_fmt)
    (entries,) = struct.unpack(order + count_fmt, f.read(count_size))
    if entries > _MOST_ENTRIES:
        return None
    entry_size = struct.calcsize(order + entry_fmt)
    table = f.read(entries * entry_size)
    for e in range(entries):
        tag, kind, count, value = struct.unpack_from(order + entry_fmt, table, e * entry_size)
        if tag != GEO_KEY_DIRECTORY_TAG:
            continue
        if kind != _SHORT or count > 4 * 65536:
            return None
        nbytes = 2 * count
        # A value that fits in the entry is stored there, left-aligned; else it is an offset.
        if nbytes <= inline:
            start = e * entry_size + struct.calcsize(order + "HH" + entry_fmt[2])
            data = table[start : start + nbytes]
        else:
            f.seek(value)
            data = f.read(nbytes)
        if len(data) != nbytes:
            return None
        return struct.unpack(order + "H" * count, data)
    return None
