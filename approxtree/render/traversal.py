"""Traversal: the cut of a frame, what to load for it, and what to draw meanwhile (no GL).

The traversal is the second of the renderer's three roles (DESIGN.md, "Renderer roles"). It is
pure: from a FrameState, a Cut and the tree's flat arrays it decides, and the caller (the
Engine) carries the decisions out with the provider and the renderer.

1. The wanted cut: the tile source's selection for the frame's ``Cut`` (render/source.py): the
   selector's traversal by alpha and gamma, a triangle budget, or the full-resolution chunks.
2. Wanted nodes missing from the GPU, and their missing ancestors, coarsest level first and
   within a level the largest screen-space error first (``upload_order``, the priority of
   CesiumJS: what is most visible, coarsest needed first): those whose payload is in the CPU
   cache are uploaded this frame (up to ``max_uploads`` of ``Paging``), the others are
   requested from the provider in that order — a request replaces the previous frame's, so
   views already left are never loaded late. After them, at a lower priority (``prefetch``):
   the cuts of the views the camera is predicted to reach (render/prefetch.py, a fly-to
   path), then the siblings of wanted nodes (the view's edges, a step aside).
3. Every wanted node not yet drawable is replaced by its nearest drawable ancestor and nodes
   under a drawn ancestor are dropped (``nearest_resident``, ``drop_covered``): the drawn cut
   is a crack-free partition of the wanted cut's area — coarser, never with holes or overlaps.
   ``Plan.stand_ins`` counts the ancestors drawn in place of wanted nodes.
4. α and γ of the drawn cut are recomputed, so the frame's max_alpha tells the truth.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.render.frame_state import FrameState
from approxtree.render.selector import Selection
from approxtree.render.visual_error import visual_errors

#: is_resident(ids (k,) int64) -> (k,) bool
Residency = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Paging:
    """How a frame waits for the store (step 2 above).

    wait: draw the settled cut, loading every payload it needs (a single image). False: an
    interactive frame that never waits for the store except for the root: the nodes not
    loaded yet are requested in the background and their nearest resident ancestors drawn
    meanwhile (stats "stand_ins", "pending"). max_uploads: meshes such a frame uploads at
    most (None: every one in the CPU cache); upload_ms: its upload budget in milliseconds,
    counted after the first upload (None: no limit).

    Prefetch (interactive frames, render/prefetch.py): lookahead: also request, at a lower
    priority, the cut of the camera extrapolated this many frames ahead from its recent
    motion (0: off); path: cameras the host knows the view will pass (a fly-to path), their
    cuts requested after the current frame's; siblings: request the siblings of wanted nodes
    last. frame_margin_ms: let the upload budget follow the frame time — uploads may spend
    this margin over the recent median frame time without them, plus what the last frame
    left of that (never less than the margin, at least one upload); None: only
    ``upload_ms``.
    """

    wait: bool = True
    max_uploads: int | None = None
    upload_ms: float | None = None
    lookahead: int = 4
    path: tuple = ()
    siblings: bool = True
    frame_margin_ms: float | None = None

    def __post_init__(self) -> None:
        n = self.max_uploads
        if n is not None and (isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0):
            raise InvalidParameterError(f"max_uploads must be an int >= 0 or None, got {n!r}.")
        ms = self.upload_ms
        if ms is not None and not (isinstance(ms, int | float) and not math.isnan(ms)):
            raise InvalidParameterError(f"upload_ms must be a number or None, got {ms!r}.")
        n = self.lookahead
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
            raise InvalidParameterError(f"lookahead must be an int >= 0, got {n!r}.")
        ms = self.frame_margin_ms
        if ms is not None and not (isinstance(ms, int | float) and math.isfinite(ms) and ms >= 0):
            raise InvalidParameterError(f"frame_margin_ms must be a number >= 0, got {ms!r}.")
        object.__setattr__(self, "wait", bool(self.wait))
        object.__setattr__(self, "siblings", bool(self.siblings))
        object.__setattr__(self, "path", tuple(self.path))


def nearest_resident(nodes: np.ndarray, parents: np.ndarray, is_resident: Residency) -> np.ndarray:
    """(k,) int64: each of ``nodes`` (k,), or its nearest ancestor for which
    ``is_resident(ids) -> bool array`` holds; −1 when none holds up to the root."""
    out = np.asarray(nodes, dtype=np.int64).copy()
    todo = ~is_resident(out) if len(out) else np.zeros(0, dtype=bool)
    # One step up the tree per round, for all missing nodes at once.
    while todo.any():
        idx = np.flatnonzero(todo)
        up = parents[out[idx]]
        top = up < 0
        out[idx[top]] = -1
        todo[idx[top]] = False
        idx, up = idx[~top], up[~top]
        out[idx] = up
        todo[idx] = ~is_resident(up)
    return out


def drop_covered(nodes: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """``nodes`` (k,) without duplicates and without nodes that have an ancestor among them,
    in first-seen order."""
    if len(nodes) == 0:
        return np.asarray(nodes, dtype=np.int64)
    _, first = np.unique(nodes, return_index=True)
    nodes = np.asarray(nodes, dtype=np.int64)[np.sort(first)]
    member = np.zeros(len(parents), dtype=bool)
    member[nodes] = True
    covered = np.zeros(len(nodes), dtype=bool)
    anc = parents[nodes]
    while (anc >= 0).any():
        live = anc >= 0
        covered[live] |= member[anc[live]]
        anc[live] = parents[anc[live]]
    return nodes[~covered]


def upload_order(
    wanted: np.ndarray,
    parents: np.ndarray,
    levels: np.ndarray,
    is_resident: Residency,
    priority: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """(m,) int64 node ids to upload, coarsest level first: the missing ``wanted`` nodes and
    their missing ancestors below the nearest resident one. Uploading ancestors first lets the
    drawn cut refine level by level while a large request is still in the queue.
    priority(ids (m,)) -> (m,) float: within a level, the larger first (None: by id)."""
    wanted = np.asarray(wanted, dtype=np.int64)
    if len(wanted) == 0:
        return wanted
    parts = [wanted[~is_resident(wanted)]]
    cur = parts[0]
    while len(cur):
        up = np.unique(parents[cur])
        up = up[up >= 0]
        cur = up[~is_resident(up)] if len(up) else up
        parts.append(cur)
    nodes = np.unique(np.concatenate(parts))
    if priority is None or len(nodes) < 2:
        return nodes[np.argsort(levels[nodes], kind="stable")]
    return nodes[np.lexsort((-priority(nodes), levels[nodes]))]


def sibling_nodes(nodes: np.ndarray, parents: np.ndarray, child_start, child_count) -> np.ndarray:
    """(s,) int64 the children of the parents of ``nodes`` (k,) that are not among them."""
    up = np.unique(parents[np.asarray(nodes, dtype=np.int64)])
    up = up[up >= 0]
    if len(up) == 0:
        return np.zeros(0, dtype=np.int64)
    counts = np.asarray(child_count, dtype=np.int64)[up]
    starts = np.repeat(np.asarray(child_start, dtype=np.int64)[up], counts)
    offsets = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    kids = starts + offsets
    return kids[~np.isin(kids, nodes)]


def prefetch_order(
    ahead: Sequence[np.ndarray],
    siblings: np.ndarray,
    exclude: np.ndarray,
    parents: np.ndarray,
    levels: np.ndarray,
    is_resident: Residency,
) -> np.ndarray:
    """(p,) int64 nodes to load at a lower priority than a frame's own: the missing nodes of
    each predicted cut in ``ahead`` (with their missing ancestors, coarsest first), in order,
    then the missing ``siblings``; none of ``exclude`` and no node twice."""
    parts = [upload_order(nodes, parents, levels, is_resident) for nodes in ahead]
    sib = np.asarray(siblings, dtype=np.int64)
    sib = sib[~is_resident(sib)] if len(sib) else sib
    parts.append(sib[np.argsort(levels[sib], kind="stable")])
    order = np.concatenate([np.zeros(0, dtype=np.int64), *parts])
    _, first = np.unique(order, return_index=True)
    order = order[np.sort(first)]
    return order[~np.isin(order, exclude)]


@dataclass(frozen=True)
class Plan:
    """What one frame does.

    drawn: the Selection drawn (the wanted cut where drawable, nearest drawable ancestors
    elsewhere). upload: (u,) int64 nodes to upload now (payload in the CPU cache), coarsest
    first. request: (r,) int64 nodes to ask the provider for, coarsest first. pending: wanted
    nodes not drawn as themselves; stand_ins: drawn nodes that are not wanted ones. prefetch:
    (p,) int64 nodes not on the GPU to load after ``request`` (predicted views, siblings).
    """

    drawn: Selection
    upload: np.ndarray
    request: np.ndarray
    pending: int
    stand_ins: int
    prefetch: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def plan_frame(
    wanted: Selection,
    frame: FrameState,
    tree,
    texels: np.ndarray,
    on_gpu: Residency,
    on_cpu: Residency,
    max_uploads: int | None = None,
    ahead: Sequence[np.ndarray] = (),
    siblings: bool = False,
) -> Plan:
    """The Plan of a frame whose wanted cut is ``wanted`` (see the module docstring).

    tree: its ``parents``, ``levels``, ``bboxes``, ``errors`` (and for ``siblings`` its
    ``child_start``, ``child_count``) arrays are used. texels: (n, 2) texel sizes of the nodes
    (γ). on_gpu / on_cpu: residency of node payloads on the GPU / in the CPU cache.
    max_uploads: uploads this frame at most (None: every CPU-resident one). ahead: (a_i,)
    wanted nodes of predicted views, most likely first; siblings: prefetch the siblings of
    the wanted nodes too (Plan.prefetch).
    """
    parents = tree.parents
    nodes = np.asarray(wanted.nodes, dtype=np.int64)

    def visibility(ids: np.ndarray) -> np.ndarray:
        # The screen-space error of each node in this frame: the largest is loaded first.
        return visual_errors(tree.bboxes[ids], tree.errors[ids], texels[ids], frame)[0]

    order = upload_order(nodes, parents, tree.levels, on_gpu, visibility)
    prefetch = np.zeros(0, dtype=np.int64)
    if len(ahead) or siblings:
        sib = (
            sibling_nodes(nodes, parents, tree.child_start, tree.child_count)
            if siblings
            else np.zeros(0, dtype=np.int64)
        )
        prefetch = prefetch_order(ahead, sib, order, parents, tree.levels, on_gpu)
    cpu = on_cpu(order) if len(order) else np.zeros(0, dtype=bool)
    upload = order[cpu]
    if max_uploads is not None:
        upload = upload[: max(0, int(max_uploads))]
    request = order[~cpu]
    uploading = np.zeros(len(parents), dtype=bool)
    uploading[upload] = True

    def drawable(ids: np.ndarray) -> np.ndarray:
        return on_gpu(ids) | uploading[ids]

    stand_in = nearest_resident(nodes, parents, drawable)
    pending = int(np.count_nonzero(stand_in != nodes))
    drawn = drop_covered(stand_in[stand_in >= 0], parents)
    stand_ins = int(np.count_nonzero(~np.isin(drawn, nodes)))
    if pending == 0:
        return Plan(wanted, upload, request, 0, 0, prefetch)
    # The drawn cut's own visual errors.
    alphas, gammas = visual_errors(tree.bboxes[drawn], tree.errors[drawn], texels[drawn], frame)
    stats = dict(wanted.stats)
    stats.update(
        selected=len(drawn),
        max_alpha=float(alphas.max()) if len(drawn) else 0.0,
        max_gamma=float(gammas.max()) if len(drawn) else 0.0,
    )
    selection = replace(wanted, nodes=drawn, alphas=alphas, gammas=gammas, stats=stats)
    return Plan(selection, upload, request, pending, stand_ins, prefetch)
