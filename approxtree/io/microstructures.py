"""TIN microstructures for a GridRefinement: precomputed TIN files, or corridors along lines.

A line layer (rivers, roads; any vector format pyogrio reads) becomes river-bed corridors:

1. every line is buffered to the corridor width; the union of the buffers is the footprint;
2. the footprint is sampled on a lattice finer than the grid (plus its densified outline) and
   triangulated once (scipy Delaunay); triangles whose centre lies outside the footprint go;
3. each triangle goes to the line nearest its centre, so every line gets its own
   microstructure and microstructures never overlap;
4. heights come from the grid resampled finer (bicubic, ``profile="resampled"``) or from an
   incised channel (``profile="incised"``): h_T lowered by depth · (1 − (d / half width)²) at
   distance d from the centre line, which meets the grid surface at the corridor's edge.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import EmptyTerrainError, InvalidParameterError, TerrainFormatError
from approxtree.geometry.grid import Grid
from approxtree.geometry.refinement import GridRefinement
from approxtree.geometry.tin import TIN
from approxtree.io._common import check_shapefile_length

VECTOR_SUFFIXES = (".shp", ".gpkg", ".geojson", ".json", ".fgb", ".gml", ".kml")
PROFILES = ("incised", "resampled")


def read_lines(path: str | os.PathLike, crs: str | None = None) -> np.ndarray:
    """Line geometries of a vector layer as a shapely array, reprojected to ``crs``.

    Empty geometries and geometries with non-finite coordinates are left out.
    """
    import pyogrio
    import shapely

    path = Path(path)
    if not path.is_file():
        raise TerrainFormatError(f"Vector layer {path} does not exist.")
    check_shapefile_length(path)
    try:
        info = pyogrio.read_info(path)
        _, _, wkb, _ = pyogrio.raw.read(path, columns=[])
    except Exception as exc:
        raise TerrainFormatError(f"Cannot read {path} as a vector layer: {exc}") from exc
    if wkb is None:
        raise TerrainFormatError(f"{path} has no geometry column: it holds no lines.")
    geoms = shapely.from_wkb(wkb)
    keep = ~shapely.is_missing(geoms) & ~shapely.is_empty(geoms)
    coords_ok = np.array(
        [
            np.isfinite(shapely.get_coordinates(g)).all() if k else False
            for g, k in zip(geoms, keep, strict=True)
        ]
    )
    geoms = geoms[keep & coords_ok]
    src_crs = info.get("crs")
    if crs and src_crs:
        from rasterio.crs import CRS
        from rasterio.warp import transform_geom

        if CRS.from_user_input(src_crs) != CRS.from_user_input(crs):
            geoms = np.array(
                [
                    shapely.geometry.shape(transform_geom(src_crs, crs, g.__geo_interface__))
                    for g in geoms
                ]
            )
    return geoms


def _bicubic_heights(grid: Grid, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Heights of the grid resampled bicubically at (x, y); NaN where the grid has none."""
    from scipy.ndimage import map_coordinates

    fr, fc = grid.fractional_index(x, y)
    z = grid.heights_array("resampling heights for microstructures").astype(np.float64)
    valid = np.isfinite(z)
    filled = np.where(valid, z, np.nanmean(z))
    out = map_coordinates(filled, [fr, fc], order=3, mode="nearest")
    # Cubic weights reach two cells: stay NaN wherever the linear surface is undefined.
    out[np.isnan(grid.height_at(x, y))] = np.nan
    return out


