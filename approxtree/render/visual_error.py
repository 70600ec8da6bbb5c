"""The visual approximation errors α_N and γ_N of section 4.1 of the core paper.

For a node N with box B_N, geometric error ε_T(N) and texel size w × h:

- α_N bounds, in pixels, the on-screen length of every vertical error segment
  (x, y, h_T)–(x, y, h_patch) of length ≤ ε_T(N) inside B_N (its part inside the frustum);
- γ_N = area in pixels of the projection of the w × h rectangle, parallel to the xy-plane,
  centred at p, the point of B_N nearest the camera (the eye clamped into the box).

The bound α_N (all lengths in display units, see frame_state.py). Put a point P of the frustum
in camera coordinates Q = P − eye = d·(t_x, t_y, 1): d is its depth along the view axis,
t = (t_x, t_y) the tangent of its direction, and its pixel is F·t + centre (F = focal_px; the
viewport is the rectangle |t_x| <= tan_x, |t_y| <= tan_y). Moving P along the unit vertical v
(camera coordinates (v_s, v_f): screen-plane part and depth part) moves its pixel at the speed

    |ds/dλ| = F·|v_s − v_f·t| / d = F·|c| / d²,    c = the part of v × Q across the view axis.

The projection of a segment is a segment, so its length is at most ε times the largest speed
along it, and a vertical segment inside the convex B_N ∩ frustum only meets points of that set.
Two upper bounds of the speed over B_N ∩ frustum, both kept, α_N the smaller:

1. |c| <= |v × Q| = ρ, the horizontal distance from the eye, and d² = |Q|² / (1 + |t|²), so
   speed <= F · ρ/|Q|² · (1 + |t|²). ρ/|Q|² = ρ / (ρ² + z²) is maximised over the ρ and height
   gap z that B_N allows (it rises up to ρ = z, then falls: the nadir bound), and |t|² over the
   tangents that B_N ∩ frustum can take. The factor 1 + |t|² = 1/cos²θ is the perspective's
   growth of pixels per radian towards the image edges; it is what a bound measured at the image
   centre misses (2.4× at the corners of a 60° 16:9 view, 6.9× at 100°).
2. speed <= max over those tangents of F·|v_s − v_f·t|, over the smallest depth d of B_N ∩
   frustum. v_s − v_f·t is affine in t, so its largest norm over a rectangle of tangents is at a
   corner; d is at least the smallest corner depth, the near distance, and |Q|min / sqrt(1+|t|²).
   Exact for a small box seen head-on; bound 1 is better for boxes deep along the view axis.

The tangents B_N can take: when all eight corners lie in front of the eye, the bounding
rectangle of the corners' projections (a box in front of the eye projects inside the hull of
its corners), cut to the viewport; otherwise the viewport. Corners go through the real clip
matrix m; in bound 2 the pixel speed per world z unit at NDC (x, y) and clip w is
(vw/2·(m02 − x·m32), vh/2·(m12 − y·m32)) / w. Both ends of an error segment lie in B_N: its
z range holds the node's data, and the patch interpolates data points.

An eye inside B_N gives +inf (always refined), as does a rectangle reaching behind the eye for
γ (clip w <= 0). A segment part outside the frustum is not on screen and is not bounded.

The texel of a node is that of the texture patch it is drawn with: with a texture pyramid its
own patch's (``textures.patch.patch_texel_sizes``), untextured its normal patch's
(``render.normal_map.NormalPatches``: the one normal map for every node of a grid within its
side, else the finest pyramid level covering D_N). ``texel_sizes`` (the node's data spacing)
is what ``select`` takes when a caller passes no texels.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from approxtree.kernels._jit import readonly
from approxtree.render.frame_state import FrameState


@njit(cache=True, inline="always")
def frame_tuples(m: np.ndarray, eye: np.ndarray, lens: np.ndarray):
    """(m (16,) row-major, eye (3,), lens (7,)) as tuples, for the per-node kernels."""
    # fmt: off
    mt = (
        m[0, 0], m[0, 1], m[0, 2], m[0, 3],
        m[1, 0], m[1, 1], m[1, 2], m[1, 3],
        m[2, 0], m[2, 1], m[2, 2], m[2, 3],
        m[3, 0], m[3, 1], m[3, 2], m[3, 3],
    )
    # fmt: on
    lt = (lens[0], lens[1], lens[2], lens[3], lens[4], lens[5], lens[6])
    return mt, (eye[0], eye[1], eye[2]), lt


@njit(cache=True, inline="always")
def box_tuple(bboxes: np.ndarray, i: int):
    """Row i of bboxes (n, 6) as a tuple."""
    return (bboxes[i, 0], bboxes[i, 1], bboxes[i, 2], bboxes[i, 3], bboxes[i, 4], bboxes[i, 5])


@njit(cache=True, inline="always")
def _project(m: tuple, x: float, y: float, z: float, vw: float, vh: float):
    """World point → (pixel x, pixel y, clip w) through the clip matrix m (16,) row-major."""
    cx = m[0] * x + m[1] * y + m[2] * z + m[3]
    cy = m[4] * x + m[5] * y + m[6] * z + m[7]
    cw = m[12] * x + m[13] * y + m[14] * z + m[15]
    if cw <= 0.0:
        return 0.0, 0.0, cw
    return (cx / cw * 0.5 + 0.5) * vw, (cy / cw * 0.5 + 0.5) * vh, cw


@njit(cache=True, inline="always")
def _nadir_gain(box: tuple, eye: tuple, lens: tuple) -> float:
    """max over B_N of ρ / (ρ² + z²), display units: ρ horizontal distance, z height gap."""
    sx, sy, sz = lens[1], lens[2], lens[3]
    # Nearest and farthest horizontal distances from the eye to the box's footprint.
    nx = max(box[0] - eye[0], 0.0, eye[0] - box[3]) * sx
    ny = max(box[1] - eye[1], 0.0, eye[1] - box[4]) * sy
    fx = max(abs(eye[0] - box[0]), abs(eye[0] - box[3])) * sx
    fy = max(abs(eye[1] - box[1]), abs(eye[1] - box[4])) * sy
    dmin = math.sqrt(nx * nx + ny * ny)
    dmax = math.sqrt(fx * fx + fy * fy)
    gap = max(box[2] - eye[2], 0.0, eye[2] - box[5]) * sz
    if gap == 0.0:
        return np.inf if dmin == 0.0 else 1.0 / dmin
    # ρ / (ρ² + z²) rises up to ρ = z and falls after it.
    d = min(max(gap, dmin), dmax)
    return d / (d * d + gap * gap)


@njit(cache=True, inline="always")
def node_alpha(
    box: tuple, error: float, eye: tuple, m: tuple, vw: float, vh: float, lens: tuple
) -> float:
    """α_N of one node (see the module docstring); arguments as in ``node_visual_errors``."""
    # An exact patch is 0 px at any depth; an unknown error is never good enough.
    if error == 0.0:
        return 0.0
    if not math.isfinite(error):
        return np.inf
    # Gaps from the eye to B_N per axis, display units; all 0: the eye inside B_N, parts of
    # which lie arbitrarily close to it.
    qx = max(box[0] - eye[0], 0.0, eye[0] - box[3]) * lens[1]
    qy = max(box[1] - eye[1], 0.0, eye[1] - box[4]) * lens[2]
    qz = max(box[2] - eye[2], 0.0, eye[2] - box[5]) * lens[3]
    if qx + qy + qz == 0.0:
        return np.inf
    focal, tan_x, tan_y, near = lens[0], lens[4], lens[5], lens[6]
    # NDC rectangle of B_N ∩ frustum and the smallest corner depth (clip w = depth). Clip
    # coordinates are linear: each corner sums one term per axis.
    x0, y0, x1, y1 = np.inf, np.inf, -np.inf, -np.inf
    wmin = np.inf
    for x in (box[0], box[3]):
        ax = m[0] * x + m[3]
        ay = m[4] * x + m[7]
        aw = m[12] * x + m[15]
        for y in (box[1], box[4]):
            bx = ax + m[1] * y
            by = ay + m[5] * y
            bw = aw + m[13] * y
            for z in (box[2], box[5]):
                cw = bw + m[14] * z
                wmin = min(wmin, cw)
                if cw > 0.0:
                    inv = 1.0 / cw
                    nx = (bx + m[2] * z) * inv
                    ny = (by + m[6] * z) * inv
                    x0, x1 = min(x0, nx), max(x1, nx)
                    y0, y1 = min(y0, ny), max(y1, ny)
    if wmin > 0.0:
        x0, x1 = max(x0, -1.0), min(x1, 1.0)
        y0, y1 = max(y0, -1.0), min(y1, 1.0)
        # No point of B_N projects into the viewport: nothing of it is on screen.
        if x0 > x1 or y0 > y1:
            return 0.0
    else:
        x0, y0, x1, y1 = -1.0, -1.0, 1.0, 1.0
    # Largest |t|² over the tangent rectangle: 1 + |t|² = 1/cos² of the angle off the axis.
    t2 = max(x0 * x0, x1 * x1) * tan_x * tan_x + max(y0 * y0, y1 * y1) * tan_y * tan_y
    # Bound 1: F · max ρ/|Q|² · (1 + |t|²), per world z unit (× sz).
    a1 = error * lens[3] * focal * _nadir_gain(box, eye, lens) * (1.0 + t2)
    # Bound 2: largest pixel speed numerator over the rectangle's corners / smallest depth.
    hx, hy = 0.5 * vw, 0.5 * vh
    num2 = 0.0
    for nx in (x0, x1):
        for ny in (y0, y1):
            sx = hx * (m[2] - nx * m[14])
            sy = hy * (m[6] - ny * m[14])
            num2 = max(num2, sx * sx + sy * sy)
    depth = max(wmin, near, math.sqrt((qx * qx + qy * qy + qz * qz) / (1.0 + t2)))
    a2 = error * math.sqrt(num2) / depth
    return min(a1, a2)


@njit(cache=True)
def node_visual_errors(
    box: tuple,
    error: float,
    tw: float,
    th: float,
    eye: tuple,
    m: tuple,
    vw: float,
    vh: float,
    lens: tuple,
) -> tuple[float, float]:
    """(α_N, γ_N) of one node: box (6,) world B_N, error ε_T(N), texel tw × th (world units),
    eye (3,) world, m (16,) world → clip row-major, viewport vw × vh pixels, lens (7,)
    FrameState.lens (focal length in pixels, display scale, viewport tangents, near).

    Tuples, not arrays (``frame_tuples``, ``box_tuple``): arrays passed per node cost numba
    reference counting, which doubled the traversal's time per node.
    """
    alpha = node_alpha(box, error, eye, m, vw, vh, lens)
    # γ: the tw × th rectangle centred at the nearest point p, parallel to the xy-plane;
    # clamping per axis is the same in world and display units (diagonal positive scale).
    px = min(max(eye[0], box[0]), box[3])
    py = min(max(eye[1], box[1]), box[4])
    pz = min(max(eye[2], box[2]), box[5])
    x0, y0, w0 = _project(m, px - 0.5 * tw, py - 0.5 * th, pz, vw, vh)
    x1, y1, w1 = _project(m, px + 0.5 * tw, py - 0.5 * th, pz, vw, vh)
    x2, y2, w2 = _project(m, px + 0.5 * tw, py + 0.5 * th, pz, vw, vh)
    x3, y3, w3 = _project(m, px - 0.5 * tw, py + 0.5 * th, pz, vw, vh)
    if w0 <= 0.0 or w1 <= 0.0 or w2 <= 0.0 or w3 <= 0.0:
        gamma = np.inf
    else:
        gamma = 0.5 * abs(
            (x0 * y1 - x1 * y0) + (x1 * y2 - x2 * y1) + (x2 * y3 - x3 * y2) + (x3 * y0 - x0 * y3)
        )
    return alpha, gamma


@njit(cache=True)
def _visual_errors_many(bboxes, errors, texels, eye, m, vw, vh, lens):
    n = bboxes.shape[0]
    alpha = np.empty(n)
    gamma = np.empty(n)
    mt, et, lt = frame_tuples(m, eye, lens)
    for i in range(n):
        alpha[i], gamma[i] = node_visual_errors(
            box_tuple(bboxes, i), errors[i], texels[i, 0], texels[i, 1], et, mt, vw, vh, lt
        )
    return alpha, gamma


def visual_errors(
    bboxes: np.ndarray, errors: np.ndarray, texels: np.ndarray, frame: FrameState
) -> tuple[np.ndarray, np.ndarray]:
    """(α, γ): two (n,) float64 arrays in pixels and pixels² for n nodes.

    bboxes: (n, 6) world boxes; errors: (n,) ε_T(N) in z units; texels: (n, 2) texel width
    and height in world x, y units; frame: the FrameState of the frame.
    """
    vw, vh = frame.viewport
    # Read-only views: one compiled signature for built and memory-mapped trees.
    return _visual_errors_many(
        readonly(bboxes, np.float64),
        readonly(errors, np.float64),
        readonly(texels, np.float64),
        readonly(frame.eye, np.float64),
        readonly(frame.world_to_clip, np.float64),
        float(vw),
        float(vh),
        frame.lens,
    )


def texel_sizes(tree) -> np.ndarray:
    """(n, 2) float64 data spacing of every node as a texel, in world x, y units: the texels
    ``select`` takes when given none (the Engine passes the texels its nodes are drawn with):
    grid-strategy nodes on a Grid: the rectangle's extent over the number of sampled
    intervals (computed from the rectangles alone, so no patch is loaded);
    other nodes: sqrt(area / points) of their patch, in both directions.
    """
    from approxtree.geometry.grid import Grid

    rects = tree.rects
    n = len(rects)
    extent = np.column_stack([rects[:, 2] - rects[:, 0], rects[:, 3] - rects[:, 1]])
    out = np.empty((n, 2))
    is_grid = np.zeros(n, dtype=bool)
    if isinstance(tree.terrain, Grid) and "grid" in tree.strategy_names:
        is_grid = tree.strategies == tree.strategy_names.index("grid")
        cell = np.array(tree.terrain.cell_size)
        k = math.isqrt(int(tree.max_points))
        lines = np.rint(extent[is_grid] / cell).astype(np.int64) + 1
        # Same steps as GridPatch: the smallest keeping at most k lines per direction.
        step = np.maximum(1, -(-(lines - 1) // max(k - 1, 1)))
        intervals = np.maximum(-(-(lines - 1) // step), 1)
        out[is_grid] = np.where(lines > 1, extent[is_grid] / intervals, cell)
    for i in np.flatnonzero(~is_grid):
        patch = tree.patch(int(i))
        area = max(extent[i, 0] * extent[i, 1], 0.0)
        out[i] = math.sqrt(area / max(patch.point_count, 1))
    return out
