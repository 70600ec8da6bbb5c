"""Box–frustum test: which axis-parallel boxes may intersect the view frustum.

``box_in_frustum`` tests one box (compiled, used inside the selection kernel);
``boxes_in_frustum`` runs it over many.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels._jit import readonly


@njit(cache=True)
def box_in_frustum(box: np.ndarray, planes: np.ndarray) -> bool:
    """False when the box (6,) lies entirely outside one of the planes (6, 4).

    box: (xmin, ymin, zmin, xmax, ymax, zmax); a NaN z (node without data) counts as outside.
    planes: inside where a·x + b·y + c·z + d >= 0. Conservative (the "positive vertex" test):
    a box near a frustum corner may be reported inside although it is not, never the reverse.
    """
    if not (np.isfinite(box[2]) and np.isfinite(box[5])):
        return False
    for k in range(planes.shape[0]):
        a, b, c, d = planes[k, 0], planes[k, 1], planes[k, 2], planes[k, 3]
        # The box corner farthest along the plane's normal.
        x = box[3] if a >= 0.0 else box[0]
        y = box[4] if b >= 0.0 else box[1]
        z = box[5] if c >= 0.0 else box[2]
        if a * x + b * y + c * z + d < 0.0:
            return False
    return True


@njit(cache=True)
def _boxes_in_frustum(bboxes: np.ndarray, planes: np.ndarray) -> np.ndarray:
    out = np.empty(bboxes.shape[0], dtype=np.bool_)
    for i in range(bboxes.shape[0]):
        out[i] = box_in_frustum(bboxes[i], planes)
    return out


def boxes_in_frustum(bboxes: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """(n,) bool: ``box_in_frustum`` for each of bboxes (n, 6) against planes (6, 4)."""
    # Read-only views: one compiled signature for built and memory-mapped trees.
    return _boxes_in_frustum(readonly(bboxes, np.float64), readonly(planes, np.float64))
