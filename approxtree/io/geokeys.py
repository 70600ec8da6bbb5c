"""The model a GeoTIFF's own GeoKeys declare, read through tifffile (not GDAL).

GDAL builds a raster's CRS from its GeoKeys (through libgeotiff and PROJ) and reports one it
could not build as no CRS at all: rasterio's ``crs`` is then None, exactly as for a file that
has none. ``declared_model`` is the second witness ``raster.check_crs_read`` asks when GDAL
gave none: GTModelTypeGeoKey (1024) of the first image's GeoKeyDirectoryTag (34735), as
tifffile decodes it (classic TIFF and BigTIFF, either byte order). Anything else (not a TIFF,
no GeoKeys, a user-defined model, a damaged file) answers None: the witness only ever adds an
error.
"""

from __future__ import annotations

import io
import os
import zipfile

#: GTModelTypeGeoKey's values: 1 projected, 2 geographic, 3 geocentric (GeoTIFF 1.1, 7.3.1).
MODELS = {1: "projected", 2: "geographic", 3: "geocentric"}


def declared_model(path: str | os.PathLike, member: str | None = None) -> str | None:
    """The model ("projected", "geographic" or "geocentric") the TIFF at ``path`` (or the
    zip archive ``path``'s ``member``) declares in its first image's GeoKeys; else None."""
    import tifffile

    try:
        if member is not None:
            with zipfile.ZipFile(path) as archive, archive.open(member) as f:
                # tifffile seeks: a zip member is read into memory (only on this rare path).
                with tifffile.TiffFile(io.BytesIO(f.read())) as tif:
                    return _model_of(tif)
        with tifffile.TiffFile(path) as tif:
            return _model_of(tif)
    except (OSError, zipfile.BadZipFile, KeyError, ValueError, tifffile.TiffFileError):
        return None


def _model_of(tif) -> str | None:
    """The declared model of an open tifffile.TiffFile, or None."""
    tag = tif.pages[0].tags.get(34735) if len(tif.pages) else None
    if tag is None:
        return None
    directory = tuple(int(v) for v in tag.value)
    # Header (version, revision, minor, key count), then (key, location, count, value) each;
    # location 0 means the value is the SHORT itself.
    keys = min(directory[3], (len(directory) - 4) // 4) if len(directory) >= 4 else 0
    for k in range(keys):
        key, location, _count, value = directory[4 + 4 * k : 8 + 4 * k]
        if key == 1024 and location == 0:
            return MODELS.get(value)
    return None
