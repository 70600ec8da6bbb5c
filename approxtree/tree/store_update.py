"""``approxtree update STORE PATCH.tif``: a store's terrain edited by a raster, transactionally.

The patch raster must lie on the terrain's cells (same cell size, corners on cell edges, same
CRS) and inside it; its cells (no data included) replace the terrain's. The tree is loaded,
updated in memory (``ApproximationTree.update``: only the nodes the window reaches are
rebuilt; the kept nodes' patches are one table read from the store's patch arrays, the large
patches re-measured only in the lattice cells near the window, from the per-cell figures the
store keeps, ``update_cells``) and written as a new store beside the old one, which is then
swapped in with one atomic folder exchange (``io.atomic.atomic_directory``): a reader opening
the store sees the old tree or the new one, never half of each; a writer killed at any point
leaves the old store (and a temp folder the next write removes) or the new one.

The terrain of a grid-patch tree is not read whole: its grid holds a sparse band
(``update_band``) into which the store's height chunks are read as the update asks for them
(the window, the domains of the nodes rebuilt, the cells around the window of the large
patches); the coarse patches' records take their lattice heights from the old records (the
window's points from the edited band), not from the band. The new
store's chunks that the update leaves unchanged are hard links to the old store's files: the
height and overview chunks the window misses (``zarr_store.ChunkReuse``), and the chunks of
the node, patch and per-cell arrays that hold the same bytes (``zarr_store.EqualChunks``).
"""

from __future__ import annotations

import copy
import math
import os
import signal
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from approxtree.errors import InvalidParameterError, StoreError, TerrainFormatError
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.geometry.windowed import WindowedHeights
from approxtree.patches.grid import GridPatch
from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.patch_table import PatchTable
from approxtree.tree.tree_store import TreeStoreSource, save_tree
from approxtree.tree.update import TreeUpdate, window_cells
from approxtree.tree.update_band import SparseBand, read_domains
from approxtree.tree.zarr_store import ChunkReuse, ZarrHeightSource, is_url, is_zip


def _same_crs(a: str | None, b: str | None) -> bool:
    """Whether two CRS (EPSG codes or WKT) name the same system; a missing one matches any."""
    if a is None or b is None or a == b:
        return True
    from rasterio.crs import CRS
    from rasterio.errors import CRSError

    try:
        return CRS.from_user_input(a) == CRS.from_user_input(b)
    except CRSError:
        return False


def patch_window(terrain: Grid, patch: Grid) -> Rect:
    """The world rect of the patch raster's cells on the terrain's grid, or
    InvalidParameterError when its CRS, cell size or corners do not match the terrain's."""
    if not _same_crs(terrain.crs, patch.crs):
        raise InvalidParameterError(
            f"The patch's CRS ({patch.crs}) is not the terrain's ({terrain.crs}); reproject it "
            "onto the terrain's grid first."
        )
    ta, pa = terrain.transform, patch.transform
    if not (math.isclose(ta.a, pa.a, rel_tol=1e-9) and math.isclose(ta.e, pa.e, rel_tol=1e-9)):
        raise InvalidParameterError(
            f"The patch's cells ({abs(pa.a):g} × {abs(pa.e):g}) are not the terrain's "
            f"({abs(ta.a):g} × {abs(ta.e):g}); resample it onto the terrain's grid first."
        )
    # The patch's own cell edges, in the patch's full-raster pixel corners.
    r_off, c_off = patch.index_offset
    x0, x1 = pa.c + c_off * pa.a, pa.c + (c_off + patch.width) * pa.a
    y0, y1 = pa.f + r_off * pa.e, pa.f + (r_off + patch.height) * pa.e
    return Rect(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))


def update_store(path: str | os.PathLike, patch: Grid, verify: bool = True) -> TreeUpdate:
    """Replace the cells of the store's terrain that ``patch`` covers and rewrite the store at
    ``path`` atomically (module doc); returns what the update changed."""
    text = str(path)
    if is_url(text) or is_zip(text):
        raise StoreError(
            f"{text}: only a store folder on disk can be updated in place; convert it to a "
            "folder store (NAME.zarr) first."
        )
    tree = ApproximationTree.load(path, verify=verify)
    terrain = tree.terrain
    if not isinstance(terrain, Grid):
        raise TerrainFormatError(
            f"{text} holds a tree over a {type(terrain).__name__}; only a grid's tree is updated."
        )
    sparse = _sparse_grid(tree, terrain)
    # The coarse patches' stored lattice heights, by patch index (a sparse band's only).
    lattices: dict[tuple[int, ...], np.ndarray] = {}
    if sparse is not None and isinstance(tree._source, TreeStoreSource):
        for index, z in tree._source.stored_lattices(GridPatch.kind):
            lattices[tuple(int(v) for v in index)] = z
    if sparse is None:
        # The terrain is read whole: the update edits its cells in memory, then the store is new.
        grid = Grid(
            _band(terrain),
            terrain.transform,
            terrain.crs,
            terrain.nodata,
            allow_empty=True,
        )
        grid.nodata_policy = terrain.nodata_policy
        grid.filled_count = terrain.filled_count
    else:
        grid = sparse
    tree.terrain = grid
    rect = patch_window(grid, patch)
    heights = np.asarray(patch.heights_array("updating a store's terrain"))
    if sparse is not None:
        r0, r1, c0, c1 = window_cells(grid, rect, heights.shape)
        read_domains(grid, np.array([[r0, r1, c0, c1]]))
    report = tree.update(rect, heights)
    if sparse is not None and "_z_range" not in grid.__dict__:
        # The band is not all read: the z range is the root patch's (a zero extreme's sign
        # is the root patch's kernel's, where a scan of the band might find the other zero).
        grid.__dict__["_z_range"] = (float(tree.bboxes[0, 2]), float(tree.bboxes[0, 5]))
    if sparse is not None:
        _hand_lattices(tree, sparse, lattices, report.window)
    _hook("updated")
    # The new store links the chunks the update left unchanged to the old store's files.
    r0, r1, c0, c1 = report.window
    reuse = ChunkReuse(Path(path) / "terrain" / "heights", (r0, r1, c0, c1))
    save_tree(tree, path, reuse)
    _hook("saved")
    return report


