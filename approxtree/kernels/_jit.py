"""How arrays reach a kernel, so that each kernel compiles one signature (no compile twice).

numba compiles a kernel once per distinct argument type, and an array's type includes its
dtype, layout and whether it is read-only. A tree opened from a store hands out read-only
(memory-mapped or cached) arrays where a freshly built tree hands out writable ones: the same
kernel would then compile twice, on the user's clock. The convention:

- every array a kernel only reads is passed through :func:`readonly` at the Python boundary
  (C-contiguous, the kernel's one dtype, read-only view: zero-copy when already so);
- arrays a kernel writes into (outputs passed in) stay writable and are allocated by the
  caller with the kernel's dtype;
- a kernel avoids numba features that compile large library code into every cold start:
  array slice assignment ``a[:n] = b`` (its shape-mismatch error formats strings; write a
  loop), ``np.sort``/``np.argsort`` (sort in numpy before the call);
- a small kernel that allocates nothing and is called very often is compiled by
  :func:`njit_no_nrt`, without numba's reference-counting runtime.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numpy as np
from numba import njit
from numba.core.dispatcher import Dispatcher

_F = TypeVar("_F", bound=Callable[..., object])


def njit_no_nrt(*, fastmath: bool = False) -> Callable[[_F], Dispatcher[_F]]:
    """``@njit(cache=True, _nrt=False)``: a cached kernel compiled without numba's runtime.

    A call then costs no atomic reference-count updates on its array arguments, which would
    outweigh a kernel as small as a heap sift; the kernel must allocate nothing.
    """
    # numba's stubs leave out the _nrt target option that njit accepts (numba.core.options).
    return njit(cache=True, fastmath=fastmath, _nrt=False)  # type: ignore[call-overload]


def readonly(a: np.ndarray, dtype: np.dtype | type | None = None) -> np.ndarray:
    """``a`` as a C-contiguous, read-only array of ``dtype`` (a view when no copy is needed).

    The view shares memory with ``a``; ``a`` itself keeps its flags.
    """
    out = np.ascontiguousarray(a, dtype=dtype)
    if out.flags.writeable:
        out = out.view()
        out.flags.writeable = False
    return out
