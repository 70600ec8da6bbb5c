"""Selection under a triangle budget: the cut with the smallest largest α that fits.

Pure and GL-free, like ``selector``: (tree, FrameState, max_triangles, node triangle counts)
→ Selection. Instead of refining while α_N > alpha, it finds the smallest α* such that some cut
of the visible tree has every selected node's α_N <= α* and at most max_triangles triangles,
and draws that cut (the one with the fewest triangles). γ is reported, not constrained.

1. Traverse every node whose box meets the frustum; α_N, γ_N as in threshold mode (α_N bounds
   the node's screen error anywhere in the view, see visual_error.py). Culled
   nodes cost 0 triangles and are skipped with their subtree.
2. For a candidate a, cost(a) = the fewest triangles of a cut whose selected nodes all have
   α_N <= a, by one bottom-up pass: cost(N) = sum over children when N has children, replaced
   by tri(N) when α_N <= a and that is smaller; a leaf with α_N > a is infeasible (+inf).
3. cost(a) never grows with a (every cut allowed at a is allowed at any a' > a), so α* is found
   by bisection over the sorted distinct α_N of the visible nodes.

Monotonicity: a budget N' >= N admits every a that N admits, so α*(N') <= α*(N): the α reached
never grows when the budget grows. And a threshold selection with T triangles and largest α m
is one of the cuts tried for budget T, so α*(T) <= m.

Triangle counts are what the engine draws per node: the patch's triangles plus its skirt walls
(two per border edge on the node's rectangle) when skirts are on (``node_triangles``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.errors import InvalidParameterError
from approxtree.kernels._jit import readonly
from approxtree.render.frame_state import FrameState
from approxtree.render.frustum import box_in_frustum
from approxtree.render.selector import Selection, SelectionResult, _stats, eye_below_ground
from approxtree.render.skirts import patches_reach_rect, skirt_edge_count
from approxtree.render.visual_error import (
    box_tuple,
    frame_tuples,
    node_visual_errors,
    texel_sizes,
)


def node_triangles(tree, skirts: bool = True) -> np.ndarray:
    """(n,) int64 triangles the engine draws for each node (patch, plus 2 per skirted edge).

    Loads every patch of a lazily loaded tree.
    """
    out = np.empty(len(tree), dtype=np.int64)
    node_borders = patches_reach_rect(tree.terrain)
    for i in range(len(tree)):
        patch = tree.patch(i)
        tris = patch.triangles
        walls = 0
        if skirts and len(tris):
            rect = patch.rect.as_tuple() if node_borders else None
            walls = 2 * skirt_edge_count(patch.vertices, tris, rect)
        out[i] = len(tris) + walls
    return out


def select_budget(
    tree,
    frame: FrameState,
    max_triangles: int,
    triangles: np.ndarray,
    texels: np.ndarray | None = None,
) -> Selection:
    """The cut of smallest largest α within ``max_triangles`` (see the module docstring).

    triangles: (n,) int64 per-node counts (``node_triangles``). Selection.stats gains
    "alpha_reached" (= max_alpha) and "budget_triangles" (the cut's count).
    Raises InvalidParameterError when even the coarsest cut of this view needs more.
    """
    if isinstance(max_triangles, bool) or not isinstance(max_triangles, int | np.integer):
        raise InvalidParameterError(f"max_triangles must be an int, got {max_triangles!r}.")
    if max_triangles < 1:
        raise InvalidParameterError(f"max_triangles must be >= 1, got {max_triangles}.")
    if texels is None:
        texels = texel_sizes(tree)
    empty_i = np.empty(0, dtype=np.int64)
    empty_f = np.empty(0)
    if eye_below_ground(tree, frame):
        stats = _stats(0, 0, [], [])
        stats.update(alpha_reached=0.0, budget_triangles=0)
        return Selection(empty_i, empty_f, empty_f, empty_i, np.empty(0, np.uint8), True, stats)
    vw, vh = frame.viewport
    # Read-only views: one compiled signature for built and memory-mapped trees.
    ids, first, alphas, gammas, visible = _visible_tree(
        readonly(tree.bboxes, np.float64),
        readonly(tree.errors, np.float64),
        readonly(texels, np.float64),
        readonly(tree.child_start, np.int64),
        readonly(tree.child_count, np.int64),
        readonly(frame.planes, np.float64),
        readonly(frame.eye, np.float64),
        readonly(frame.world_to_clip, np.float64),
        float(vw),
        float(vh),
        frame.lens,
    )
    counts = np.asarray(triangles, dtype=np.int64)[ids]
    nchild = np.asarray(tree.child_count, dtype=np.int64)[ids]
    candidates = np.unique(alphas[visible])
    if len(candidates) == 0:
        candidates = np.zeros(1)
    # Bisection over the candidates: cost is non-increasing in a.
    cost_top = _cut_cost(first, nchild, counts, alphas, visible, candidates[-1])
    if cost_top > max_triangles:
        raise InvalidParameterError(
            f"max_triangles={max_triangles} is below the {cost_top} triangles that the "
            "coarsest cut of this view needs; raise the budget."
        )
    lo, hi = -1, len(candidates) - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _cut_cost(first, nchild, counts, alphas, visible, candidates[mid]) <= max_triangles:
            hi = mid
        else:
            lo = mid
    a_star = float(candidates[hi])
    results = _cut(first, nchild, counts, alphas, visible, a_star)
    reached = results < 255
    visited = ids[reached]
    res = results[reached]
    chosen = res == SelectionResult.SELECTED
    sel_a = alphas[reached][chosen]
    sel_g = gammas[reached][chosen]
    stats = _stats(len(visited), int(np.count_nonzero(res == 0)), sel_a, sel_g)
    stats.update(
        alpha_reached=stats["max_alpha"],
        budget_triangles=int(counts[reached][chosen].sum()),
    )
    return Selection(visited[chosen], sel_a, sel_g, visited, res, False, stats)


@njit(cache=True)
def _visible_tree(bboxes, errors, texels, child_start, child_count, planes, eye, m, vw, vh, lens):
    """Breadth-first over every node whose parent is visible.

    Returns (ids (v,), first (v,) position of the first child in ids (−1: none traversed),
    α (v,), γ (v,), visible (v,) bool). Children of a node are contiguous in ids.
    """
    # The frame as tuples: per-node calls then pass no arrays (see node_visual_errors).
    mt, et, lt = frame_tuples(m, eye, lens)
    cap = min(bboxes.shape[0], 4096)
    ids = np.empty(cap, dtype=np.int64)
    first = np.full(cap, -1, dtype=np.int64)
    a_out = np.zeros(cap)
    g_out = np.zeros(cap)
    vis = np.zeros(cap, dtype=np.bool_)
    ids[0] = 0
    head, tail = 0, 1
    while head < tail:
        i = ids[head]
        if box_in_frustum(bboxes[i], planes):
            vis[head] = True
            a, g = node_visual_errors(
                box_tuple(bboxes, i), errors[i], texels[i, 0], texels[i, 1], et, mt, vw, vh, lt
            )
            a_out[head] = a
            g_out[head] = g
            if child_count[i] > 0:
                if tail + child_count[i] > cap:
                    cap = 2 * cap + child_count[i]
                    ids = _grow(ids, cap, 0)
                    first = _grow(first, cap, -1)
                    a_out = _grow(a_out, cap, 0.0)
                    g_out = _grow(g_out, cap, 0.0)
                    vis = _grow(vis, cap, False)
                first[head] = tail
                for c in range(child_count[i]):
                    ids[tail] = child_start[i] + c
                    tail += 1
        head += 1
    return ids[:tail], first[:tail], a_out[:tail], g_out[:tail], vis[:tail]


@njit(cache=True)
def _grow(a, cap, fill):
    out = np.full(cap, fill, dtype=a.dtype)
    # A loop, not out[:n] = a: slice assignment compiles numba's shape-error formatting.
    for k in range(a.shape[0]):
        out[k] = a[k]
    return out


@njit(cache=True)
def _costs(first, nchild, counts, alphas, visible, a):
    """cost (v,) of the best cut below every traversed node for threshold a (inf: none)."""
    v = first.shape[0]
    cost = np.zeros(v)
    # Children come after their parent in breadth-first order: fill bottom-up.
    for p in range(v - 1, -1, -1):
        if not visible[p]:
            cost[p] = 0.0
            continue
        own = counts[p] if alphas[p] <= a else np.inf
        if first[p] < 0:
            cost[p] = own
            continue
        sub = 0.0
        for c in range(first[p], first[p] + nchild[p]):
            sub += cost[c]
        cost[p] = min(own, sub)
    return cost


@njit(cache=True)
def _cut_cost(first, nchild, counts, alphas, visible, a) -> float:
    return _costs(first, nchild, counts, alphas, visible, a)[0]


@njit(cache=True)
def _cut(first, nchild, counts, alphas, visible, a):
    """results (v,) uint8 of the cheapest cut for threshold a (255: not reached)."""
    cost = _costs(first, nchild, counts, alphas, visible, a)
    v = first.shape[0]
    res = np.full(v, 255, dtype=np.uint8)
    res[0] = 1
    for p in range(v):
        if res[p] == 255:
            continue
        if not visible[p]:
            res[p] = 0
            continue
        # Draw N itself when allowed and no more expensive than its best cut below.
        if alphas[p] <= a and (first[p] < 0 or counts[p] <= cost[p]):
            res[p] = 2
            continue
        res[p] = 1
        for c in range(first[p], first[p] + nchild[p]):
            res[c] = 1
    return res
