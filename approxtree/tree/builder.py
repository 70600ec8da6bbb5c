"""Top-down construction of an approximation tree A(s,d)(T), one level at a time.

Each level's nodes are built in one batch per strategy (so the numba kernels see many nodes at
once); a node is split while ε_T(N) > ε and its domain can still be cut. Nodes are numbered in
breadth-first order, so the children of a node are contiguous.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from approxtree.errors import InvalidParameterError, UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.patches.base import GeometryPatch
from approxtree.patches.grid import GridPatchArrays
from approxtree.patches.table import patch_class
from approxtree.progress import ProgressCallback, no_progress
from approxtree.tree import update_cells
from approxtree.tree.patch_table import PatchTable
from approxtree.tree.policy import StrategyPolicy
from approxtree.tree.subdivision import FANOUTS, subdivide_level
from approxtree.tree.update_cells import CellCache


@dataclass
class BuiltLevels:
    """The flat arrays of a freshly built tree (see ApproximationTree for their meaning).

    rects: (n, 4) float64; levels, parents, child_start, child_count: (n,) int64; patches: the
    n patches in the same breadth-first order (a list, or a PatchTable that makes the objects
    of grid patches on first access).
    """

    rects: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    patches: Sequence[GeometryPatch] | PatchTable = field(default_factory=list)
    levels: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    parents: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    child_start: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    child_count: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    seconds: float = 0.0
    #: Per-cell figures of the large grid patches (``update_cells``), when measured so.
    cells: CellCache | None = None


def validate_parameters(epsilon: float, max_points: int, fanout: int) -> None:
    """Raise InvalidParameterError for a threshold, point budget or fanout out of range."""
    if not isinstance(epsilon, int | float) or not math.isfinite(epsilon) or epsilon < 0:
        raise InvalidParameterError(
            f"epsilon must be a finite number >= 0 (in the terrain's z units), got {epsilon!r}."
        )
    if not isinstance(max_points, int | np.integer) or max_points < 4:
        raise InvalidParameterError(
            f"max_points must be an integer >= 4 (a patch needs 2 × 2 points), got {max_points!r}."
        )
    if fanout not in FANOUTS:
        raise InvalidParameterError(f"fanout must be one of {FANOUTS}, got {fanout!r}.")


def _build_level(
    terrain: GeometryData,
    policy: StrategyPolicy,
    level: int,
    rects: np.ndarray,
    max_points: int,
    epsilon: float,
) -> Sequence[GeometryPatch] | GridPatchArrays:
    """The patch of every node of one level, as the policy chooses among its candidates.

    rects: (k, 4) float64 rectangles of the level's nodes. Python runs per group of nodes
    sharing their candidates and per strategy; the strategies build whole arrays of nodes.
    A level of one strategy that keeps arrays (grid patches) comes back as its table.
    """
    k = len(rects)
    groups = policy.candidates_level(terrain, level, rects)
    if len(groups) == 1 and len(groups[0][0]) == 1:
        # The common case: one strategy for the whole level.
        name = groups[0][0][0]
        return patch_class(terrain, name).build_level_table(terrain, rects, max_points, epsilon)
    # Candidate names per node, strategies in the order the nodes first name them.
    wanted: list[tuple[str, ...]] = [()] * k
    for names, idx in groups:
        for i in idx.tolist():
            wanted[i] = names
    order = sorted(groups, key=lambda g: int(g[1].min()) if len(g[1]) else k)
    built: list[list[GeometryPatch]] = [[] for _ in range(k)]
    refused: dict[str, UnsupportedStrategyError] = {}
    # One batch per strategy so every kernel sees the whole level at once.
    for name in dict.fromkeys(n for names, _ in order for n in names):
        idx = np.sort(np.concatenate([i for names, i in groups if name in names]))
        try:
            cls = patch_class(terrain, name)
            patches = cls.build_level(terrain, rects[idx], max_points, epsilon)
        except UnsupportedStrategyError as exc:
            # A strategy that cannot build this data type drops out of multi-candidate choices.
            refused[name] = exc
            continue
        for i, p in zip(idx.tolist(), patches, strict=True):
            built[i].append(p)
    out: list[GeometryPatch] = []
    for names, options in zip(wanted, built, strict=True):
        if not options:
            if len(names) == 1:
                raise refused[names[0]]
            raise UnsupportedStrategyError(
                f"No approximation strategy can build a {type(terrain).__name__} "
                f"(tried {', '.join(names)}); convert the data to a regular grid."
            )
        out.append(options[0] if len(options) == 1 else policy.choose(options, epsilon))
    return out


def build_levels(
    terrain: GeometryData,
    epsilon: float,
    max_points: int,
    fanout: int,
    policy: StrategyPolicy,
    progress: ProgressCallback | None = None,
    root: Rect | None = None,
    root_level: int = 0,
) -> BuiltLevels:
    """Build the nodes level by level; ``progress(done, total)`` after each level, in data
    points of the root's rectangle covered by finished leaves (``approxtree.progress``).

    root: the rectangle of the first node (default the terrain's domain) and root_level its
    level, so that a subtree of a larger tree can be built on its own (a block of a blocked
    build, on the window of its rectangle); ``levels`` then count from root_level.

    Every level is a set of arrays (rects, parents); its patches are built per strategy, its
    children cut in one array pass (``subdivide_level``): Python runs per level, not per node.
    """
    validate_parameters(epsilon, max_points, fanout)
    t0 = time.perf_counter()
    # Progress: the points (area share of the root's points) covered by finished leaves,
    # reported once a level is done; the last report is exactly the total.
    report = progress or no_progress
    root = terrain.domain if root is None else root
    domain_area = root.area or 1.0
    share = min(1.0, root.area / (terrain.domain.area or 1.0))
    share = share if math.isfinite(share) else 1.0
    total = max(1, round(terrain.point_count * share)) if progress else 1
    covered = 0.0
    report(0, total)
    # The frontier: rects (k, 4) of the level's nodes and their parents (−1 for the root).
    rects = np.array([root.as_tuple()], dtype=np.float64)
    parents = np.array([-1], dtype=np.int64)
    level = int(root_level)
    first = 0
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("rects", "levels", "parents", "cs", "cc")}
    patches_out: list[Sequence[GeometryPatch] | GridPatchArrays] = []
    # A whole in-memory grid's large grid patches are measured per lattice cell, which an
    # update (and a store update, the cells being saved) re-measures only near its edit.
    cells = CellCache() if root_level == 0 and _whole_grid(terrain) else None
    while len(rects):
        patches = _level_with_cells(terrain, policy, level, rects, max_points, epsilon, cells)
        if isinstance(patches, GridPatchArrays):
            errors = patches.error
        else:
            errors = np.fromiter((p.error for p in patches), dtype=np.float64, count=len(patches))
        split = np.flatnonzero(errors > epsilon)
        children, counts = subdivide_level(terrain, rects[split], fanout)
        count = np.zeros(len(rects), dtype=np.int64)
        count[split] = counts
        # Children of the level are numbered right after it, in their parents' order.
        next_first = first + len(rects)
        start = np.where(count > 0, next_first + np.cumsum(count) - count, 0)
        parts["rects"].append(rects)
        parts["levels"].append(np.full(len(rects), level, dtype=np.int64))
        parts["parents"].append(parents)
        parts["cs"].append(start)
        parts["cc"].append(count)
        patches_out.append(patches)
        leaf = count == 0
        if leaf.any():
            r = rects[leaf]
            with np.errstate(over="ignore", invalid="ignore"):
                covered += float(((r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])).sum())
        parents = np.repeat(np.arange(first, next_first, dtype=np.int64), count)
        rects = children
        first = next_first
        level += 1
        # Areas overflow to inf at huge coordinates: then the share is unknown until the end.
        share = covered / domain_area
        if not len(rects):
            done = total
        else:
            done = min(total - 1, int(total * share)) if math.isfinite(share) else 0
        report(done, total)
    out = BuiltLevels(
        rects=np.concatenate(parts["rects"]),
        patches=PatchTable(patches_out),
        levels=np.concatenate(parts["levels"]),
        parents=np.concatenate(parts["parents"]),
        child_start=np.concatenate(parts["cs"]),
        child_count=np.concatenate(parts["cc"]),
    )
    out.seconds = time.perf_counter() - t0
    out.cells = cells if cells is not None and cells.entries else None
    return out


def _whole_grid(terrain: GeometryData) -> bool:
    """Whether the terrain is a plain Grid held in memory whole (the one an update edits)."""
    return type(terrain) is Grid and not terrain.is_windowed and terrain.index_offset == (0, 0)


def _level_with_cells(
    terrain: GeometryData,
    policy: StrategyPolicy,
    level: int,
    rects: np.ndarray,
    max_points: int,
    epsilon: float,
    cells: CellCache | None,
) -> Sequence[GeometryPatch] | GridPatchArrays:
    """``_build_level``, the large grid patches measured per cell into ``cells`` (the same
    figures, bit for bit): a level all of whose nodes are such patches of at least
    ``update_cells.BUILD_POINTS`` points (smaller ones cost more per cell than whole)."""
    if cells is not None:
        grid = cast(Grid, terrain)
        ranges = grid.index_ranges(rects)
        points = (ranges[:, 1] - ranges[:, 0] + 1) * (ranges[:, 3] - ranges[:, 2] + 1)
        wide = len(points) > 0 and points.min() >= update_cells.BUILD_POINTS
        if wide and cells.eligible(grid, policy, level, rects, max_points).all():
            return cells.build(grid, rects, max_points)
    return _build_level(terrain, policy, level, rects, max_points, epsilon)
