"""Height arrays saved by numpy: .npy (one 2-D array) and .npz (an ``elevation`` array).

Row 0 is the top (north) row, as in images. A .npy has no georeference: cell_size (default 1)
and origin (x of the left edge, y of the top edge; default (0, rows * cell_size)) place it.
A .npz may carry its extent as scalars ``xmin, xmax, ymin, ymax`` (cell edges, as matplotlib's
``imshow(extent=...)``) and optionally ``dx, dy``. Some files store ymin and ymax swapped
(matplotlib's jacksboro_fault_dem.npz), so each pair is sorted before use.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import IO

import numpy as np
from affine import Affine

from approxtree.errors import EmptyTerrainError, InvalidParameterError, TerrainFormatError
from approxtree.geometry import Grid
from approxtree.io._common import (
    as_heights,
    check_cell_size,
    check_claimed_bytes,
    check_crs,
    check_nodata_policy,
    check_origin,
    existing_file,
    make_grid,
    reading,
    resolve_transform,
)

#: Names of the extent scalars a .npz may carry.
EXTENT_KEYS = ("xmin", "xmax", "ymin", "ymax")


def read_array(
    path: str | os.PathLike,
    *,
    key: str | None = None,
    nodata: str = "mask",
    crs: str | None = None,
    cell_size: float | tuple[float, float] | None = None,
    origin: tuple[float, float] | None = None,
) -> Grid:
    """Read a .npy or .npz height array as a Grid; NaN entries are nodata.

    key: the .npz entry to read (default ``elevation``, else its only 2-D array).
    crs: the CRS of the coordinates (arrays carry none). Returns heights (rows, cols).
    """
    p = existing_file(path)
    policy = check_nodata_policy(nodata)
    crs = check_crs(crs)
    cell = check_cell_size(cell_size)
    corner = check_origin(origin)
    if key is not None and not isinstance(key, str):
        raise InvalidParameterError(f"key must be the name of a .npz entry, got {key!r}.")
    with reading(p, "a numpy array file"):
        # numpy allocates the shape a header claims before reading: check it against the file.
        _check_sizes(p)
        # Pickled objects could run code; height arrays never need them.
        loaded = np.load(p, allow_pickle=False)
        if isinstance(loaded, np.lib.npyio.NpzFile):
            with loaded:
                values, own = _from_npz(p, loaded, key)
        elif key is not None:
            raise InvalidParameterError(f"key applies to .npz files only; {p} is a .npy.")
        else:
            values, own = np.asarray(loaded), None
    values = _check_array(p, values)
    heights = as_heights(values)
    transform = resolve_transform(own, heights.shape, cell, corner, p)
    return make_grid(heights, transform, crs, None, policy)


def _npy_claim(f: IO[bytes]) -> tuple[int, str]:
    """(bytes of data, shape and dtype in words) from an .npy header; f is left at the data."""
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(f)
    else:
        shape, _, dtype = np.lib.format.read_array_header_2_0(f)
    return int(np.prod(shape, dtype=object)) * dtype.itemsize, f"a {shape} array of {dtype}"


def _check_sizes(path: Path) -> None:
    """Every array of a .npy/.npz claims no more bytes than its file (or zip member) holds."""
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                if not info.filename.endswith(".npy"):
                    continue
                with archive.open(info) as member:
                    claimed, what = _npy_claim(member)
                    present = info.file_size - member.tell()
                check_claimed_bytes(path, claimed, present, f"{what} in {info.filename}")
        return
    with open(path, "rb") as f:
        claimed, what = _npy_claim(f)
        present = path.stat().st_size - f.tell()
    check_claimed_bytes(path, claimed, present, what)


def _check_array(path: Path, values: np.ndarray) -> np.ndarray:
    """The array if it can be a height grid: non-empty, 2-D, real numbers."""
    if values.size == 0:
        raise EmptyTerrainError(f"{path} holds an empty array {values.shape}: no heights at all.")
    if values.ndim != 2:
        raise TerrainFormatError(
            f"{path} must hold a 2-D array of heights (rows, cols); got shape {values.shape}."
        )
    if values.dtype.kind not in "iuf":
        raise TerrainFormatError(f"{path} holds {values.dtype} values, not heights.")
    return values


def _from_npz(
    path: Path, npz: np.lib.npyio.NpzFile, key: str | None
) -> tuple[np.ndarray, Affine | None]:
    """(heights (rows, cols), transform or None) from the entries of a .npz."""
    names = list(npz.files)
    if key is None:
        grids = [n for n in names if npz[n].ndim == 2]
        if "elevation" in names:
            key = "elevation"
        elif len(grids) == 1:
            key = grids[0]
        else:
            raise TerrainFormatError(
                f"{path} has no 'elevation' entry and {len(grids)} 2-D arrays "
                f"(entries: {', '.join(names) or 'none'}); pass key= to choose one."
            )
    elif key not in names:
        raise InvalidParameterError(
            f"{path} has no entry {key!r}; its entries are {', '.join(names) or 'none'}."
        )
    values = npz[key]
    present = [k for k in EXTENT_KEYS if k in names]
    if not present or values.ndim != 2:
        return values, None
    if len(present) != len(EXTENT_KEYS):
        raise TerrainFormatError(
            f"{path} has only {', '.join(present)} of the extent {', '.join(EXTENT_KEYS)}; "
            "store all four or none."
        )
    extent = {k: float(npz[k]) for k in (*EXTENT_KEYS, "dx", "dy") if k in names}
    rows, cols = values.shape
    x0, dx = _axis(path, "x", extent["xmin"], extent["xmax"], cols, extent.get("dx"))
    y0, dy = _axis(path, "y", extent["ymin"], extent["ymax"], rows, extent.get("dy"))
    # Row 0 is the north edge: y falls with the row.
    return values, Affine(dx, 0.0, x0, 0.0, -dy, y0 + rows * dy)


def _axis(
    path: Path, name: str, a: float, b: float, n: int, step: float | None
) -> tuple[float, float]:
    """(lower edge, cell size) of one axis from its two extent values (in either order).

    The extent spans the cell edges (n cells) unless the stored step says it spans the
    centres (n - 1 steps).
    """
    lo, hi = min(a, b), max(a, b)
    if not np.isfinite([lo, hi]).all() or hi <= lo:
        raise TerrainFormatError(f"{path} has an empty or invalid {name} extent {a}..{b}.")
    edges = (hi - lo) / n
    if step is None or np.isclose(step, edges, rtol=1e-3):
        return lo, edges
    if n > 1 and np.isclose(step, (hi - lo) / (n - 1), rtol=1e-3):
        return lo - step / 2, step
    raise TerrainFormatError(
        f"{path}: d{name} = {step} does not fit the {name} extent {lo}..{hi} over {n} cells "
        f"(expected {edges})."
    )
