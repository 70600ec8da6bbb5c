"""Selection: which nodes of an approximation tree a frame draws (section 4.2 of the paper).

Pure and GL-free: (tree, FrameState, alpha, gamma) → Selection. The traversal is breadth-first
over the tree's flat arrays, compiled with numba (one queue, no recursion, no Python per
node), so a view of a 100,000-node tree takes well under the 5 ms budget.

Decision for each node N of the frontier (starting with the root):

1. B_N misses the view frustum (or N holds no data)   → CULLED: N and its subtree are skipped.
2. N has children and (α_N > alpha or γ_N > gamma)     → REFINED: its children join the next
                                                          frontier; γ counts only where a
                                                          descendant's texel is finer.
3. otherwise (a leaf, or errors within the thresholds)  → SELECTED: T_N is drawn.

α_N bounds the on-screen length of every error segment of N anywhere in the view, image edges
included (visual_error.py), so every drawn inner node is within alpha pixels of the terrain.

γ_N is the texel of the texture patch N is drawn with (core paper, 3.3 and 4.1). Refining N
gets finer texels only when some descendant's patch has them; where none has (the pyramid's
finest level reached, or one texture shading every node, as the normal map of a grid within
its side does; a larger grid's nodes have normal patches, render/normal_map.py),
the texels have run out and refining would add geometry, not texels: γ_N > gamma refines N
only where ``finer_below`` says a descendant's texel area is smaller than N's. γ_N is reported
as it is either way (Selection.gammas, stats "max_gamma").

Before the traversal: an eye below the terrain surface (z < h_T(x, y)) sees nothing, and the
selection is empty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
from numba import njit

from approxtree.kernels._jit import readonly
from approxtree.render.cut import Cut
from approxtree.render.frame_state import FrameState
from approxtree.render.frustum import box_in_frustum
from approxtree.render.visual_error import (
    box_tuple,
    frame_tuples,
    node_visual_errors,
    texel_sizes,
)


class SelectionResult(IntEnum):
    """What the traversal decided for a visited node."""

    #: B_N outside the frustum (or no data): skipped with its subtree.
    CULLED = 0
    #: Visual errors over the thresholds: replaced by its children.
    REFINED = 1
    #: Drawn.
    SELECTED = 2


@dataclass(frozen=True)
class Selection:
    """The cut of one frame.

    nodes: (k,) int64 selected node ids, in traversal order. alphas, gammas: (k,) their α_N,
    γ_N. visited: (v,) int64 every node the traversal tested; results: (v,) uint8
    SelectionResult of each. below_ground: the eye was under the terrain (empty selection).
    visited_gammas: (v,) γ of every visited node (0 when culled), used to let a node share
    the texture patch of an ancestor.
    """

    nodes: np.ndarray
    alphas: np.ndarray
    gammas: np.ndarray
    visited: np.ndarray
    results: np.ndarray
    below_ground: bool = False
    stats: dict[str, Any] = field(default_factory=dict)
    visited_gammas: np.ndarray | None = None

    def result_of(self, node: int) -> SelectionResult | None:
        """The decision for ``node``, None when the traversal never reached it."""
        hit = np.flatnonzero(self.visited == node)
        return SelectionResult(int(self.results[hit[0]])) if len(hit) else None


def eye_below_ground(tree, frame: FrameState) -> bool:
    """True when the eye is above the domain and below h_T there."""
    x, y, z = frame.eye
    # Above the highest box or outside the domain nobody is underground: skip h_T (its
    # kernel runs on a thread pool whose wake-up alone can cost milliseconds).
    box = tree.bboxes[0]
    if not (box[0] <= x <= box[3] and box[1] <= y <= box[4] and z < box[5]):
        return False
    h = float(np.asarray(tree.terrain.height_at(np.array([x]), np.array([y])))[0])
    return math.isfinite(h) and z < h


def select(
    tree,
    frame: FrameState,
    alpha: float = 1.0,
    gamma: float = 2.0,
    texels: np.ndarray | None = None,
    finer: np.ndarray | None = None,
) -> Selection:
    """The nodes to draw for ``frame`` with thresholds ``alpha`` (px) and ``gamma`` (px²).

    tree: an ApproximationTree (only its flat arrays are read, and the terrain's height_at).
    texels: (n, 2) texel sizes; ``texel_sizes(tree)`` when None. finer: (n,) bool
    ``finer_below(tree, texels)`` when None (callers that draw many frames compute both once).
    """
    cut = Cut(alpha, gamma)  # the thresholds are checked where a Cut is made
    alpha, gamma = cut.alpha, cut.gamma
    if texels is None:
        texels = texel_sizes(tree)
    if finer is None:
        finer = finer_below(tree, texels)
    empty_i = np.empty(0, dtype=np.int64)
    empty_f = np.empty(0)
    if eye_below_ground(tree, frame):
        return Selection(
            empty_i, empty_f, empty_f, empty_i, np.empty(0, np.uint8), True, _stats(0, 0, [], [])
        )
    vw, vh = frame.viewport
    # Read-only views: a built tree and a memory-mapped one share one compiled signature.
    visited, results, a, g = _traverse(
        readonly(tree.bboxes, np.float64),
        readonly(tree.errors, np.float64),
        readonly(texels, np.float64),
        readonly(finer, np.bool_),
        readonly(tree.child_start, np.int64),
        readonly(tree.child_count, np.int64),
        readonly(frame.planes, np.float64),
        readonly(frame.eye, np.float64),
        readonly(frame.world_to_clip, np.float64),
        float(vw),
        float(vh),
        frame.lens,
        alpha,
        gamma,
    )
    chosen = results == SelectionResult.SELECTED
    nodes, alphas, gammas = visited[chosen], a[chosen], g[chosen]
    stats = _stats(len(visited), int(np.count_nonzero(results == 0)), alphas, gammas)
    return Selection(nodes, alphas, gammas, visited, results, False, stats, g)


@njit(cache=True)
def _traverse(
    bboxes,
    errors,
    texels,
    finer,
    child_start,
    child_count,
    planes,
    eye,
    m,
    vw,
    vh,
    lens,
    alpha,
    gamma,
):
    """Breadth-first traversal; returns (visited ids, results, α, γ) in visiting order.

    α and γ are 0 for culled nodes. The queue is the visited array itself: nodes are appended
    as their parent is refined, and read in order.
    """
    # Output arrays double when full: cost follows the nodes visited, not the tree's size.
    # The frame as tuples: per-node calls then pass no arrays (see node_visual_errors).
    mt, et, lt = frame_tuples(m, eye, lens)
    cap = min(bboxes.shape[0], 4096)
    visited = np.empty(cap, dtype=np.int64)
    results = np.empty(cap, dtype=np.uint8)
    a_out = np.empty(cap)
    g_out = np.empty(cap)
    visited[0] = 0
    head, tail = 0, 1
    while head < tail:
        i = visited[head]
        results[head] = 0
        a_out[head] = 0.0
        g_out[head] = 0.0
        # 1. Frustum test of B_N.
        if box_in_frustum(bboxes[i], planes):
            a, g = node_visual_errors(
                box_tuple(bboxes, i), errors[i], texels[i, 0], texels[i, 1], et, mt, vw, vh, lt
            )
            a_out[head] = a
            g_out[head] = g
            # 2. Refine a node with children while either visual error is over its threshold
            # (γ only where a descendant has finer texels).
            if child_count[i] > 0 and (a > alpha or (g > gamma and finer[i])):
                results[head] = 1
                if tail + child_count[i] > cap:
                    cap = 2 * cap + child_count[i]
                    visited = _grow(visited, cap)
                    results = _grow(results, cap)
                    a_out = _grow(a_out, cap)
                    g_out = _grow(g_out, cap)
                for c in range(child_count[i]):
                    visited[tail] = child_start[i] + c
                    tail += 1
            # 3. Otherwise draw it.
            else:
                results[head] = 2
        head += 1
    return visited[:tail], results[:tail], a_out[:tail], g_out[:tail]


def finer_below(tree, texels: np.ndarray) -> np.ndarray:
    """(n,) bool: whether some descendant of each node has a smaller texel area than it.

    tree: its ``parents`` and ``levels`` arrays are read; texels: (n, 2) texel sizes.
    """
    texels = np.asarray(texels, dtype=np.float64)
    area = texels[:, 0] * texels[:, 1]
    parents = np.asarray(tree.parents, dtype=np.int64)
    levels = np.asarray(tree.levels, dtype=np.int64)
    # The smallest texel area below each node, gathered level by level from the deepest.
    below = np.full(len(area), np.inf)
    for depth in range(int(levels.max(initial=0)), 0, -1):
        nodes = np.flatnonzero(levels == depth)
        np.minimum.at(below, parents[nodes], np.minimum(area[nodes], below[nodes]))
    return below < area


@njit(cache=True)
def _grow(a, cap):
    """A copy of ``a`` with room for ``cap`` items."""
    out = np.empty(cap, dtype=a.dtype)
    # A loop, not out[:n] = a: slice assignment compiles numba's shape-error formatting.
    for k in range(a.shape[0]):
        out[k] = a[k]
    return out


def _stats(visited: int, culled: int, alphas, gammas) -> dict[str, Any]:
    return {
        "nodes_visited": int(visited),
        "culled": int(culled),
        "selected": len(alphas),
        "max_alpha": float(np.max(alphas)) if len(alphas) else 0.0,
        "max_gamma": float(np.max(gammas)) if len(gammas) else 0.0,
    }
