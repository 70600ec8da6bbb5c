"""Hot loops as plain functions on arrays, compiled with numba (@njit(cache=True)).

No classes and no I/O here: patches and geometry call these with numpy arrays.
"""
