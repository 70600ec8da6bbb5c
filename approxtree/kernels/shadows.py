"""Cast shadows of a directional light over a height grid, by marching towards the light."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True)
def cast_shadows(
    z: np.ndarray, dx: float, dy: float, azimuth: float, altitude: float
) -> np.ndarray:
    """Cells hidden from a light at (azimuth, altitude) degrees by higher terrain.

    z: (rows, cols) float, NaN = nodata (casts no shadow). dx: column step; dy: signed row step
    (negative when row 0 is north), both in z units. Returns (rows, cols) bool.

    From each cell the ray towards the light is sampled one cell at a time (bilinear heights);
    the cell is shadowed as soon as the terrain rises above the ray.
    """
    rows, cols = z.shape
    out = np.zeros((rows, cols), dtype=np.bool_)
    az = math.radians(azimuth)
    # Light direction in world (east, north), then in (col, row) index steps.
    east, north = math.sin(az), math.cos(az)
    step_c = east / abs(dx) if dx != 0 else 0.0
    step_r = north / dy if dy != 0 else 0.0
    norm = max(abs(step_c), abs(step_r))
    if norm == 0.0:
        return out
    step_c /= norm
    step_r /= norm
    # World distance covered by one step, and the height the ray gains over it.
    dist = math.hypot(step_c * dx, step_r * dy)
    rise = math.tan(math.radians(altitude)) * dist
    zmax = np.nanmax(z)
    for r in prange(rows):
        for c in range(cols):
            h = z[r, c]
            if np.isnan(h):
                continue
            fr = r + step_r
            fc = c + step_c
            ray = h + rise
            while 0.0 <= fr <= rows - 1 and 0.0 <= fc <= cols - 1 and ray <= zmax:
                r0 = min(int(fr), rows - 2)
                c0 = min(int(fc), cols - 2)
                tr = fr - r0
                tc = fc - c0
                t = (1 - tr) * ((1 - tc) * z[r0, c0] + tc * z[r0, c0 + 1]) + tr * (
                    (1 - tc) * z[r0 + 1, c0] + tc * z[r0 + 1, c0 + 1]
                )
                if t > ray:
                    out[r, c] = True
                    break
                fr += step_r
                fc += step_c
                ray += rise
    return out
