"""LAS/LAZ point clouds through laspy (LAZ decompressed by the lazrs backend).

The scaled x, y, z coordinates become a TINPointSet (which merges points sharing an (x, y)
position into their mean height). The CRS comes from the WKT VLR when the file has one, else
from an EPSG code in the GeoTIFF keys; pyproj is not needed.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from approxtree.errors import EmptyTerrainError
from approxtree.geometry import TINPointSet
from approxtree.geometry.tin import gap_fill_points
from approxtree.io._common import check_crs, check_flag, existing_file, reading
from approxtree.io.las_layout import check_las_layout

#: ASPRS classification code of ground points.
GROUND_CLASS = 2

# GeoTIFF keys holding an EPSG code (projected first); 32767 means "user-defined".
_EPSG_GEOKEYS = (3072, 2048)
_USER_DEFINED = 32767


def read_point_cloud(
    path: str | os.PathLike,
    *,
    ground_only: bool = False,
    crs: str | None = None,
) -> TINPointSet:
    """Read a .las/.laz file as scattered data points.

    ground_only: keep only points classified as ground (class 2). crs: replaces the file's CRS.
    Returns a TINPointSet of the (n, 3) float64 scaled coordinates.
    """
    p = existing_file(path)
    ground_only = check_flag(ground_only, "ground_only")
    crs = check_crs(crs)
    points, classes, file_crs = _read_las(p)
    if ground_only:
        points = points[classes == GROUND_CLASS]
    if len(points) == 0:
        what = "ground points (classification 2)" if ground_only else "points"
        hint = " Leave ground_only off to use all points." if ground_only else ""
        raise EmptyTerrainError(f"{p} has no {what}.{hint}")
    return TINPointSet(points, crs=crs or file_crs)


def read_ground_surface(
    path: str | os.PathLike, *, crs: str | None = None
) -> tuple[TINPointSet, tuple[int, int] | None]:
    """A point cloud's ground surface: its ground points (class 2) when it has them beside
    points of other classes (trees, buildings: needles and slabs in a picture of the
    surface), every point otherwise, with its gaps filled the way the point quadtree fills
    them (``gap_fill_points``: lattice points at the mean height of their 4 nearest points),
    so the surface covers the cloud's whole rectangle; crs replaces the file's CRS.

    Returns (the TINPointSet, (ground points kept, points in the file) when only the ground
    was kept, else None), so that a caller can say that it kept the ground.
    """
    p = existing_file(path)
    crs = check_crs(crs)
    points, classes, file_crs = _read_las(p)
    ground = classes == GROUND_CLASS
    kept: tuple[int, int] | None = None
    if ground.any() and not ground.all():
        points, kept = points[ground], (int(ground.sum()), len(points))
    if len(points) == 0:
        raise EmptyTerrainError(f"{p} has no points.")
    points = np.concatenate([points, gap_fill_points(points)])
    return TINPointSet(points, crs=crs or file_crs), kept


def _read_las(p: Path) -> tuple[np.ndarray, np.ndarray, str | None]:
    """(points (n, 3) float64 scaled x, y, z; classes (n,) uint8; the file's CRS or None)."""
    # laspy and lazrs trust the header (a bad one hangs laspy or aborts the process in lazrs):
    # every size and offset is checked against the file and the memory first.
    with reading(p, "a LAS/LAZ point cloud"):
        check_las_layout(p)
        import laspy

        las = laspy.read(p)
        points = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
        return points, np.asarray(las.classification), _crs_of(las.header)


def _crs_of(header) -> str | None:
    """The CRS of a LAS header: its WKT VLR, else an EPSG code from its GeoTIFF keys, or None."""
    from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr

    records = [*header.vlrs, *(header.evlrs or [])]
    for record in records:
        if isinstance(record, WktCoordinateSystemVlr):
            wkt = record.string.strip("\x00 \n")
            if wkt:
                return wkt
    for record in records:
        if isinstance(record, GeoKeyDirectoryVlr):
            keys = {k.id: k.value_offset for k in record.geo_keys}
            for key in _EPSG_GEOKEYS:
                code = keys.get(key)
                if code and code != _USER_DEFINED:
                    return f"EPSG:{code}"
    return None
