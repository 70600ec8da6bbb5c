"""Independent checks of approxtree's outputs against their source terrain (``approxtree verify``).

``verify(output, source)`` detects what ``output`` is (``verify.detect``) and recomputes, with
none of the writers' code (no tiles, patches, pyramid halving nor their kernels: zarr,
pygltflib, quantized-mesh-tile, pyproj and rasterio read the files, ``kernels.verify_mesh``
measures), whether every claim it makes holds:

- tree store (``verify.tree_store``): every node's error against the true max ``|h_TN − h_T|``
  over the source's data points, leaves within ε, bounding boxes, children partitioning their
  parent, every chunk present and decoding, the metadata checksums, every node's patch;
- mesh file (``verify.mesh``): its max error (GLB extras, PLY comment, OBJ header, or
  ``max_error`` given) over the data points under it;
- 3D Tiles (``verify.tiles3d``): every content referenced exists and parses, each tile's error
  (its positions taken back to the terrain's CRS) within its geometricError, volumes nested;
- quantized-mesh (``verify.quantized_mesh``): every tile layer.json lists exists and decodes,
  each within its level's error at the DEM's data points (the height quantization allowed);
- texture pyramid (``verify.pyramid``): every level decodes, halves the one before, covers the
  source, matches its tile checksums;
- raster-dem and imagery tiles, folder or PMTiles (``verify.map_tiles``): every tile listed
  exists and decodes, each raster-dem height within its encoding's step of h_T at the pixel's
  centre, each imagery pixel within its format's tolerance of the texture pyramid (given as
  ``textures``) resampled at its centre.

The result is a ``VerifyReport`` (``ok``, checks, worst offenders, figures, what was not
checked). Bad input (a missing or unrecognised output, an unreadable source) raises an
ApproxTreeError.
"""

from __future__ import annotations

import os
import sys
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

from approxtree.verify.detect import detect_kind
from approxtree.verify.report import Check, Offender, VerifyReport


def _tree_store(output: Path, terrain: Any, report: VerifyReport, options: dict) -> None:
    from approxtree.verify.tree_store import verify_tree_store
    from approxtree.verify.zarr_read import StoreFiles

    files = StoreFiles(output)
    try:
        verify_tree_store(files, terrain, report)
    finally:
        files.close()


def _mesh(output: Path, terrain: Any, report: VerifyReport, options: dict) -> None:
    from approxtree.verify.mesh import verify_mesh

    verify_mesh(output, terrain, report, options.get("max_error"))


def _tiles3d(output: Path, terrain: Any, report: VerifyReport, options: dict) -> None:
    from approxtree.verify.tiles3d import verify_3dtiles

    verify_3dtiles(output, terrain, report)


def _quantized_mesh(output: Path, terrain: Any, report: VerifyReport, options: dict) -> None:
    from approxtree.verify.quantized_mesh import verify_quantized_mesh

    verify_quantized_mesh(output, terrain, report)


def _pyramid(output: Path, terrain: Any, report: VerifyReport, options: dict) -> None:
    from approxtree.verify.pyramid import verify_pyramid

    verify_pyramid(
        output,
        terrain,
        report,
        options.get("hillshade", False),
        options.get("source_path"),
        options.get("image"),
        options.get("resampling", "bilinear"),
    )


def _map_tiles(output: Path, terrain: Any, report: VerifyReport, options: dict) -> None:
    from approxtree.verify.map_tiles import verify_map_tiles

    verify_map_tiles(output, terrain, report, options.get("textures"))


#: Kind of output → the verification of that kind.
VERIFIERS: dict[str, Callable[[Path, Any, VerifyReport, dict], None]] = {
    "tree-store": _tree_store,
    "mesh": _mesh,
    "3dtiles": _tiles3d,
    "quantized-mesh": _quantized_mesh,
    "texture-pyramid": _pyramid,
    "raster-dem": _map_tiles,
    "imagery": _map_tiles,
}


def verify(
    output: str | os.PathLike,
    source: Any = None,
    *,
    max_error: float | None = None,
    hillshade: bool = False,
    source_file: str | os.PathLike | None = None,
    textures: Any = None,
    image: str | os.PathLike | None = None,
    resampling: str = "bilinear",
    **reader_options: Any,
) -> VerifyReport:
    """Check the approxtree output ``output`` against its source terrain (module docstring).

    source: the terrain file the output was made from (read with ``open_terrain`` and
    ``reader_options``), or a GeometryData; None checks what needs no source (completeness,
    checksums, structure). max_error: the error a mesh file claims when it records none.
    hillshade: a texture pyramid is a plain hillshade bake at gdaldem's defaults (level 0 is
    then compared with ``gdaldem hillshade`` of the source file). source_file: the file a
    GeometryData ``source`` was read from (named in the report, given to gdaldem). textures:
    the texture pyramid imagery tiles were cut from (their colours are checked): its folder, a
    TexturePyramid, or a DetailTextures when a detail was laid over from a zoom. image: a
    texture pyramid is a bake of this image alone (``--shading none --image``), warped with
    ``resampling`` (gdalwarp's -r name): every level is compared with the image's
    box-filtered reprojection.
    """
    from approxtree.errors import InvalidParameterError

    if max_error is not None and not (max_error >= 0):
        raise InvalidParameterError(f"max_error must be a number >= 0, got {max_error!r}.")
    if image is not None and not Path(image).is_file():
        from approxtree.errors import TerrainFormatError

        raise TerrainFormatError(f"Image {image} does not exist.")
    from approxtree.io.warp import RESAMPLINGS

    if resampling not in RESAMPLINGS:
        raise InvalidParameterError(
            f"Unknown resampling {resampling!r}; choose one of {', '.join(RESAMPLINGS)}."
        )
    path = Path(output)
    kind = detect_kind(path)
    terrain = _open_source(source, reader_options)
    if source_file is None and isinstance(source, (str, os.PathLike)):
        source_file = source
    name = (
        str(source_file) if source_file is not None else (None if source is None else repr(source))
    )
    report = VerifyReport(kind, str(path), name)
    if terrain is None:
        report.not_checked.append("errors against the terrain: no source given")
    options = {
        "max_error": max_error,
        "hillshade": hillshade,
        "source_path": None if source_file is None else str(source_file),
        "textures": Path(textures) if isinstance(textures, (str, os.PathLike)) else textures,
        "image": None if image is None else str(image),
        "resampling": resampling,
    }
    VERIFIERS[kind](path, terrain, report, options)
    return report


def _open_source(source: Any, options: dict[str, Any]) -> Any:
    """The source terrain: None, a GeometryData as given, or a terrain file read now."""
    from approxtree.geometry.base import GeometryData

    if source is None or isinstance(source, GeometryData):
        return source
    from approxtree.io import open_terrain

    return open_terrain(source, **options)


class _CallableModule(types.ModuleType):
    """This package is also the function ``approxtree.verify``: once the package is imported,
    Python binds the name ``approxtree.verify`` to it (not to the function), so calling the
    package calls ``verify``."""

    def __call__(self, *args: Any, **kwargs: Any) -> VerifyReport:
        return verify(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule

__all__ = ["Check", "Offender", "VerifyReport", "detect_kind", "verify"]
