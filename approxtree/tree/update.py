"""Dynamic terrain: replace a window of a Grid's heights and bring the tree up to date.

``ApproximationTree.update(rect, heights)`` writes the window's cells into the terrain and
walks the tree level by level as the builder does (``builder.build_levels``): a node whose
domain meets the window, or that did not exist before, gets its patch (and exact error)
rebuilt with the builder's own level code; every other node keeps its patch, and, when it
was split before, its children. The split decision of a rebuilt node follows its new error,
so subtrees appear (built fresh, level by level) or vanish where ε_T(N) crosses ε. Nodes are
numbered breadth-first in the builder's frontier order, so the result is the tree a fresh
build of the edited terrain makes, node for node and bit for bit (a patch depends on its own
domain's points only, and a level's patches on nothing but their own rectangles).

The tree's origin (the float32 anchor of GPU buffers) is kept, so an Engine's payloads of the
unchanged nodes stay valid; ``TreeUpdate.old_to_new`` maps their ids.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from approxtree.errors import EmptyTerrainError, InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.patches.base import GeometryPatch
from approxtree.patches.grid import GridPatch, GridPatchArrays
from approxtree.tree import update_cells
from approxtree.tree.builder import BuiltLevels, _build_level
from approxtree.tree.patch_table import PatchTable
from approxtree.tree.policy import StrategyPolicy
from approxtree.tree.subdivision import subdivide_level
from approxtree.tree.tree_store import TreeStoreSource
from approxtree.tree.update_band import read_domains
from approxtree.tree.update_cells import CellCache

if TYPE_CHECKING:
    from approxtree.tree.approximation_tree import ApproximationTree

#: Node maps of the last updates a tree keeps for the Engines drawing it (``changes_since``).
KEPT_CHANGES = 16

#: Tolerance, in cells, on a window's edges lying on the grid's cell edges.
_ALIGN_TOLERANCE = 1e-6


@dataclass
class TreeUpdate:
    """What an update changed.

    window: (r0, r1, c0, c1) inclusive cell indices of the edited cells (the grid's own).
    old_to_new: (n_old,) int64 the new id of each old node, −1 where it is gone or rebuilt.
    rebuilt: (k,) int64 new ids whose patch was built by the update (changed or new nodes).
    removed: (m,) int64 old ids with no unchanged counterpart (rebuilt or dropped).
    seconds: wall time of the update.
    """

    window: tuple[int, int, int, int]
    old_to_new: np.ndarray
    rebuilt: np.ndarray
    removed: np.ndarray
    nodes_before: int
    nodes_after: int
    seconds: float

    def as_dict(self) -> dict[str, object]:
        """JSON-ready figures (the CLI's ``--json``)."""
        r0, r1, c0, c1 = self.window
        return {
            "window": {"row": r0, "col": c0, "rows": r1 - r0 + 1, "cols": c1 - c0 + 1},
            "nodes_before": self.nodes_before,
            "nodes_after": self.nodes_after,
            "rebuilt": len(self.rebuilt),
            "removed": len(self.removed),
            "kept": int((self.old_to_new >= 0).sum()),
            "seconds": round(self.seconds, 6),
        }


def window_cells(grid: Grid, rect: Rect, shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    """(r0, r1, c0, c1) inclusive cells (the grid's own indices) a world rect covers.

    rect's edges must lie on the grid's cell edges (pixel corners) and span ``shape`` =
    (rows, cols) cells inside the grid, else InvalidParameterError.
    """
    if len(shape) != 2:
        raise InvalidParameterError(f"Window heights must be a 2-D array, got shape {shape}.")
    t = grid.transform
    r_off, c_off = grid.index_offset
    # Pixel-corner coordinates of the rect's edges: integers when aligned.
    cols = sorted(((rect.xmin - t.c) / t.a - c_off, (rect.xmax - t.c) / t.a - c_off))
    rows = sorted(((rect.ymax - t.f) / t.e - r_off, (rect.ymin - t.f) / t.e - r_off))
    edges = [*rows, *cols]
    if not all(math.isfinite(v) and abs(v - round(v)) <= _ALIGN_TOLERANCE for v in edges):
        raise InvalidParameterError(
            f"The window {rect.as_tuple()} does not lie on the terrain's cell edges "
            f"(cell size {grid.cell_size}); align it with the grid's cells."
        )
    r0, r_end, c0, c_end = (round(v) for v in edges)
    if (r_end - r0, c_end - c0) != tuple(shape):
        raise InvalidParameterError(
            f"The window covers {r_end - r0} × {c_end - c0} cells but the heights are "
            f"{shape[0]} × {shape[1]}."
        )
    if r0 < 0 or c0 < 0 or r_end > grid.height or c_end > grid.width or r_end <= r0:
        raise InvalidParameterError(
            f"The window (rows {r0}..{r_end - 1}, columns {c0}..{c_end - 1}) is not inside the "
            f"terrain's {grid.height} × {grid.width} cells."
        )
    return r0, r_end - 1, c0, c_end - 1


def edit_grid(grid: Grid, window: tuple[int, int, int, int], heights: np.ndarray) -> np.ndarray:
    """Write ``heights`` (rows, cols; NaN = no data) into the grid's cells, in place; returns
    the cells' previous heights (rows, cols), a copy."""
    if grid.is_windowed or not isinstance(grid.heights, np.ndarray):
        raise InvalidParameterError(
            "Only an in-memory Grid can be updated; read the terrain whole (not windowed)."
        )
    r0, r1, c0, c1 = window
    band = grid.heights
    old = band[r0 : r1 + 1, c0 : c1 + 1]
    new = np.asarray(heights, dtype=band.dtype)
    n_valid = grid.point_count - int(np.isfinite(old).sum()) + int(np.isfinite(new).sum())
    if n_valid == 0:
        raise EmptyTerrainError("The update would leave the terrain without a single data point.")
    if not band.flags.writeable:
        # A band read from a store may be read-only: the grid takes its own copy once.
        band = grid.heights = np.array(band)
    before = np.array(old)
    band[r0 : r1 + 1, c0 : c1 + 1] = new
    # The grid's cached figures follow; its z range is found again when next asked.
    grid.__dict__["_n_valid"] = n_valid
    grid.__dict__.pop("_z_range", None)
    return before


def _meets(grid: Grid, rects: np.ndarray, window: tuple[int, int, int, int]) -> np.ndarray:
    """(k,) bool: the node's data points (closed rect) include a cell of the window."""
    r = grid.index_ranges(rects)
    w0, w1, v0, v1 = window
    return (r[:, 0] <= w1) & (r[:, 1] >= w0) & (r[:, 2] <= v1) & (r[:, 3] >= v0)


def _level_part(
    old: PatchTable | Sequence[GeometryPatch | None],
    tree: ApproximationTree,
    old_ids: np.ndarray,
    need: np.ndarray,
    built: Sequence[GeometryPatch] | GridPatchArrays,
) -> Sequence[GeometryPatch] | GridPatchArrays:
    """One level's patches: the old nodes' where kept, the built ones (in order) elsewhere."""
    keep = np.flatnonzero(~need)
    fresh = np.flatnonzero(need)
    k = len(need)
    rows = old.row[old_ids[keep]] if isinstance(old, PatchTable) else None
    if (
        isinstance(built, GridPatchArrays)
        and isinstance(old, PatchTable)
        and old.arrays is not None
        and rows is not None
        and (rows >= 0).all()
        and (len(keep) == 0 or old.arrays.grid is built.grid)
    ):
        # Grid levels stay arrays: the kept rows and the built rows in node order.
        fields = {}
        for name in GridPatchArrays._fields:
            b = getattr(built, name)
            col = np.empty((k, *b.shape[1:]), dtype=b.dtype)
            col[fresh] = b
            col[keep] = getattr(old.arrays, name)[rows]
            fields[name] = col
        return GridPatchArrays(built.grid, **fields)
    out: list[GeometryPatch] = [None] * k  # type: ignore[list-item]
    made = built.patches() if isinstance(built, GridPatchArrays) else built
    for i, p in zip(fresh.tolist(), made, strict=True):
        out[i] = p
    for i, o in zip(keep.tolist(), old_ids[keep].tolist(), strict=True):
        out[i] = tree.patch(o)
    return out


def _errors(patches: Sequence[GeometryPatch] | GridPatchArrays) -> np.ndarray:
    """(k,) float64 ε_T(N) of a level's patches."""
    if isinstance(patches, GridPatchArrays):
        return np.asarray(patches.error, dtype=np.float64)
    return np.fromiter((p.error for p in patches), dtype=np.float64, count=len(patches))


def _prebuild(
    tree: ApproximationTree,
    grid: Grid,
    policy: StrategyPolicy,
    window: tuple[int, int, int, int],
    max_points: int,
) -> tuple[np.ndarray, GridPatchArrays] | None:
    """The new grid patches of every old node the window reaches (below the per-cell size),
    in one kernel call rather than one per level: (old ids (m,) ascending, their patches).
    None unless the policy makes all of them grid patches (a patch then depends on its
    rectangle alone, whatever its level)."""
    ids = np.flatnonzero(_meets(grid, tree.rects, window))
    r = grid.index_ranges(tree.rects[ids])
    points = (r[:, 1] - r[:, 0] + 1) * (r[:, 3] - r[:, 2] + 1)
    ids = ids[points < update_cells.LARGE_POINTS]
    if not len(ids):
        return None
    read_domains(grid, r[points < update_cells.LARGE_POINTS])
    levels = tree.levels[ids]
    for lv in np.unique(levels).tolist():
        groups = policy.candidates_level(grid, int(lv), tree.rects[ids[levels == lv]])
        if len(groups) != 1 or tuple(groups[0][0]) != ("grid",):
            return None
    return ids, GridPatch.build_level_arrays(grid, tree.rects[ids], max_points)


def _merge(
    grid: Grid, parts: list[tuple[np.ndarray, Sequence[GeometryPatch] | GridPatchArrays]]
) -> Sequence[GeometryPatch] | GridPatchArrays:
    """One level's patches from parts (mask (k,) bool, the patches of the masked nodes in
    order) that together cover the k nodes once: one table when all parts are arrays."""
    k = len(parts[0][0])
    if all(isinstance(p, GridPatchArrays) for _, p in parts):
        fields = {}
        for name in GridPatchArrays._fields:
            first = getattr(parts[0][1], name)
            col = np.empty((k, *first.shape[1:]), dtype=first.dtype)
            for mask, p in parts:
                col[mask] = getattr(p, name)
            fields[name] = col
        return GridPatchArrays(grid, **fields)
    out: list[GeometryPatch] = [None] * k  # type: ignore[list-item]
    for mask, p in parts:
        made = p.patches() if isinstance(p, GridPatchArrays) else p
        for i, g in zip(np.flatnonzero(mask).tolist(), made, strict=True):
            out[i] = g
    return out


def _build_need(
    grid: Grid,
    policy: StrategyPolicy,
    level: int,
    rects: np.ndarray,
    need: np.ndarray,
    old_ids: np.ndarray,
    max_points: int,
    eps: float,
    cells: CellCache | None,
    window: tuple[int, int, int, int],
    pre: tuple[np.ndarray, GridPatchArrays] | None,
) -> Sequence[GeometryPatch] | GridPatchArrays:
    """The patches of the level's nodes in ``need`` (in order): prebuilt ones (``_prebuild``),
    large grid patches from the cell cache (``update_cells``), the others by the builder's own
    level code."""
    wanted = rects[need]
    if not len(wanted):
        return []
    parts: list[tuple[np.ndarray, Sequence[GeometryPatch] | GridPatchArrays]] = []
    left = np.ones(len(wanted), dtype=bool)
    if pre is not None:
        # Old nodes prebuilt in one call: their rows, by old id.
        wanted_old = old_ids[need]
        pos = np.minimum(np.searchsorted(pre[0], wanted_old), len(pre[0]) - 1)
        taken = (wanted_old >= 0) & (pre[0][pos] == wanted_old)
        if taken.any():
            a = pre[1]
            rows = pos[taken]
            cols = [getattr(a, name)[rows] for name in GridPatchArrays._fields]
            parts.append((taken, GridPatchArrays(a.grid, *cols)))
            left &= ~taken
    if cells is not None and left.any():
        large = np.zeros(len(wanted), dtype=bool)
        large[left] = cells.eligible(grid, policy, level, wanted[left], max_points)
        if large.any():
            parts.append((large, cells.build(grid, wanted[large], max_points, window)))
            left &= ~large
    if left.any():
        read_domains(grid, grid.index_ranges(wanted[left]))
        parts.append((left, _build_level(grid, policy, level, wanted[left], max_points, eps)))
    if len(parts) == 1:
        return parts[0][1]
    return _merge(grid, parts)


def update_levels(
    tree: ApproximationTree,
    window: tuple[int, int, int, int],
    policy: StrategyPolicy,
    cells: CellCache | None = None,
) -> tuple[BuiltLevels, np.ndarray, np.ndarray]:
    """The new tree's nodes after the terrain's cells in ``window`` changed.

    Returns (built levels, old_of (n,) int64 old id of each new node that kept its patch or
    −1, rebuilt (k,) int64 new ids whose patch was built here).
    """
    grid = tree.terrain
    if not isinstance(grid, Grid):  # pragma: no cover - update_tree checks it first
        raise InvalidParameterError("Only a tree over a regular Grid can be updated.")
    eps, max_points, fanout = tree.epsilon, tree.max_points, tree.fanout
    o_rects, o_cs, o_cc = tree.rects, tree.child_start, tree.child_count
    # Patches of the old tree: a build's table, or the loaded tree's (read on demand).
    old_patches = tree._patches
    # The frontier: rects (k, 4), old ids (−1: no old node), new parents.
    rects = o_rects[:1].copy()
    old_ids = np.zeros(1, dtype=np.int64)
    parents = np.array([-1], dtype=np.int64)
    level = 0
    first = 0
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("rects", "lv", "par", "cs", "cc", "old")}
    patch_parts: list[Sequence[GeometryPatch] | GridPatchArrays] = []
    rebuilt: list[np.ndarray] = []
    pre = _prebuild(tree, grid, policy, window, max_points)
    # Whether each frontier node's parent met the window: a child's points are among its
    # parent's, so only those children are tested (a new node's children are new anyway).
    parent_met = np.ones(1, dtype=bool)
    while len(rects):
        need = old_ids < 0
        known = np.flatnonzero(~need & parent_met)
        met = np.zeros(len(rects), dtype=bool)
        met[known] = _meets(grid, rects[known], window)
        need |= met
        built = _build_need(
            grid, policy, level, rects, need, old_ids, max_points, eps, cells, window, pre
        )
        patches = _level_part(old_patches, tree, old_ids, need, built)
        split = np.flatnonzero(_errors(patches) > eps)
        # Split nodes that had children keep them (same rectangles); others are cut afresh.
        s_old = old_ids[split]
        had = s_old >= 0
        had[had] = o_cc[s_old[had]] > 0
        fresh_rects, fresh_counts = subdivide_level(grid, rects[split[~had]], fanout)
        counts = np.zeros(len(split), dtype=np.int64)
        counts[had] = o_cc[s_old[had]]
        counts[~had] = fresh_counts
        owner = np.repeat(np.arange(len(split)), counts)
        within = np.arange(len(owner)) - (np.cumsum(counts) - counts)[owner]
        from_old = had[owner]
        child_old = np.full(len(owner), -1, dtype=np.int64)
        child_old[from_old] = o_cs[s_old[owner[from_old]]] + within[from_old]
        children = np.empty((len(owner), 4))
        children[from_old] = o_rects[child_old[from_old]]
        children[~from_old] = fresh_rects
        # Children are numbered right after the level, in their parents' order (the builder's).
        count = np.zeros(len(rects), dtype=np.int64)
        count[split] = counts
        next_first = first + len(rects)
        parts["rects"].append(rects)
        parts["lv"].append(np.full(len(rects), level, dtype=np.int64))
        parts["par"].append(parents)
        parts["cs"].append(np.where(count > 0, next_first + np.cumsum(count) - count, 0))
        parts["cc"].append(count)
        parts["old"].append(np.where(need, -1, old_ids))
        patch_parts.append(patches)
        rebuilt.append(first + np.flatnonzero(need))
        parents = next_first - len(rects) + split[owner]
        rects, old_ids = children, child_old
        parent_met = met[split[owner]]
        first = next_first
        level += 1
    out = BuiltLevels(
        rects=np.concatenate(parts["rects"]),
        patches=PatchTable(patch_parts),
        levels=np.concatenate(parts["lv"]),
        parents=np.concatenate(parts["par"]),
        child_start=np.concatenate(parts["cs"]),
        child_count=np.concatenate(parts["cc"]),
    )
    return out, np.concatenate(parts["old"]), np.concatenate(rebuilt)


def update_tree(tree: ApproximationTree, rect: Rect, heights: np.ndarray) -> TreeUpdate:
    """Edit the tree's terrain in place and rebuild the nodes the window reaches (module doc).

    rect: the window in world units, on the grid's cell edges; heights: (rows, cols) of its
    cells, north-up as the grid's own, NaN for no data.
    """
    t0 = time.perf_counter()
    grid = tree.terrain
    if type(grid) is not Grid:
        raise InvalidParameterError(
            f"Only a tree over a regular Grid can be updated, not over a {type(grid).__name__}."
        )
    heights = np.asarray(heights)
    window = window_cells(grid, rect, heights.shape)
    policy = StrategyPolicy.resolve(tree.params["policy"])
    before = edit_grid(grid, window, heights)
    _table_of_loaded(tree, grid)
    # Large grid patches are measured per lattice cell, kept by the tree between updates
    # (made by the build, or read from the store the tree was loaded from).
    cells = tree.__dict__.get("_cell_cache")
    if cells is None:
        cells = tree.__dict__["_cell_cache"] = _stored_cells(tree)
    cells.begin()
    try:
        built, old_of, rebuilt = update_levels(tree, window, policy, cells)
    except BaseException:
        # A failed walk leaves tree and terrain as they were; the cache is forgotten.
        edit_grid(grid, window, before)
        tree.__dict__.pop("_cell_cache", None)
        raise
    cells.end(window)
    n_old = len(tree)
    old_to_new = np.full(n_old, -1, dtype=np.int64)
    kept = np.flatnonzero(old_of >= 0)
    old_to_new[old_of[kept]] = kept
    tree.replace_nodes(built)
    _root_z_range(tree, grid)
    return TreeUpdate(
        window=window,
        old_to_new=old_to_new,
        rebuilt=rebuilt,
        removed=np.flatnonzero(old_to_new < 0),
        nodes_before=n_old,
        nodes_after=len(tree),
        seconds=time.perf_counter() - t0,
    )


def _table_of_loaded(tree: ApproximationTree, grid: Grid) -> None:
    """Hold a loaded grid tree's patches as one table read from its store (two arrays, not a
    record per node), so the update keeps the unchanged nodes' rows without an object each."""
    source = tree._source
    if (
        isinstance(tree._patches, PatchTable)
        or not isinstance(source, TreeStoreSource)
        or list(tree.strategy_names) != [GridPatchArrays.kind]
    ):
        return
    table = source.grid_table(grid, tree.rects)
    if table is not None:
        tree._patches = PatchTable([table])


def _root_z_range(tree: ApproximationTree, grid: Grid) -> None:
    """The edited grid's z range from the root's patch (its data points are all the grid's),
    not from a pass over the band; left to that pass where an extreme is a zero (its sign
    follows the scan order)."""
    zmin, zmax = float(tree.bboxes[0, 2]), float(tree.bboxes[0, 5])
    if grid.point_count > 0 and zmin != 0.0 and zmax != 0.0 and zmin <= zmax:
        grid.__dict__["_z_range"] = (zmin, zmax)


def _stored_cells(tree: ApproximationTree) -> CellCache:
    """The per-cell figures a loaded tree's store holds (``cells/``), or an empty cache."""
    source = tree._source
    entries = source.cell_entries() if isinstance(source, TreeStoreSource) else None
    return CellCache(entries=dict(entries) if entries else {})


def compose_changes(changes: list[np.ndarray], behind: int) -> np.ndarray | None:
    """The node map from ``behind`` updates ago to now: the last ``behind`` old_to_new maps
    composed (−1 stays −1); None when fewer are kept. behind 0 is no map (None as well)."""
    if behind <= 0 or behind > len(changes):
        return None
    out = changes[-behind]
    for step in changes[len(changes) - behind + 1 :]:
        out = np.where(out >= 0, step[np.maximum(out, 0)], -1)
    return out
