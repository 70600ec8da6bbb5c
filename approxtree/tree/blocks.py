"""Blocked builds: the tree of a Grid cut into blocks at a level L, each block built on its own.

The plan is the *complete* subdivision of the domain down to level L (every node split,
whatever its error): its leaves are the blocks (level-L rectangles, or shallower ones that
cannot be cut), its inner nodes the *upper* nodes. A block task reads only the window of its
rectangle (border lines included), builds its subtree with the normal builder, and measures
each of its ancestors' grid patches over the block's own points (``kernels.grid_patch
.grid_patch_part``). The client reduces those per-block maxima, minima and counts into the
upper nodes' exact errors ε_T(N), keeps the upper nodes whose ancestors were all split, drops
the blocks under an unsplit one, and numbers every node in the serial builder's breadth-first
order. The result is the serial build's tree, node for node.

Upper nodes are grid patches (their error must be a reduction over blocks), so a policy must
choose ``grid`` for every upper node: the ``type`` policy on a Grid, or ``level:grid@0-(L-1),X``.
This module is pure (no dask): ``tree.distributed`` runs the same tasks on a cluster.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.geometry.windowed import WindowedHeights
from approxtree.kernels.grid_patch import grid_patch_part
from approxtree.patches.base import GeometryPatch
from approxtree.patches.grid import GridPatch, grid_steps
from approxtree.patches.table import patch_class
from approxtree.progress import ProgressCallback, no_progress
from approxtree.tree.builder import BuiltLevels, build_levels, validate_parameters
from approxtree.tree.patch_table import PatchTable
from approxtree.tree.policy import StrategyPolicy
from approxtree.tree.store_regions import HeightRegions, OverviewPart
from approxtree.tree.subdivision import subdivide

#: Cells per block side when none is given: a block's window of 2049² float32 heights is 16 MB.
DEFAULT_BLOCK_SIZE = 2048


@dataclass
class Ancestor:
    """The grid patch of an upper node, as a block measures it.

    index: (r0, r1, c0, c1, sr, sc) in the full raster's indices. lattice: heights (dtype of
    the grid) of the sampled rows k_lo.. × sampled columns j_lo.. that the block's cells use,
    or None when the task reads them itself (windowed grids).
    """

    node: int
    index: tuple[int, int, int, int, int, int]
    lattice: np.ndarray | None = None
    k_lo: int = 0
    j_lo: int = 0


@dataclass
class BlockTask:
    """Everything one block task needs; pickles small (a window, or a windowed grid by path).

    grid: the block's window (in-memory terrains) or the whole windowed grid (read inside).
    index: (r0, r1, c0, c1) of the block in the full raster; rect, level: its root node.
    """

    block: int
    grid: Grid
    index: tuple[int, int, int, int]
    rect: Rect
    level: int
    ancestors: list[Ancestor]
    epsilon: float
    max_points: int
    fanout: int
    policy: StrategyPolicy
    #: numba threads inside the task (1 on a cluster: one task per core).
    threads: int | None = None
    #: Where the task writes the height chunks it owns (windowed grids, ``store_regions``).
    regions: HeightRegions | None = None


@dataclass
class BlockResult:
    """A block's subtree (breadth-first, local numbering) and its ancestors' figures.

    rects: (n, 4) float64; levels: (n,) int32 (global levels); parents, child_start,
    child_count: (n,) int64 local (−1 for the block root); kinds, records: each node's patch
    as ``to_record`` (full-raster indices), except grid patches, whose record is None and whose
    figures are rows of ``grid_index`` (k, 6) int64 (full-raster indices and steps) and
    ``grid_stats`` (k, 4) float64 (error, zmin, zmax, count), in node order.
    ancestors: (a, 4) float64 (error, zmin, zmax, count) of each ancestor's grid patch over the
    block's own points, root first.
    Windowed grids only: lattices, the (kr, kc) float64 lattice heights of the block's nodes
    whose records carry them (``GridPatch.stores_lattice``) by local node; ancestor_lattices,
    each ancestor's (lattice part, k_lo, j_lo) as ``lattice_part`` read it, root first; the
    client needs no read of the band for them. overview: the task's overview lines when it
    wrote its height chunks; write_seconds: the time that took.
    """

    block: int
    rects: np.ndarray
    levels: np.ndarray
    parents: np.ndarray
    child_start: np.ndarray
    child_count: np.ndarray
    kinds: list[str]
    records: list[dict[str, np.ndarray] | None]
    grid_index: np.ndarray
    grid_stats: np.ndarray
    ancestors: np.ndarray
    seconds: float
    points: int
    lattices: dict[int, np.ndarray] = field(default_factory=dict)
    ancestor_lattices: list[tuple[np.ndarray, int, int]] = field(default_factory=list)
    overview: OverviewPart | None = None
    write_seconds: float = 0.0


@dataclass
class BlockPlan:
    """The complete subdivision down to the block level.

    Plan nodes are numbered breadth-first; ``rects``, ``levels``, ``parents`` (−1 root),
    ``children`` (lists) per plan node. ``blocks``: plan nodes that are blocks (leaves of the
    plan), in plan order; ``upper``: the others (inner nodes, all with children).
    """

    block_level: int
    rects: list[Rect] = field(default_factory=list)
    levels: list[int] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    children: list[list[int]] = field(default_factory=list)
    index: list[tuple[int, int, int, int]] = field(default_factory=list)
    blocks: list[int] = field(default_factory=list)
    upper: list[int] = field(default_factory=list)

    def ancestors(self, node: int) -> list[int]:
        """Plan nodes above ``node``, root first."""
        out: list[int] = []
        p = self.parents[node]
        while p >= 0:
            out.append(p)
            p = self.parents[p]
        return out[::-1]


def _side(index: tuple[int, int, int, int]) -> int:
    """Cells along the longer side of an index range (its points are one more)."""
    r0, r1, c0, c1 = index
    return max(r1 - r0, c1 - c0)


def plan_blocks(
    grid: Grid,
    fanout: int,
    block_size: int | None = None,
    block_level: int | None = None,
) -> BlockPlan:
    """The complete subdivision down to level L: the given ``block_level``, or the first level
    whose rectangles have at most ``block_size`` cells per side (default 2048; a block's window
    holds one line more, the border it shares with its neighbour)."""
    if block_level is not None and (not isinstance(block_level, int) or block_level < 0):
        raise InvalidParameterError(f"block_level must be an integer >= 0, got {block_level!r}.")
    if block_size is None:
        block_size = DEFAULT_BLOCK_SIZE
    if not isinstance(block_size, int | np.integer) or block_size < 1:
        raise InvalidParameterError(
            f"block_size must be an integer >= 1 (cells per block side), got {block_size!r}."
        )
    plan = BlockPlan(block_level=0)
    root = grid.domain
    plan.rects.append(root)
    plan.levels.append(0)
    plan.parents.append(-1)
    plan.children.append([])
    plan.index.append(grid.index_range(root))
    frontier = [0]
    level = 0
    # Split every node of the frontier until the level is reached (or nothing can be cut).
    while frontier:
        deep_enough = (
            level >= block_level
            if block_level is not None
            else max(_side(plan.index[i]) for i in frontier) <= block_size
        )
        if deep_enough:
            break
        next_frontier: list[int] = []
        for node in frontier:
            for rect in subdivide(grid, plan.rects[node], fanout):
                child = len(plan.rects)
                plan.rects.append(rect)
                plan.levels.append(level + 1)
                plan.parents.append(node)
                plan.children.append([])
                plan.index.append(grid.index_range(rect))
                plan.children[node].append(child)
                next_frontier.append(child)
        frontier = next_frontier
        level += 1
    plan.block_level = level
    plan.blocks = [i for i, ch in enumerate(plan.children) if not ch]
    plan.upper = [i for i, ch in enumerate(plan.children) if ch]
    return plan


def check_policy(grid: Grid, plan: BlockPlan, policy: StrategyPolicy) -> None:
    """InvalidParameterError unless the policy builds every upper node with a grid patch."""
    for node in plan.upper:
        names = policy.candidates(grid, plan.levels[node], plan.rects[node])
        if tuple(names) != ("grid",):
            raise InvalidParameterError(
                f"A blocked build (workers, scheduler or block size) makes the levels above the "
                f"block level {plan.block_level} grid patches, but the policy {policy.name!r} "
                f"asks for {', '.join(names)} at level {plan.levels[node]}. Use the default "
                f"policy or 'level:grid@0-{plan.block_level - 1},<strategy>', a larger block "
                "size, or build without workers."
            )


def upper_patch_index(
    grid: Grid, plan: BlockPlan, node: int, max_points: int
) -> tuple[int, int, int, int, int, int]:
    """(r0, r1, c0, c1, sr, sc) of the grid patch an upper node gets (as GridPatch builds it)."""
    k = math.isqrt(max_points)
    r0, r1, c0, c1 = plan.index[node]
    return (r0, r1, c0, c1, grid_steps(r1 - r0 + 1, k), grid_steps(c1 - c0 + 1, k))


def _sampled(lo: int, hi: int, step: int) -> np.ndarray:
    """Sampled lines of a grid patch: every step-th from lo, and hi."""
    return np.append(np.arange(lo, hi, step), hi).astype(np.int64)


def _cell(lo: int, hi: int, step: int, at: int) -> int:
    """The sampled block (cell) of line ``at`` as ``_patch_error`` assigns it."""
    return min((at - lo) // step, (hi - lo + step - 1) // step - 1)


def lattice_part(
    heights: Any,
    index: tuple[int, int, int, int, int, int],
    block: tuple[int, int, int, int],
) -> tuple[np.ndarray, int, int]:
    """(lattice, k_lo, j_lo): the patch vertices a block's cells use (see grid_patch_part).

    heights: the full raster's heights (an array, or a windowed array-like with integer-array
    indexing); index: the patch; block: (r0, r1, c0, c1) of the block, inside the patch.
    """
    r0, r1, c0, c1, sr, sc = index
    rows = _sampled(r0, r1, sr)
    cols = _sampled(c0, c1, sc)
    k_lo = max(_cell(r0, r1, sr, block[0]) - 1, 0)
    k_hi = _cell(r0, r1, sr, block[1]) + 2
    j_lo = max(_cell(c0, c1, sc, block[2]) - 1, 0)
    j_hi = _cell(c0, c1, sc, block[3]) + 2
    rr, cc = np.meshgrid(rows[k_lo:k_hi], cols[j_lo:j_hi], indexing="ij")
    lattice = np.asarray(heights[rr.ravel(), cc.ravel()]).reshape(rr.shape)
    return np.ascontiguousarray(lattice), k_lo, j_lo


def measure_ancestors(
    window: Grid, block: tuple[int, int, int, int], ancestors: list[Ancestor]
) -> np.ndarray:
    """(a, 4) float64 (error, zmin, zmax, count) of each ancestor patch over the block's own
    points: its rows r0..r1 and columns c0..c1, less the last row (column) unless it is the
    patch's own last one (the next block owns it), so counts add up without double counting."""
    out = np.zeros((len(ancestors), 4))
    br0, br1, bc0, bc1 = block
    wr0, wc0 = window.index_offset
    heights = window.heights_array("measuring a block's ancestor patches")
    for a, anc in enumerate(ancestors):
        if anc.lattice is None:
            raise InvalidParameterError(
                f"Ancestor {anc.node} of the block carries no lattice: read it with lattice_part."
            )
        r0, r1, c0, c1, sr, sc = anc.index
        a1 = br1 if br1 == r1 else br1 - 1
        b1 = bc1 if bc1 == c1 else bc1 - 1
        part = (br0, a1, bc0, b1)
        patch = (r0, r1, c0, c1, sr, sc)
        out[a] = grid_patch_part(heights, wr0, wc0, *part, anc.lattice, anc.k_lo, anc.j_lo, *patch)
    # No data point: no z range (NaN, as the serial build reports it).
    out[out[:, 3] == 0, 1:3] = np.nan
    return out