def corridor_microstructures(
    grid: Grid,
    lines: Sequence[Any] | np.ndarray,
    width: float,
    spacing: float | None = None,
    profile: str = "incised",
    depth: float = 2.0,
) -> list[TIN]:
    """One TIN microstructure per line (see the module docstring).

    grid: the terrain grid; lines: shapely line geometries in the grid's CRS; width: corridor
    width in world units; spacing: sample spacing (default: a third of the grid cell);
    profile: "incised" or "resampled"; depth: channel depth of the incised profile (z units).
    """
    import shapely
    from scipy.spatial import Delaunay

    if profile not in PROFILES:
        raise InvalidParameterError(f"Unknown corridor profile {profile!r}; choose {PROFILES}.")
    if not width > 0:
        raise InvalidParameterError(f"Corridor width must be > 0, got {width}.")
    lines = np.asarray(lines, dtype=object)
    if len(lines) == 0:
        raise EmptyTerrainError("The line layer holds no usable geometry.")
    spacing = spacing or min(grid.cell_size) / 3.0
    half = width / 2.0
    footprint = shapely.union_all(shapely.buffer(lines, half))
    # Clip to the grid's domain: microstructures replace the grid, they do not extend it.
    d = grid.domain
    footprint = shapely.intersection(footprint, shapely.box(d.xmin, d.ymin, d.xmax, d.ymax))
    if footprint.is_empty:
        raise EmptyTerrainError("No corridor overlaps the grid's domain.")
    # Lattice points inside the footprint plus its outline, densified to the same spacing.
    x0, y0, x1, y1 = footprint.bounds
    gx, gy = np.meshgrid(np.arange(x0, x1 + spacing, spacing), np.arange(y0, y1 + spacing, spacing))
    gx, gy = gx.ravel(), gy.ravel()
    inside = shapely.contains_xy(footprint, gx, gy)
    outline = shapely.get_coordinates(shapely.segmentize(footprint.boundary, spacing))
    xy = np.unique(np.concatenate([np.column_stack([gx[inside], gy[inside]]), outline]), axis=0)
    # Heights first, so points without a terrain height never enter the triangulation.
    tree = shapely.STRtree(lines)
    pts = shapely.points(xy)
    nearest_line = tree.query_nearest(pts, return_distance=False, all_matches=False)[1]
    dist = shapely.distance(pts, lines[nearest_line])
    if profile == "incised":
        z = grid.height_at(xy[:, 0], xy[:, 1]) - depth * np.clip(1.0 - (dist / half) ** 2, 0.0, 1.0)
    else:
        z = _bicubic_heights(grid, xy[:, 0], xy[:, 1])
    ok = np.isfinite(z)
    xy, z = xy[ok], z[ok]
    if len(xy) < 3:
        raise EmptyTerrainError("The corridors hold fewer than 3 points with a terrain height.")
    tri = Delaunay(xy).simplices
    centres = xy[tri].mean(axis=1)
    keep = shapely.contains_xy(footprint, centres[:, 0], centres[:, 1])
    tri, centres = tri[keep], centres[keep]
    owner = tree.query_nearest(shapely.points(centres), return_distance=False, all_matches=False)[1]
    vertices = np.column_stack([xy, z])
    tins: list[TIN] = []
    order = np.argsort(owner, kind="stable")
    bounds = np.flatnonzero(np.diff(owner[order])) + 1
    for group in np.split(order, bounds):
        if len(group) == 0:
            continue
        used, local = np.unique(tri[group], return_inverse=True)
        tins.append(TIN(vertices[used], local.reshape(-1, 3), crs=grid.crs))
    return tins


def load_microstructures(
    path: str | os.PathLike,
    grid: Grid,
    width: float = 30.0,
    profile: str = "incised",
    depth: float = 2.0,
    spacing: float | None = None,
) -> list[TIN]:
    """Microstructures from a file: a line layer (corridors) or any TIN the readers support."""
    path = Path(path)
    if path.suffix.lower() in VECTOR_SUFFIXES:
        return corridor_microstructures(
            grid, read_lines(path, grid.crs), width, spacing=spacing, profile=profile, depth=depth
        )
    from approxtree.io import open_terrain

    tin = open_terrain(path)
    if not isinstance(tin, TIN):
        raise TerrainFormatError(
            f"{path} is a {type(tin).__name__}, not a TIN or a line layer; microstructures are "
            "TINs (e.g. .terrain tiles, LAS points) or lines to build corridors along."
        )
    return [tin]


def refine_grid(
    terrain: Any,
    files: Sequence[str],
    width: float,
    depth: float,
    profile: str,
    spacing: float | None,
) -> Any:
    """The GridRefinement of a regular grid by the microstructures of ``files``: any TIN file,
    or line layers turned into corridors ``width`` wide and ``depth`` deep
    (``load_microstructures``)."""
    if not isinstance(terrain, Grid):
        raise InvalidParameterError(
            f"--microstructures refines a regular grid, got a {type(terrain).__name__}."
        )
    tins = []
    for f in files:
        tins.extend(
            load_microstructures(
                f, terrain, width=width, profile=profile, depth=depth, spacing=spacing
            )
        )
    return GridRefinement(terrain, tins)