def _sparse_grid(tree: ApproximationTree, terrain: Grid) -> Grid | None:
    """The stored terrain as a grid over a sparse band (``update_band``): its chunks read as
    the update needs them, the coarse patches' stored lattices copied in; None where the
    band is read whole (a tree with other patches than grid patches, whose records may be
    rebuilt from the band, or a terrain that is not a store's)."""
    heights = terrain.heights
    source = tree._source
    if (
        not isinstance(heights, WindowedHeights)
        or not isinstance(heights.source, ZarrHeightSource)
        or not isinstance(source, TreeStoreSource)
        or list(tree.strategy_names) != [GridPatch.kind]
        or terrain.index_offset != (0, 0)
    ):
        return None
    band = SparseBand(heights.source)
    grid = copy.copy(terrain)
    for key in ("_whole_heights", "_overviews", "_z_range_blockwise"):
        grid.__dict__.pop(key, None)
    grid.__dict__["heights"] = band.band
    grid.__dict__["_sparse_band"] = band
    if "_n_valid" not in grid.__dict__:
        # A store written without the band's figures: counting the points reads it all.
        return None
    return grid


def _hand_lattices(
    tree: ApproximationTree,
    grid: Grid,
    stored: dict[tuple[int, ...], np.ndarray],
    window: tuple[int, int, int, int],
) -> None:
    """Give each coarse grid patch of the updated tree whose lattice the store holds (same
    patch index) those heights, its points in the window taken from the edited band, so
    writing its record gathers nothing from the sparse band; a coarse patch with a new index
    was built from its domain, which the band read whole."""
    patches = tree._patches
    if not isinstance(patches, PatchTable):
        return
    band = np.asarray(grid.heights)
    w0, w1, v0, v1 = window
    for p in patches.lattice_holders():
        if type(p) is not GridPatch or p.grid is not grid or not p.stores_lattice:
            continue
        rows, cols = p.lines
        # Grid indices are the full raster's (a sparse grid has no index offset).
        z = stored.get(tuple(int(v) for v in p.index))
        if z is None or len(z) != len(rows) * len(cols):
            continue
        z = np.array(z, dtype=np.float64).reshape(len(rows), len(cols))
        ri = np.flatnonzero((rows >= w0) & (rows <= w1))
        ci = np.flatnonzero((cols >= v0) & (cols <= v1))
        if len(ri) and len(ci):
            z[np.ix_(ri, ci)] = band[np.ix_(rows[ri], cols[ci])]
        p._lattice_z = z


def _band(terrain: Grid) -> np.ndarray:
    """The (rows, cols) heights of a loaded grid as a writable array of its own: read from the
    store straight into it (a windowed grid's band is read-only, so it would be copied)."""
    heights = terrain.heights
    if isinstance(heights, WindowedHeights) and isinstance(heights.source, ZarrHeightSource):
        source = heights.source
        rows, cols = heights.shape
        band = np.empty((rows, cols), dtype=source.dtype)
        step = source.block_shape[0]

        def read(r0: int) -> None:
            band[r0 : r0 + step] = source.read(r0, min(rows, r0 + step), 0, cols)

        # Rows of chunks on a thread per core (zarr decodes the chunks of one read on one).
        threads = max(1, min(os.cpu_count() or 1, -(-rows // step)))
        with ThreadPoolExecutor(threads, thread_name_prefix="store-read") as pool:
            list(pool.map(read, range(0, rows, step)))
        return band
    return np.array(terrain.heights_array("updating a store's terrain"))


def _hook(stage: str) -> None:
    """Test hook: APPROXTREE_UPDATE_KILL=stage kills this process here (a crash at a known
    point of the transaction, for the tests that check the store survives it)."""
    if os.environ.get("APPROXTREE_UPDATE_KILL") == stage:
        os.kill(os.getpid(), signal.SIGKILL)


__all__ = ["patch_window", "update_store"]
