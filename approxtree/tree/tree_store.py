"""Trees in a tree store (``zarr_store``): the layout of an ApproximationTree or PointQuadtree.

Writing: ``save_tree`` and ``save_quadtree`` (``tree.store.save`` picks one by tree kind).
Reading: ``TreeStoreSource``, the ``TreeSource`` of a store (``tree.store.open_store``): meta
data, terrain, node table or quadtree arrays, and each node's patch on demand.

Layout (format version 1)::

    zarr.json                root attributes: format, format_version, metadata_crc32c, meta =
                             {library, tree_kind, terrain_kind, params, strategy_names,
                              ancestor_level, nodes}
    terrain/                 attributes {kind, attrs}: the terrain's ``to_record``
      heights                (rows, cols) in 512 × 512 chunks (Grid, GridRefinement)
      <other arrays>         chunked along axis 0 (TIN vertices, point sets, ...)
    nodes/                   the node table, (n, ...) arrays chunked along axis 0:
      rects errors bboxes levels parents child_start child_count strategies
      patch_slot             (n,) int64: the node's position in its strategy's patch arrays
    patches/<strategy>/      attributes {count, fields: {name: width or null}}
      node                   (k,) int64: the node of each slot
      <field>                (k, width) when every record has the same length, else
      <field>_data           (total,) the records raveled one after the other and
      <field>_offsets        (k + 1,) int64: slot s is data[offsets[s]:offsets[s + 1]]
    quadtree/                (point quadtrees) the arrays of ``PointQuadtree.to_sections``
    cells/                   optional (a grid tree whose large patches were measured per cell,
                             ``tree.update_cells``): attributes {count: m}
      index                  (m, 6) int64 the patches (r0, r1, c0, c1, sr, sc), sorted
      start                  (m + 1,) int64: patch i's cells are [start[i], start[i + 1])
      error zmin zmax        (cells,) float64, row-major per patch
      count zeros            (cells,) int64 and uint8

A store without ``cells/`` (written before it existed, or by a blocked build) reads and updates
the same; its first update measures the large patches above the edit whole.

Patch order: slots follow the *storage order*: nodes above the ancestor level L first (in
breadth-first order), then the subtrees of the level-L nodes one after the other (each in
breadth-first order). L is the shallowest level with at least ``SUBTREE_ROOTS`` nodes, so a
chunk of patch data holds whole subtrees (or a part of one) and the patches a renderer pages
in together are stored together.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from approxtree._version import __version__
from approxtree.errors import StoreError
from approxtree.geometry import TERRAIN_TYPES
from approxtree.geometry.base import GeometryData, RecordArray
from approxtree.geometry.grid import Grid
from approxtree.geometry.windowed import WindowedHeights
from approxtree.patches.grid import GridPatch, GridPatchArrays
from approxtree.patches.records import Batch, take
from approxtree.tree.patch_table import PatchTable
from approxtree.tree.update_band import read_domains
from approxtree.tree.zarr_store import (
    HEIGHT_CHUNK,
    ChunkReuse,
    EqualChunks,
    StoreReader,
    ZarrHeightSource,
    is_url,
    is_zip,
    write_array,
    writing,
)

if TYPE_CHECKING:
    from approxtree.tree.approximation_tree import ApproximationTree
    from approxtree.tree.point_quadtree import PointQuadtree
    from approxtree.tree.store_regions import HeightRegions

NODE_ARRAYS = (
    "rects",
    "errors",
    "bboxes",
    "levels",
    "parents",
    "child_start",
    "child_count",
    "strategies",
)
#: The ancestor level L is the shallowest level holding at least this many nodes.
SUBTREE_ROOTS = 64


# -- order -------------------------------------------------------------------------------------


def ancestor_level(levels: np.ndarray) -> int:
    """L: the shallowest level with at least SUBTREE_ROOTS nodes (else the deepest)."""
    counts = np.bincount(np.asarray(levels, dtype=np.int64))
    wide = np.flatnonzero(counts >= SUBTREE_ROOTS)
    return int(wide[0]) if len(wide) else len(counts) - 1


def storage_order(levels: np.ndarray, parents: np.ndarray, level: int) -> np.ndarray:
    """(n,) node indices in storage order: levels < ``level`` first, then subtree by subtree
    of the level-``level`` nodes (breadth-first inside each)."""
    n = len(levels)
    anc = np.arange(n, dtype=np.int64)
    # Climb every node to its level-L ancestor, one vectorized step per level.
    for _ in range(int(levels.max(initial=0)) - level):
        deep = levels[anc] > level
        if not deep.any():
            break
        anc = np.where(deep, parents[anc], anc)
    key = np.where(levels < level, -1, anc)
    return np.lexsort((np.arange(n), key))


# -- terrain -----------------------------------------------------------------------------------


def _write_terrain(
    root: Any,
    terrain: GeometryData,
    tap: Any = None,
    reuse: ChunkReuse | None = None,
    regions: HeightRegions | None = None,
) -> None:
    """The terrain group; ``tap(r0, r1, c0, c1, values)`` sees every slab of the heights;
    ``reuse`` links the unchanged height chunks to an old store's; ``regions``: the heights
    the block tasks wrote (``store_regions``), moved in, and their overview lines.

    A grid larger than its overview also gets ``overview`` (the Engine's normal map samples,
    ``Grid.strided_heights``), picked from the same slabs: no second read of the band.
    """
    attrs, arrays = terrain.to_record()
    group = root.create_group("terrain", attributes={"kind": terrain.kind, "attrs": attrs})
    grid = getattr(terrain, "grid", terrain)
    # An update's overview is written from the band, not collected: no (values) to fill.
    update = reuse is not None and isinstance(grid, Grid) and not grid.is_windowed
    overview = _OverviewTap(grid, collect=not update) if isinstance(grid, Grid) else None
    if overview is not None and max(abs(v) for v in overview.steps) == 1:
        overview = None
    taps = [t for t in (tap, overview) if t is not None]

    def both(*args: Any) -> None:
        for t in taps:
            t(*args)

    lines: _GridLines | None = None
    lines_reuse: ChunkReuse | None = None
    if update and isinstance(grid, Grid) and reuse is not None:
        # An update: the heights and the overview chunks the change misses are links, the
        # others read from the (possibly sparse, ``update_band``) band as they are written.
        taps = [t for t in (tap,) if t is not None]
        if overview is not None:
            lines = _GridLines(grid, overview.steps)
            lines_reuse = overview.reuse(reuse)
            overview = None
    for name, a in arrays.items():
        if name == "heights" and regions is not None:
            regions.move_into(group, name)
        elif name == "heights" and reuse is not None and not taps and isinstance(grid, Grid):
            write_array(
                group,
                name,
                _GridLines(grid, (1, 1)),
                chunks=(HEIGHT_CHUNK, HEIGHT_CHUNK),
                reuse=reuse,
            )
        elif name == "heights":
            write_array(
                group,
                name,
                a,
                chunks=(HEIGHT_CHUNK, HEIGHT_CHUNK),
                tap=both if taps else None,
                reuse=reuse,
            )
        else:
            write_array(group, name, np.asarray(a))
    if lines is not None and reuse is not None:
        arr = write_array(
            group, "overview", lines, chunks=(HEIGHT_CHUNK, HEIGHT_CHUNK), reuse=lines_reuse
        )
        arr.attrs.update({"row_step": lines.steps[0], "col_step": lines.steps[1]})
    if overview is not None:
        values = overview.values if regions is None else regions.overview(overview)
        # Its chunks that the changed heights miss are links too (the same chunking).
        linked = overview.reuse(reuse) if reuse is not None else None
        arr = write_array(
            group, "overview", values, chunks=(HEIGHT_CHUNK, HEIGHT_CHUNK), reuse=linked
        )
        arr.attrs.update({"row_step": overview.steps[0], "col_step": overview.steps[1]})


class _GridLines:
    """``heights[::rs, ::cs]`` of an in-memory grid as a 2-D array-like read by slices, each
    read announced first (``update_band.read_domains``: a sparse band reads its chunks).

    shape: (0,) when there is nothing to write (no overview); dtype: float64 or float32.
    """

    def __init__(self, grid: Grid, steps: tuple[int, int]) -> None:
        self.grid = grid
        self.steps = steps
        rows, cols = grid.shape
        self.rows = np.arange(rows)[:: steps[0]]
        self.cols = np.arange(cols)[:: steps[1]]
        self.shape: tuple[int, ...] = (len(self.rows), len(self.cols))
        self.dtype = np.dtype(np.float64 if grid.heights.dtype == np.float64 else np.float32)

    def __getitem__(self, key: tuple[slice, slice]) -> np.ndarray:
        rr, cc = self.rows[key[0]], self.cols[key[1]]
        if not len(rr) or not len(cc):
            return np.empty((len(rr), len(cc)), dtype=self.dtype)
        read_domains(self.grid, np.array([[rr.min(), rr.max(), cc.min(), cc.max()]]))
        heights = self.grid.heights
        if tuple(self.steps) == (1, 1):
            return np.asarray(heights[rr[0] : rr[-1] + 1, cc[0] : cc[-1] + 1], dtype=self.dtype)
        return np.asarray(heights[np.ix_(rr, cc)], dtype=self.dtype)


class _OverviewTap:
    """Collects ``heights[::rs, ::cs]`` (the grid's overview steps) from the slabs streamed past."""

    def __init__(self, grid: Any, collect: bool = True) -> None:
        self.steps = grid.overview_steps()
        rows, cols = grid.shape
        rs, cs = self.steps
        self.rows = np.arange(rows)[::rs]
        self.cols = np.arange(cols)[::cs]
        # Slab lines → overview positions, by lookup (steps may be negative: lines reversed).
        self.row_at = np.full(rows, -1, dtype=np.int64)
        self.row_at[self.rows] = np.arange(len(self.rows))
        self.col_at = np.full(cols, -1, dtype=np.int64)
        self.col_at[self.cols] = np.arange(len(self.cols))
        dtype = np.float64 if grid.heights.dtype == np.float64 else np.float32
        # collect False: only the line lookups (``reuse``), no values collected.
        shape = (len(self.rows), len(self.cols)) if collect else (0, 0)
        self.values = np.full(shape, np.nan, dtype=dtype)

    def reuse(self, heights: ChunkReuse) -> ChunkReuse:
        """The overview's chunks to link to an old store's: those holding no changed height
        (``heights.changed``: inclusive rows and columns of the heights)."""
        r0, r1, c0, c1 = heights.changed
        rows = self.row_at[r0 : r1 + 1]
        cols = self.col_at[c0 : c1 + 1]
        rows, cols = rows[rows >= 0], cols[cols >= 0]
        if not len(rows) or not len(cols):
            # No overview line crosses the change: every chunk is the old one.
            return ChunkReuse(heights.old.parent / "overview", (0, -1, 0, -1))
        changed = (int(rows.min()), int(rows.max()), int(cols.min()), int(cols.max()))
        return ChunkReuse(heights.old.parent / "overview", changed)

    @staticmethod
    def steps_of(grid: Grid) -> tuple[int, int] | None:
        """The overview steps of ``grid``, None when it is its own overview."""
        steps = grid.overview_steps()
        return None if max(abs(v) for v in steps) == 1 else steps

    def __call__(self, r0: int, r1: int, c0: int, c1: int, block: np.ndarray) -> None:
        ri = np.flatnonzero(self.row_at[r0:r1] >= 0)
        ci = np.flatnonzero(self.col_at[c0:c1] >= 0)
        if len(ri) and len(ci):
            self.values[np.ix_(self.row_at[r0 + ri], self.col_at[c0 + ci])] = block[np.ix_(ri, ci)]


class _LatticeTap:
    """Picks the lattice heights of coarse grid patches out of the terrain's slabs as the store
    copies them, so a windowed terrain is read once, not once more for the lattices.

    patches: GridPatch objects over the terrain's (windowed) grid that store their lattice and
    do not hold it yet. ``finish()`` hands each patch its (kr, kc) heights.
    """

    def __init__(self, patches: list[Any]) -> None:
        self.patches = patches
        lines = [p.lines for p in patches]
        self.sizes = [(len(r), len(c)) for r, c in lines]
        rr = np.concatenate([np.repeat(r, len(c)) for r, c in lines])
        cc = np.concatenate([np.tile(c, len(r)) for r, c in lines])
        # Points sorted by row: a slab's points are one searchsorted range, then a column test.
        self.order = np.argsort(rr, kind="stable")
        self.rows = rr[self.order]
        self.cols = cc[self.order]
        self.values = np.full(len(rr), np.nan, dtype=np.float64)

    def __call__(self, r0: int, r1: int, c0: int, c1: int, block: np.ndarray) -> None:
        lo, hi = np.searchsorted(self.rows, [r0, r1])
        cols = self.cols[lo:hi]
        inside = np.flatnonzero((cols >= c0) & (cols < c1))
        if len(inside):
            at = lo + inside
            self.values[self.order[at]] = block[self.rows[at] - r0, cols[inside] - c0]

    def finish(self) -> None:
        ends = np.cumsum([kr * kc for kr, kc in self.sizes])
        parts = np.split(self.values, ends[:-1])
        for p, (kr, kc), z in zip(self.patches, self.sizes, parts, strict=True):
            p._lattice_z = z.reshape(kr, kc)


def _lattice_tap(tree: ApproximationTree) -> _LatticeTap | None:
    """The tap for the coarse grid patches of a tree over a windowed grid (None otherwise)."""
    grid = tree.terrain
    if not isinstance(grid, Grid) or not grid.is_windowed or grid.index_offset != (0, 0):
        return None
    patches = tree._patches
    # Of a PatchTable only the coarse patches store a lattice: no object for the others.
    held = patches.lattice_holders() if isinstance(patches, PatchTable) else patches
    wanted = [
        p
        for p in held
        if type(p) is GridPatch and p.grid is grid and p._lattice_z is None and p.stores_lattice
    ]
    return _LatticeTap(wanted) if wanted else None


def _read_terrain(reader: StoreReader) -> GeometryData:
    tattrs = reader.attrs("terrain")
    kind = tattrs.get("kind")
    if kind not in TERRAIN_TYPES:
        raise StoreError(f"{reader.location} holds an unknown terrain kind {kind!r}.")
    arrays: dict[str, RecordArray] = {}
    overview = None
    for name in reader.children("terrain"):
        path = f"terrain/{name}"
        if name == "overview":
            overview = path
        elif name == "heights":
            # The heights stay in the store: windows are read (and checksummed) as asked for,
            # through a cache bounded in bytes.
            source = ZarrHeightSource(reader.location, path, reader=reader)
            arrays[name] = WindowedHeights(source)
        else:
            arrays[name] = reader.read(path)
    try:
        terrain = TERRAIN_TYPES[kind].from_record(tattrs["attrs"], arrays)
    except (KeyError, TypeError, ValueError) as exc:
        raise StoreError(
            f"{reader.location} holds a malformed terrain ({exc}); rebuild it."
        ) from exc
    if overview is not None:
        # Read when first asked for (the Engine's normal map), checksummed like every chunk.
        steps = reader.attrs(overview)
        grid = getattr(terrain, "grid", terrain)
        key = (int(steps["row_step"]), int(steps["col_step"]))
        grid.__dict__.setdefault("_overviews", {})[key] = lambda: reader.read(overview)
    return terrain


# -- patches -----------------------------------------------------------------------------------


def _write_batch(group: Any, batch: Batch, old: EqualChunks | None = None) -> dict[str, int | None]:
    """Each field as a (k, width) table when fixed-width, else flat data plus offsets.

    old: the old store's group of these records (an update), whose chunks holding the same
    bytes are linked (``EqualChunks``).
    """

    def same(name: str) -> EqualChunks | None:
        return EqualChunks(old.old / name) if old is not None else None

    fields: dict[str, int | None] = {}
    for name, (flat, offsets) in batch.items():
        lengths = np.diff(offsets)
        k = len(lengths)
        if k and (lengths == lengths[0]).all() and lengths[0] > 0:
            width = int(lengths[0])
            write_array(group, name, np.asarray(flat).reshape(k, width), reuse=same(name))
            fields[name] = width
        else:
            write_array(group, f"{name}_data", np.asarray(flat), reuse=same(f"{name}_data"))
            write_array(
                group,
                f"{name}_offsets",
                np.asarray(offsets, dtype="<i8"),
                reuse=same(f"{name}_offsets"),
            )
            fields[name] = None
    return fields


def save_tree(
    tree: ApproximationTree,
    path: str | os.PathLike,
    reuse: ChunkReuse | None = None,
    regions: HeightRegions | None = None,
) -> int:
    """Write ``tree`` as a tree store at ``path`` atomically; returns the stored bytes.

    reuse: the terrain height chunks to take from an old folder store by hard link (the
    unchanged ones of an update, ``store_update``); the rest is written. regions: the heights
    its block tasks wrote (``store_regions``; used once complete, else the client copies).
    """
    if regions is not None and not regions.complete:
        regions = None
    n = len(tree)
    level = ancestor_level(tree.levels)
    order = storage_order(tree.levels, tree.parents, level)
    meta = {
        "library": f"approxtree {__version__}",
        "tree_kind": "approximation_tree",
        "terrain_kind": tree.terrain.kind,
        "params": tree.params,
        "strategy_names": list(tree.strategy_names),
        "ancestor_level": level,
        "nodes": n,
    }
    slot = np.empty(n, dtype=np.int64)
    # Regions: the build's tasks handed the coarse patches their lattices; nothing streams past.
    tap = _lattice_tap(tree) if regions is None else None
    with writing(path, meta) as root:
        _write_terrain(root, tree.terrain, tap, reuse, regions)
        if tap is not None:
            tap.finish()
        # An update's other arrays link their chunks that hold the old store's bytes.
        old = Path(path) if reuse is not None else None

        def same(part: str) -> EqualChunks | None:
            return EqualChunks(old / part) if old is not None else None

        patches = root.create_group("patches")
        for s, name in enumerate(tree.strategy_names):
            nodes = order[tree.strategies[order] == s]
            slot[nodes] = np.arange(len(nodes))
            group = patches.create_group(name)
            base = f"patches/{name}"
            write_array(group, "node", nodes.astype("<i8"), reuse=same(f"{base}/node"))
            batch = tree.patch_records(nodes, name)
            fields = _write_batch(group, batch, same(base) if old is not None else None)
            group.attrs.update({"count": len(nodes), "fields": fields})
        group = root.create_group("nodes")
        for name in NODE_ARRAYS:
            write_array(group, name, np.asarray(getattr(tree, name)), reuse=same(f"nodes/{name}"))
        write_array(group, "patch_slot", slot, reuse=same("nodes/patch_slot"))
        _write_cells(root, tree, old)
    return store_bytes(path)


def _write_cells(root: Any, tree: ApproximationTree, old: Path | None = None) -> None:
    """The ``cells/`` group of a grid tree that holds per-cell figures (layout above); old:
    the old store of an update, whose chunks holding the same bytes are linked."""

    def same(name: str) -> EqualChunks | None:
        return EqualChunks(old / "cells" / name) if old is not None else None

    cache = tree.__dict__.get("_cell_cache")
    grid = tree.terrain
    if cache is None or not cache.entries or not isinstance(grid, Grid):
        return
    if grid.index_offset != (0, 0):
        return
    keys = sorted(cache.entries)
    entries = [cache.entries[key] for key in keys]
    start = np.zeros(len(keys) + 1, dtype="<i8")
    np.cumsum([e[0].size for e in entries], out=start[1:])
    group = root.create_group("cells", attributes={"count": len(keys)})
    write_array(group, "index", np.array(keys, dtype="<i8").reshape(-1, 6), reuse=same("index"))
    write_array(group, "start", start, reuse=same("start"))
    dtypes = ("<f8", "<f8", "<f8", "<i8", "u1")
    for f, (name, dtype) in enumerate(zip(CELL_FIELDS, dtypes, strict=True)):
        values = np.concatenate([np.ravel(e[f]) for e in entries]).astype(dtype)
        write_array(group, name, values, reuse=same(name))


#: The per-cell figures of ``update_cells.CellCache``, in its order.
CELL_FIELDS = ("error", "zmin", "zmax", "count", "zeros")


def store_bytes(path: str | os.PathLike) -> int:
    """Bytes a store takes (a zip's file size; a folder's or URL's chunks and metadata)."""
    if is_zip(path):
        return os.path.getsize(path)
    if not is_url(path):
        folder = os.fspath(path)
        return sum(
            os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(folder) for f in files
        )
    return StoreReader(path).sizes()["stored"]


class TreeStoreSource:
    """A tree store opened for reading: the ``TreeSource`` of a store (``tree.store``).

    The root attributes are checked on opening (``StoreReader``); the node table, the terrain
    and the quadtree arrays are read when asked for, a grid's heights by windows, and node i's
    patch as node i's slice of each field only.
    """

    def __init__(self, reader: StoreReader) -> None:
        self.reader = reader
        self.location = reader.location
        self.meta: dict[str, Any] = reader.meta
        self._fields: dict[str, dict[str, int | None]] = {}
        self._offsets: dict[str, np.ndarray] = {}
        # (strategies (n,), patch_slot (n,)) of the nodes: where each node's patch is.
        self._placement: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def tree_kind(self) -> str:
        """The tree kind: "approximation_tree" or "point_quadtree"."""
        return str(self.meta.get("tree_kind"))

    def terrain(self) -> GeometryData:
        """The stored terrain (a grid's heights stay in the store, read by windows)."""
        return _read_terrain(self.reader)

    def node_arrays(self) -> dict[str, np.ndarray]:
        """The node table of an approximation tree, (n, ...) arrays (``NODE_ARRAYS``)."""
        nodes = {name: self.reader.read(f"nodes/{name}") for name in NODE_ARRAYS}
        slot = self.reader.read("nodes/patch_slot")
        n = len(nodes["errors"])
        if any(len(a) != n for a in (*nodes.values(), slot)):
            raise StoreError(f"{self.location} has node arrays of different lengths; rebuild it.")
        self._placement = (nodes["strategies"], slot)
        return nodes

    def quadtree_arrays(self) -> dict[str, np.ndarray]:
        """The "quadtree" arrays of a point quadtree (``PointQuadtree.to_sections``)."""
        return {
            name: self.reader.read(f"quadtree/{name}") for name in self.reader.children("quadtree")
        }

    def verify(self) -> None:
        """Read every array but the terrain's now (the terrain's chunks are checked as they are
        read), so a damaged chunk fails here rather than when its patch is paged in; that
        every chunk is there was checked when the store was opened. The per-cell figures, if
        any, must agree with the patches they reduce to (``check_cells``)."""
        self.reader.verify(read_skip=("terrain/",))
        self.check_cells()

    def cell_entries(
        self,
    ) -> dict[tuple[int, int, int, int, int, int], tuple[np.ndarray, ...]] | None:
        """The stored per-cell figures (``cells/``): patch index → (error, zmin, zmax, count,
        zeros) arrays of shape (nbr, nbc) (float64 ×3, int64 ×2), as ``CellCache.entries``;
        None when the store has none."""
        if not self.reader.has("cells"):
            return None
        index = self.reader.read("cells/index").astype(np.int64)
        start = self.reader.read("cells/start").astype(np.int64)
        fields = [self.reader.read(f"cells/{name}") for name in CELL_FIELDS]
        types = (np.float64, np.float64, np.float64, np.int64, np.int64)
        fields = [f.astype(t, copy=False) for f, t in zip(fields, types, strict=True)]
        out = {}
        if index.ndim != 2 or index.shape[1] != 6 or len(start) != len(index) + 1:
            raise StoreError(f"{self.location} has malformed per-cell figures; rebuild it.")
        for i, key in enumerate(index.tolist()):
            r0, r1, c0, c1, sr, sc = key
            shape = (-(-(r1 - r0) // sr), -(-(c1 - c0) // sc))
            a, b = int(start[i]), int(start[i + 1])
            if b - a != shape[0] * shape[1] or b > len(fields[0]):
                raise StoreError(f"{self.location} has malformed per-cell figures; rebuild it.")
            out[(r0, r1, c0, c1, sr, sc)] = tuple(f[a:b].reshape(shape) for f in fields)
        return out

    def check_cells(self) -> None:
        """StoreError unless every stored cell set reduces to the error and data count of the
        grid patch with its index, where a node has one (the others stay valid for nodes an
        update may bring back: their cells still hold that patch's figures)."""
        entries = self.cell_entries()
        if not entries or list(self.meta["strategy_names"]) != [GridPatch.kind]:
            return
        base = f"patches/{GridPatch.kind}"
        index = self.reader.read(f"{base}/index")
        stats = self.reader.read(f"{base}/stats")
        where = {tuple(row): i for i, row in enumerate(index.tolist())}
        for key, (error, _, _, count, _) in entries.items():
            i = where.get(key)
            if i is None:
                continue
            if error.max() != stats[i, 0] or count.sum() != stats[i, 3]:
                raise StoreError(
                    f"Tree store {self.location} is corrupted: the per-cell figures of patch "
                    f"{key} disagree with its error. Rebuild it with `approxtree build`."
                )

    def _where(self) -> tuple[np.ndarray, np.ndarray]:
        if self._placement is None:
            self._placement = (
                self.reader.read("nodes/strategies"),
                self.reader.read("nodes/patch_slot"),
            )
        return self._placement

    def fields(self, strategy: str) -> dict[str, int | None]:
        if strategy not in self._fields:
            raw = self.reader.attrs(f"patches/{strategy}").get("fields")
            if not isinstance(raw, dict):
                raise StoreError(f"{self.location} lacks the patch fields of {strategy!r}.")
            self._fields[strategy] = raw
        return self._fields[strategy]

    def _offsets_of(self, path: str) -> np.ndarray:
        if path not in self._offsets:
            self._offsets[path] = self.reader.read(path).astype(np.int64)
        return self._offsets[path]

    def patch_record(self, i: int) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """({}, arrays) of node i's patch, like ``TreeFile.patch_record``."""
        strategies, slot = self._where()
        strategy = self.meta["strategy_names"][int(strategies[i])]
        s = int(slot[i])
        base = f"patches/{strategy}"
        out = {}
        for name, width in self.fields(strategy).items():
            if width is not None:
                out[name] = self.reader.read_rows(f"{base}/{name}", s, s + 1)[0]
            else:
                off = self._offsets_of(f"{base}/{name}_offsets")
                out[name] = self.reader.read_rows(
                    f"{base}/{name}_data", int(off[s]), int(off[s + 1])
                )
        return {}, out

    def records(self, nodes: np.ndarray, strategy: str) -> Batch:
        """The records of ``nodes`` (one strategy): the store's batch whole, reordered only
        if ``nodes`` do not follow its storage order."""
        batch = self.batch(strategy)
        slots = self._where()[1][nodes]
        same = np.array_equal(slots, np.arange(len(nodes)))
        return batch if same else take(batch, slots)

    def stored_lattices(self, strategy: str) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """(index (6,) int64, z (kr · kc,) float64) of every record of ``strategy`` (grid
        patches) that carries its lattice heights (the coarse ones), in slot order."""
        fields = self.fields(strategy)
        if fields.get("index") != 6 or "z" not in fields or fields["z"] is not None:
            return
        base = f"patches/{strategy}"
        off = self._offsets_of(f"{base}/z_offsets")
        lengths = np.diff(off)
        slots = np.flatnonzero(lengths > 0)
        if not len(slots):
            return
        index = self.reader.read(f"{base}/index").astype(np.int64)
        data = self.reader.read_rows(f"{base}/z_data", int(off[slots[0]]), int(off[slots[-1] + 1]))
        base_off = int(off[slots[0]])
        for s in slots.tolist():
            yield index[s], data[int(off[s]) - base_off : int(off[s + 1]) - base_off]

    def grid_table(self, grid: Grid, rects: np.ndarray) -> GridPatchArrays | None:
        """The grid patches of every node over ``grid`` (the stored terrain, or an in-memory
        copy of it) as one table in node order, from the "index" and "stats" arrays alone
        (no lattice heights, no object per node); None unless every node is a grid patch.

        rects: (n, 4) float64 the nodes' rectangles.
        """
        if list(self.meta["strategy_names"]) != [GridPatch.kind]:
            return None
        slot = self._where()[1]
        if self.fields(GridPatch.kind).get("index") != 6:
            return None
        base = f"patches/{GridPatch.kind}"
        index = self.reader.read(f"{base}/index")[slot].astype(np.int64)
        stats = self.reader.read(f"{base}/stats")[slot]
        # Records hold the full raster's indices (``GridPatch.to_record``).
        index[:, :4] -= np.array(grid.index_offset, dtype=np.int64).repeat(2)
        return GridPatchArrays(
            grid,
            np.asarray(rects, dtype=np.float64),
            index,
            np.ascontiguousarray(stats[:, 0]),
            np.ascontiguousarray(stats[:, 1]),
            np.ascontiguousarray(stats[:, 2]),
            stats[:, 3].astype(np.int64),
        )

    def batch(self, strategy: str) -> Batch:
        """Every record of one strategy, in slot order."""
        base = f"patches/{strategy}"
        out: Batch = {}
        for name, width in self.fields(strategy).items():
            if width is not None:
                rows = self.reader.read(f"{base}/{name}")
                out[name] = (rows.reshape(-1), np.arange(len(rows) + 1, dtype=np.int64) * width)
            else:
                off = self._offsets_of(f"{base}/{name}_offsets")
                out[name] = (self.reader.read(f"{base}/{name}_data"), off)
        return out


# -- point quadtrees ---------------------------------------------------------------------------


def save_quadtree(tree: PointQuadtree, path: str | os.PathLike) -> int:
    """Write a PointQuadtree as a tree store (terrain + "quadtree" arrays); returns bytes."""
    meta, arrays = tree.to_sections()
    with writing(path, meta) as root:
        _write_terrain(root, tree.terrain)
        group = root.create_group("quadtree")
        for name, a in arrays.items():
            write_array(group, name, np.asarray(a))
    return store_bytes(path)


def store_info(path: str | os.PathLike) -> dict[str, Any]:
    """Figures of a store: format version, tree kind, nodes, levels, strategies, chunk
    layout (chunk shape and count of the main arrays) and bytes (stored vs raw)."""
    reader = StoreReader(path)
    meta = reader.meta
    out: dict[str, Any] = {
        "store": str(path),
        "format_version": reader.root.attrs.get("format_version"),
        "tree_kind": meta.get("tree_kind"),
        "terrain_kind": meta.get("terrain_kind"),
    }
    if meta.get("tree_kind") == "approximation_tree":
        levels = reader.read("nodes/levels")
        strategies = reader.read("nodes/strategies")
        names = meta["strategy_names"]
        counts = np.bincount(strategies, minlength=len(names))
        out.update(
            {
                "nodes": len(levels),
                "levels": int(levels.max()) + 1 if len(levels) else 0,
                "strategies": {n: int(c) for n, c in zip(names, counts, strict=True)},
                "params": meta.get("params"),
                "ancestor_level": meta.get("ancestor_level"),
            }
        )
    layout = {}
    for p in sorted(reader.arrays()):
        arr = reader.node(p)
        layout[p] = {
            "shape": list(arr.shape),
            "chunks": list(arr.chunks),
            "nchunks": int(arr.nchunks),
        }
    out["chunks"] = layout
    sizes = reader.sizes()
    out["bytes_stored"] = sizes["stored"]
    out["bytes_raw"] = sizes["raw"]
    out["ratio"] = round(sizes["stored"] / sizes["raw"], 4) if sizes["raw"] else None
    return out