def run_block(task: BlockTask) -> BlockResult:
    """Build one block's subtree on its window and measure its ancestors (a task's body)."""
    import numba

    t0 = time.perf_counter()
    threads = numba.get_num_threads()
    if task.threads:
        # numba.config sets its settings from the environment at import; its stubs list none.
        limit = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
        numba.set_num_threads(min(task.threads, limit))
    overview = None
    write_seconds = 0.0
    try:
        r0, r1, c0, c1 = task.index
        grid = task.grid
        ancestors = task.ancestors
        windowed = bool(getattr(grid, "is_windowed", False))
        if windowed:
            # A windowed terrain: read the patch vertices around the block, then the window.
            ancestors = [
                Ancestor(a.node, a.index, *lattice_part(grid.heights, a.index, task.index))
                if a.lattice is None
                else a
                for a in ancestors
            ]
            local = (r0 - grid.index_offset[0], c0 - grid.index_offset[1])
            grid = grid.window(local[0], local[0] + r1 - r0, local[1], local[1] + c1 - c0)
        built = build_levels(
            grid,
            task.epsilon,
            task.max_points,
            task.fanout,
            task.policy,
            progress=None,
            root=task.rect,
            root_level=task.level,
        )
        stats = measure_ancestors(grid, task.index, ancestors)
        if task.regions is not None:
            # The height chunks this block owns go into the store from here, not the client.
            t1 = time.perf_counter()
            overview = task.regions.write(task.grid.heights, task.index)
            write_seconds = time.perf_counter() - t1
    finally:
        numba.set_num_threads(threads)
        # A worker keeps a task until its result is collected: a windowed terrain's block
        # cache and dataset handle go now, so worker memory does not grow with the blocks done.
        if isinstance(task.grid.heights, WindowedHeights):
            task.grid.heights.clear_cache()
            close = getattr(task.grid.heights.source, "close", None)
            if close is not None:
                close()
    n = len(built.patches)
    offset = np.array(grid.index_offset, dtype=np.int64).repeat(2)  # r, r, c, c
    table = built.patches
    if isinstance(table, PatchTable) and table.arrays is not None and (table.row >= 0).all():
        # A block of grid levels: its arrays as they are, no patch object.
        a = table.arrays
        rows = table.row
        is_grid = [True] * n
        grid_index = np.array(a.index[rows], dtype=np.int64).reshape(-1, 6)
        grid_stats = np.column_stack([a.error[rows], a.zmin[rows], a.zmax[rows], a.count[rows]])
    else:
        # Grid patches (most nodes) travel as two arrays rather than one record each.
        is_grid = [type(p) is GridPatch for p in built.patches]
        grid_patches = [p for p in built.patches if type(p) is GridPatch]
        grid_index = np.array([p.index for p in grid_patches], dtype=np.int64).reshape(-1, 6)
        grid_stats = np.array(
            [(p.error, *p.z_range, p.data_count) for p in grid_patches], dtype=np.float64
        ).reshape(-1, 4)
    grid_index[:, :4] += offset
    kinds = [GridPatch.kind] * n if all(is_grid) else [p.kind for p in built.patches]
    records: list[dict[str, np.ndarray] | None] = (
        [None] * n
        if all(is_grid)
        else [None if g else p.to_record() for p, g in zip(built.patches, is_grid, strict=True)]
    )
    # A windowed grid's coarse lattices travel back: the client would read the band for them.
    lattices = _stored_lattices(built.patches) if windowed else {}
    ancestor_lattices = (
        [(np.asarray(a.lattice, dtype=np.float64), a.k_lo, a.j_lo) for a in ancestors]
        if windowed
        else []
    )
    return BlockResult(
        block=task.block,
        rects=np.asarray(built.rects, dtype=np.float64).reshape(n, 4),
        levels=np.array(built.levels, dtype=np.int32),
        parents=np.array(built.parents, dtype=np.int64),
        child_start=np.array(built.child_start, dtype=np.int64),
        child_count=np.array(built.child_count, dtype=np.int64),
        kinds=kinds,
        records=records,
        grid_index=grid_index,
        grid_stats=grid_stats,
        ancestors=stats,
        seconds=time.perf_counter() - t0,
        points=(r1 - r0 + 1) * (c1 - c0 + 1),
        lattices=lattices,
        ancestor_lattices=ancestor_lattices,
        overview=overview,
        write_seconds=write_seconds,
    )


