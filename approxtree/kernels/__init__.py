"""Hot loops as plain functions on arrays, compiled with numba (@njit(cache=True)).

No classes and no I/O here: patches and geometry call these with numpy arrays.
"""

# First: numba's cache locator for the package's kernel cache (filled at install), before any
# @njit(cache=True) below or in render/ (which import kernels._jit) picks its locator.
from approxtree.kernels import _cache  # noqa: F401
