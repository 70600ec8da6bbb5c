"""Top-down construction of an approximation tree A(s,d)(T), one level at a time.

Each level's nodes are built in one batch per strategy (so the numba kernels see many nodes at
once); a node is split while ε_T(N) > ε and its domain can still be cut. Nodes are numbered in
breadth-first order, so the children of a node are contiguous.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from approxtree.errors import InvalidParameterError, UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.rect import Rect
from approxtree.patches import STRATEGIES
from approxtree.patches.base import GeometryPatch
from approxtree.progress import ProgressCallback, no_progress
from approxtree.tree.policy import StrategyPolicy
from approxtree.tree.subdivision import FANOUTS, subdivide


@dataclass
class BuiltLevels:
    """The flat arrays of a freshly built tree (see ApproximationTree for their meaning)."""

    rects: list[Rect] = field(default_factory=list)
    patches: list[GeometryPatch] = field(default_factory=list)
    levels: list[int] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    child_start: list[int] = field(default_factory=list)
    child_count: list[int] = field(default_factory=list)
    seconds: float = 0.0


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
    frontier: list[tuple[Rect, int]],
    max_points: int,
    epsilon: float,
) -> list[GeometryPatch]:
    """The patch of every node of one level, as the policy chooses among its candidates."""
    wanted = [policy.candidates(terrain, level, rect) for rect, _ in frontier]
    built: list[list[GeometryPatch]] = [[] for _ in frontier]
    refused: dict[str, UnsupportedStrategyError] = {}
    # One batch per strategy so every kernel sees the whole level at once.
    for name in dict.fromkeys(n for names in wanted for n in names):
        idx = [i for i, names in enumerate(wanted) if name in names]
        rects = [frontier[i][0] for i in idx]
        try:
            patches = STRATEGIES[name].build_many(terrain, rects, max_points, epsilon)
        except UnsupportedStrategyError as exc:
            # A strategy that cannot build this data type drops out of multi-candidate choices.
            refused[name] = exc
            continue
        for i, p in zip(idx, patches, strict=True):
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
        out.append(policy.choose(options, epsilon))
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
    """
    validate_parameters(epsilon, max_points, fanout)
    t0 = time.perf_counter()
    out = BuiltLevels()
    # Progress: the points (area share of the root's points) covered by finished leaves,
    # reported once a level is done; the last report is exactly the total.
    report = progress or no_progress
    root = terrain.domain if root is None else root
    domain_area = root.area or 1.0
    share = min(1.0, root.area / (terrain.domain.area or 1.0))
    total = max(1, round(terrain.point_count * share)) if progress else 1
    covered = 0.0
    report(0, total)
    # Each entry of the frontier: (rect, parent index); the root has no parent.
    frontier: list[tuple[Rect, int]] = [(root, -1)]
    level = int(root_level)
    while frontier:
        patches = _build_level(terrain, policy, level, frontier, max_points, epsilon)
        first = len(out.rects)
        next_frontier: list[tuple[Rect, int]] = []
        next_first = first + len(frontier)
        for i, ((rect, parent), patch) in enumerate(zip(frontier, patches, strict=True)):  # type: ignore[assignment]
            node = first + i
            out.rects.append(rect)
            out.patches.append(patch)
            out.levels.append(level)
            out.parents.append(parent)
            children = subdivide(terrain, rect, fanout) if patch.error > epsilon else []
            out.child_start.append(next_first + len(next_frontier) if children else 0)
            out.child_count.append(len(children))
            next_frontier.extend((c, node) for c in children)
            if not children:
                covered += rect.area
        frontier = next_frontier
        level += 1
        report(total if not frontier else min(total - 1, int(total * covered / domain_area)), total)
    out.seconds = time.perf_counter() - t0
    return out