def _stored_lattices(patches: Any) -> dict[int, np.ndarray]:
    """{local node: (kr, kc) float64 lattice heights} of the grid patches whose records carry
    them (the coarse ones: few per block)."""
    out: dict[int, np.ndarray] = {}
    for i in range(len(patches)):
        p = patches[i]
        if type(p) is GridPatch and p.stores_lattice:
            out[i] = np.asarray(p.lattice_heights(), dtype=np.float64)
    return out


def make_tasks(
    grid: Grid,
    plan: BlockPlan,
    epsilon: float,
    max_points: int,
    fanout: int,
    policy: StrategyPolicy,
    threads: int | None = None,
    regions: HeightRegions | None = None,
) -> list[BlockTask]:
    """One task per block. An in-memory grid ships each block's window and the patch vertices
    it needs; a windowed grid (``is_windowed``) ships itself and the task reads both, and
    writes its height chunks into ``regions`` when given."""
    windowed = bool(getattr(grid, "is_windowed", False))
    index = {node: upper_patch_index(grid, plan, node, max_points) for node in plan.upper}
    tasks: list[BlockTask] = []
    for b, node in enumerate(plan.blocks):
        block = plan.index[node]
        ancestors = [
            Ancestor(a, index[a])
            if windowed
            else Ancestor(a, index[a], *lattice_part(grid.heights, index[a], block))
            for a in plan.ancestors(node)
        ]
        tgrid = grid if windowed else grid.window(*block)
        tasks.append(
            BlockTask(
                block=b,
                grid=tgrid,
                index=block,
                rect=plan.rects[node],
                level=plan.levels[node],
                ancestors=ancestors,
                epsilon=float(epsilon),
                max_points=int(max_points),
                fanout=int(fanout),
                policy=policy,
                threads=threads,
                regions=regions if windowed else None,
            )
        )
    return tasks


