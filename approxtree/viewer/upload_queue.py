"""UploadQueue: bounded uploads per frame, drawing resident ancestors while children upload.

A fast camera move can ask for hundreds of new patch meshes in one frame; building and
uploading them all at once stalls the window. The queue is the Engine's selection filter
(``engine.set_selection_filter(queue)``). For each frame:

1. the wanted cut is the Engine's selection (α, γ within the thresholds);
2. wanted meshes missing from the GPU cache, and their missing ancestors, are uploaded,
   coarsest level first, until ``max_uploads`` meshes (or ``budget_ms`` milliseconds, after
   at least one) were uploaded; the root is always uploaded first, so every node has a
   drawable ancestor, and the cut refines level by level while the queue drains;
3. every wanted node still missing is replaced by its nearest resident ancestor, and any node
   below a drawn ancestor is dropped (the ancestor covers its rectangle), so the drawn cut
   still partitions the visible domain — coarser, never with holes or overlaps;
4. α and γ of the drawn cut are recomputed, so the frame's max_alpha tells the truth.

The queue is rebuilt from the wanted cut every frame: requests of views already left are
forgotten, not uploaded late.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from approxtree.render.frame_state import FrameState
from approxtree.render.selector import Selection
from approxtree.render.visual_error import visual_errors


def nearest_resident(nodes: np.ndarray, parents: np.ndarray, is_resident) -> np.ndarray:
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
    wanted: np.ndarray, parents: np.ndarray, levels: np.ndarray, is_resident
) -> np.ndarray:
    """(m,) int64 node ids to upload, coarsest level first: the missing ``wanted`` nodes and
    their missing ancestors below the nearest resident one. Uploading ancestors first lets the
    drawn cut refine level by level while a large request is still in the queue."""
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
    return nodes[np.argsort(levels[nodes], kind="stable")]


class UploadQueue:
    """Selection filter bounding mesh uploads per frame (see the module docstring).

    engine: the Engine (its ``tree``, ``texels``, ``resident`` and ``upload``).
    max_uploads: meshes uploaded per frame at most (0: no limit). budget_ms: stop uploading
    after this many milliseconds in a frame (None: no time limit).
    Figures of the last frame: ``uploads``, ``pending`` (wanted, still missing),
    ``fallbacks`` (drawn ancestors standing in), ``upload_ms``.
    """

    def __init__(self, engine: Any, max_uploads: int = 32, budget_ms: float | None = None) -> None:
        if max_uploads < 0:
            raise ValueError(f"max_uploads must be >= 0, got {max_uploads}")
        self.engine = engine
        self.max_uploads = int(max_uploads)
        self.budget_ms = budget_ms
        self.uploads = 0
        self.pending = 0
        self.fallbacks = 0
        self.upload_ms = 0.0

    def figures(self) -> dict[str, Any]:
        """The last frame's queue figures (for the stats lines and the overlay)."""
        return {
            "uploads": self.uploads,
            "pending": self.pending,
            "fallbacks": self.fallbacks,
            "upload_queue_ms": round(self.upload_ms, 3),
        }

    def __call__(self, selection: Selection, frame: FrameState) -> Selection:
        engine = self.engine
        tree = engine.tree
        wanted = np.asarray(selection.nodes, dtype=np.int64)
        # 2. Upload the root and then the missing wanted meshes, coarsest first.
        t0 = time.perf_counter()
        uploads = int(engine.upload(0)) if len(wanted) else 0
        order = upload_order(wanted, tree.parents, tree.levels, engine.resident)
        for node in order:
            if self.max_uploads and uploads >= self.max_uploads:
                break
            elapsed = (time.perf_counter() - t0) * 1e3
            if self.budget_ms is not None and uploads > 0 and elapsed >= self.budget_ms:
                break
            uploads += int(engine.upload(int(node)))
        self.upload_ms = (time.perf_counter() - t0) * 1e3
        self.uploads = uploads
        # 3. Nearest resident ancestors stand in for what is still missing.
        stand_in = nearest_resident(wanted, tree.parents, engine.resident)
        self.pending = int(np.count_nonzero(stand_in != wanted))
        drawn = drop_covered(stand_in[stand_in >= 0], tree.parents)
        self.fallbacks = int(np.count_nonzero(~np.isin(drawn, wanted)))
        if self.pending == 0:
            return selection
        # 4. The drawn cut's own visual errors.
        alphas, gammas = visual_errors(
            tree.bboxes[drawn], tree.errors[drawn], engine.texels[drawn], frame
        )
        stats = dict(selection.stats)
        stats.update(
            selected=len(drawn),
            max_alpha=float(alphas.max()) if len(drawn) else 0.0,
            max_gamma=float(gammas.max()) if len(drawn) else 0.0,
        )
        return replace(selection, nodes=drawn, alphas=alphas, gammas=gammas, stats=stats)
