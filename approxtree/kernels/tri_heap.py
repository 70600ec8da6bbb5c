"""An array-based binary max-heap of triangles keyed by their candidate error.

``heap[i]`` is a triangle id and ``hkey[i]`` its key, side by side so that sifting walks
contiguous memory; ``pos[t]`` is the slot of triangle t (−1 when absent), so a triangle changed
by an insertion is taken out in O(log m) without lazy tombstones. Functions return the new heap
size; the arrays must be large enough for every triangle id. They allocate nothing and are
compiled without numba's reference-counting runtime (``_nrt=False``): a call then costs no
atomic reference-count updates on its array arguments, which would outweigh a small sift.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels._jit import njit_no_nrt


# Slots and triangle ids are indexed as unsigned (np.uint64) in the sifts: numba then emits
# no negative-index wraparound per load and store.
@njit(cache=True, inline="always")
def _place(heap, hkey, pos, i, t, k) -> None:
    heap[np.uint64(i)] = t
    hkey[np.uint64(i)] = k
    pos[np.uint64(t)] = i


@njit_no_nrt()
def _sift_up(heap, hkey, pos, i, t, k) -> None:
    """Move entry (t, k) up from slot i to where it belongs."""
    while i > 0:
        parent = (i - 1) >> 1
        up = np.uint64(parent)
        if k <= hkey[up]:
            break
        _place(heap, hkey, pos, i, heap[up], hkey[up])
        i = parent
    _place(heap, hkey, pos, i, t, k)


@njit_no_nrt()
def _sift_down(heap, hkey, pos, i, t, k, size) -> None:
    """Move entry (t, k) down from slot i to where it belongs."""
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        uc = np.uint64(child)
        if child + 1 < size and hkey[uc + np.uint64(1)] > hkey[uc]:
            child += 1
            uc += np.uint64(1)
        if hkey[uc] <= k:
            break
        _place(heap, hkey, pos, i, heap[uc], hkey[uc])
        i = child
    _place(heap, hkey, pos, i, t, k)


@njit_no_nrt()
def heap_push(heap: np.ndarray, hkey: np.ndarray, pos: np.ndarray, size: int, t: int, k: float):
    """Add triangle t (not yet in the heap) with key k."""
    _sift_up(heap, hkey, pos, size, t, k)
    return size + 1


@njit_no_nrt()
def heap_remove(heap: np.ndarray, hkey: np.ndarray, pos: np.ndarray, size: int, t: int):
    """Take triangle t out of the heap if it is there."""
    # int64 like ``size``, so ``_sift_up`` compiles once (pos holds int32).
    i = np.int64(pos[np.uint64(t)])
    if i < 0:
        return size
    pos[np.uint64(t)] = -1
    last = size - 1
    if i != last:
        # The last entry fills the hole; it may belong above or below slot i.
        mt = heap[np.uint64(last)]
        mk = hkey[np.uint64(last)]
        if i > 0 and mk > hkey[np.uint64((i - 1) >> 1)]:
            _sift_up(heap, hkey, pos, i, mt, mk)
        else:
            _sift_down(heap, hkey, pos, i, mt, mk, last)
    return last


@njit_no_nrt()
def heap_update(heap: np.ndarray, hkey: np.ndarray, pos: np.ndarray, size: int, t: int, k: float):
    """Give triangle t key k: pushed when absent, else moved up or down in place (one sift)."""
    i = np.int64(pos[np.uint64(t)])
    if i < 0:
        _sift_up(heap, hkey, pos, size, t, k)
        return size + 1
    if k > hkey[np.uint64(i)]:
        _sift_up(heap, hkey, pos, i, t, k)
    else:
        _sift_down(heap, hkey, pos, i, t, k, size)
    return size
