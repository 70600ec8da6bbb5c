"""Per-node maximum error over the nodes across each side of its rectangle.

Two nodes of a tree can be drawn side by side only where their rectangles share a stretch of
a border line (the cuts are data lines, so shared coordinates are bit-identical floats). For
each node this kernel finds, over all nodes at any level whose rectangle touches one of its
sides from the outside along a stretch of positive length, the largest finite error: the worst
neighbour a cut can put beside it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels._jit import readonly


@njit(cache=True)
def _across(key_a, key_b, oa, ob, lo, hi, errors, out):
    """Nodes whose side a (at coordinate key_a) faces the opposite side b (key_b) of others.

    key_a, key_b: (n,) the coordinate of the facing sides (e.g. xmax and xmin); oa, ob: (n,)
    int64 their sort orders (argsort); lo, hi: (n,) the extent along that line (e.g. ymin,
    ymax); errors: (n,); out: (n,) raised in place to the largest finite error across, for
    both nodes of each facing pair.
    """
    n = key_a.shape[0]
    i = 0
    j = 0
    while i < n and j < n:
        ka = key_a[oa[i]]
        kb = key_b[ob[j]]
        if ka < kb:
            i += 1
        elif kb < ka:
            j += 1
        else:
            # All nodes with their side a on this line against all with side b on it.
            i1 = i
            while i1 < n and key_a[oa[i1]] == ka:
                i1 += 1
            j1 = j
            while j1 < n and key_b[ob[j1]] == ka:
                j1 += 1
            for p in range(i, i1):
                u = oa[p]
                for q in range(j, j1):
                    v = ob[q]
                    if min(hi[u], hi[v]) > max(lo[u], lo[v]):
                        if np.isfinite(errors[v]) and errors[v] > out[u]:
                            out[u] = errors[v]
                        if np.isfinite(errors[u]) and errors[u] > out[v]:
                            out[v] = errors[u]
            i = i1
            j = j1


def neighbour_max_errors(rects: np.ndarray, errors: np.ndarray) -> np.ndarray:
    """(n,) largest finite error of a node across any side of each node (0 when none).

    rects: (n, 4) float64 (xmin, ymin, xmax, ymax); errors: (n,) float64 ε_T(N), inf skipped.
    """
    # Sorting happens here in numpy, not in the kernel: numba's sort compiles for seconds on a
    # cold start. The result does not depend on the order among equal keys (a max over each
    # group of facing sides), so any correct argsort gives the same bits.
    rects = np.asarray(rects, dtype=np.float64)
    errors = readonly(errors, np.float64)
    out = np.zeros(rects.shape[0])
    # East sides against west sides (vertical lines), then north against south.
    for a, b, lo, hi in ((2, 0, 1, 3), (3, 1, 0, 2)):
        key_a, key_b = readonly(rects[:, a]), readonly(rects[:, b])
        _across(
            key_a,
            key_b,
            readonly(np.argsort(key_a), np.int64),
            readonly(np.argsort(key_b), np.int64),
            readonly(rects[:, lo]),
            readonly(rects[:, hi]),
            errors,
            out,
        )
    return out