def assemble(
    grid: Grid,
    plan: BlockPlan,
    results: list[BlockResult],
    epsilon: float,
    max_points: int,
) -> BuiltLevels:
    """The serial builder's tree from the plan and the block results (any order).

    Upper nodes get the reduced figures of their grid patches; a node is kept when all its
    ancestors were split (error > ε; every upper node can be cut); numbering is breadth-first,
    a level's nodes in the serial frontier's order (the blocks' own levels concatenated in
    block order below the block level).
    """
    by_block = {r.block: r for r in results}
    n_plan = len(plan.rects)
    # Reduce the per-block figures of every upper node: max error, min/max z, summed counts.
    err = np.zeros(n_plan)
    zmin = np.full(n_plan, np.nan)
    zmax = np.full(n_plan, np.nan)
    count = np.zeros(n_plan, dtype=np.int64)
    for b, node in enumerate(plan.blocks):
        res = by_block[b]
        anc = np.array(plan.ancestors(node), dtype=np.int64)
        if len(anc):
            s = res.ancestors
            err[anc] = np.maximum(err[anc], s[:, 0])
            zmin[anc] = np.fmin(zmin[anc], s[:, 1])
            zmax[anc] = np.fmax(zmax[anc], s[:, 2])
            count[anc] += s[:, 3].astype(np.int64)
    upper_patch: dict[int, GeometryPatch] = {}
    for node in plan.upper:
        upper_patch[node] = GridPatch(
            grid,
            plan.rects[node],
            upper_patch_index(grid, plan, node, max_points),
            err[node],
            (zmin[node], zmax[node]),
            int(count[node]),
        )
    _place_upper_lattices(plan, results, upper_patch)
    # Kept plan nodes: the root, and the children of kept upper nodes that split.
    kept = np.zeros(n_plan, dtype=bool)
    kept[0] = True
    for node in range(n_plan):  # plan order is breadth-first: parents come first
        if kept[node] and node in upper_patch and upper_patch[node].error > epsilon:
            kept[plan.children[node]] = True
    block_of = {node: b for b, node in enumerate(plan.blocks)}

    # Global numbering: upper levels in plan order; below, each kept level-L block's levels.
    gid = np.full(n_plan, -1, dtype=np.int64)
    block_gid: dict[int, np.ndarray] = {}
    next_id = 0
    for level in range(plan.block_level + 1):
        for node in np.flatnonzero(kept & (np.array(plan.levels) == level)).tolist():
            gid[node] = next_id
            next_id += 1
            if node in block_of:
                res = by_block[block_of[node]]
                block_gid[block_of[node]] = np.full(len(res.levels), -1, dtype=np.int64)
                block_gid[block_of[node]][0] = gid[node]
    deep = [b for b in sorted(block_gid) if plan.levels[plan.blocks[b]] == plan.block_level]
    level = plan.block_level + 1
    while True:
        placed = False
        for b in deep:
            sel = np.flatnonzero(by_block[b].levels == level)
            if len(sel):
                block_gid[b][sel] = np.arange(next_id, next_id + len(sel))
                next_id += len(sel)
                placed = True
        if not placed:
            break
        level += 1

    # Fill the flat arrays: upper nodes one by one (few), block nodes by whole arrays.
    n = next_id
    rects: list[Rect | None] = [None] * n
    patches: list[GeometryPatch | None] = [None] * n
    levels = np.zeros(n, dtype=np.int64)
    parents = np.full(n, -1, dtype=np.int64)
    child_start = np.zeros(n, dtype=np.int64)
    child_count = np.zeros(n, dtype=np.int64)
    for node in np.flatnonzero(kept).tolist():
        if node not in upper_patch:
            continue
        g = gid[node]
        p = upper_patch[node]
        rects[g], patches[g], levels[g] = plan.rects[node], p, plan.levels[node]
        parents[g] = gid[plan.parents[node]] if plan.parents[node] >= 0 else -1
        if p.error > epsilon:
            child_start[g] = gid[plan.children[node][0]]
            child_count[g] = len(plan.children[node])
    for b, ids in block_gid.items():
        res = by_block[b]
        node = plan.blocks[b]
        levels[ids] = res.levels
        local_parent = res.parents
        parents[ids] = np.where(local_parent >= 0, ids[np.maximum(local_parent, 0)], -1)
        parents[ids[0]] = gid[plan.parents[node]] if plan.parents[node] >= 0 else -1
        has = res.child_count > 0
        child_start[ids[has]] = ids[res.child_start[has]]
        child_count[ids] = res.child_count
        gi = res.grid_index.copy()
        gi[:, :4] -= np.array(grid.index_offset, dtype=np.int64).repeat(2)
        grid_rows = iter(zip(gi.tolist(), res.grid_stats.tolist(), strict=True))
        for j, (g, box, kind, record) in enumerate(
            zip(ids.tolist(), res.rects.tolist(), res.kinds, res.records, strict=True)
        ):
            rect = Rect(*box)
            rects[g] = rect
            if record is None:
                index, (error, lo, hi, cnt) = next(grid_rows)
                patch = GridPatch(grid, rect, index, error, (lo, hi), int(cnt))
                patch._lattice_z = res.lattices.get(j)
                patches[g] = patch
            else:
                patches[g] = patch_class(grid, kind).from_record(grid, rect, record)
    return BuiltLevels(
        rects=np.array([r.as_tuple() for r in rects], dtype=np.float64).reshape(n, 4),  # type: ignore[union-attr]
        patches=patches,  # type: ignore[arg-type]
        levels=levels,
        parents=parents,
        child_start=child_start,
        child_count=child_count,
    )


