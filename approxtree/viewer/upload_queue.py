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

The Engine's own paging (``Engine.render(..., wait=False)``, render/traversal.py) does the same
with background loads; this queue remains for hosts that upload synchronously.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from approxtree.render.frame_state import FrameState
from approxtree.render.selector import Selection
from approxtree.render.traversal import drop_covered, nearest_resident, upload_order
from approxtree.render.visual_error import visual_errors


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