def _place_upper_lattices(
    plan: BlockPlan, results: list[BlockResult], upper_patch: dict[int, GeometryPatch]
) -> None:
    """Hand the upper patches that store their lattice the heights the blocks read for them
    (windowed grids): the blocks' parts tile each lattice, so no read of the band is left."""
    by_block = {r.block: r for r in results}
    lattices: dict[int, np.ndarray] = {}
    for b, node in enumerate(plan.blocks):
        for anc, (part, k, j) in zip(
            plan.ancestors(node), by_block[b].ancestor_lattices, strict=False
        ):
            patch = upper_patch[anc]
            if not (isinstance(patch, GridPatch) and patch.stores_lattice):
                continue
            if anc not in lattices:
                rows, cols = patch.lines
                lattices[anc] = np.full((len(rows), len(cols)), np.nan)
            lattices[anc][k : k + part.shape[0], j : j + part.shape[1]] = part
    for anc, z in lattices.items():
        upper_patch[anc]._lattice_z = z  # type: ignore[attr-defined]


def build_blocked(
    grid: GeometryData,
    epsilon: float,
    max_points: int,
    fanout: int,
    policy: StrategyPolicy,
    block_size: int | None = None,
    block_level: int | None = None,
    run: Callable[[list[BlockTask]], list[BlockResult]] | None = None,
    progress: ProgressCallback | None = None,
    regions: HeightRegions | None = None,
) -> BuiltLevels:
    """The serial build's nodes, built block by block.

    run: callable(tasks) -> results (``tree.distributed`` passes a dask runner); None runs the
    tasks here, one after the other; progress(done, total) in blocks (``approxtree.progress``;
    a ``run`` reports its own); regions: where the tasks of a windowed grid write its height
    chunks (``store_regions``; the store then takes them as they are).
    """
    validate_parameters(epsilon, max_points, fanout)
    if not isinstance(grid, Grid):
        raise InvalidParameterError(
            f"Blocked builds (workers, scheduler, block size) need a regular Grid, got a "
            f"{type(grid).__name__}; build it without workers."
        )
    t0 = time.perf_counter()
    plan = plan_blocks(grid, fanout, block_size, block_level)
    check_policy(grid, plan, policy)
    tasks = make_tasks(grid, plan, epsilon, max_points, fanout, policy, regions=regions)
    if run is None:
        report = progress or no_progress
        report(0, len(tasks))
        results = []
        for i, t in enumerate(tasks):
            results.append(run_block(t))
            report(i + 1, len(tasks))
    else:
        results = run(tasks)
    if regions is not None and all(t.regions is not None for t in tasks):
        regions.collect(r.overview for r in results)
    out = assemble(grid, plan, results, epsilon, max_points)
    # The root's figures are the band's: a windowed grid need not scan itself for them.
    if getattr(grid, "is_windowed", False) and "_n_valid" not in grid.__dict__:
        root = out.patches[0]
        if root.rect == grid.domain and root.data_count > 0:
            grid.__dict__["_n_valid"] = int(root.data_count)
            grid.__dict__["_z_range"] = (float(root.z_range[0]), float(root.z_range[1]))
    out.seconds = time.perf_counter() - t0
    return out
