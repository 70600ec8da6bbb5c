"""The visual approximation errors α_N and γ_N of section 4.1 of the core paper.

For a node N with box B_N, geometric error ε_T(N) and texel size w × h:

1. p = the point of B_N nearest the camera (the eye clamped into the box);
2. α_N = length in pixels of the projection of the vertical segment of length ε_T(N)
   centred at p;
3. γ_N = area in pixels of the projection of the w × h rectangle, parallel to the xy-plane,
   centred at p.

Step 2 alone reads 0 when the eye is straight above (or below) B_N: the segment at p is then
seen end-on, although other points of B_N show the error. So α_N is also at least the angle
that a vertical segment of length ε anywhere in B_N can subtend, times the focal length in
pixels: at horizontal distance d and height gap z that angle is at most ε·d / (d² + z²),
maximised over the d and z the box allows (the nadir bound).

When the segment or the rectangle reaches behind the eye (clip w <= 0, e.g. the eye inside
B_N) the projection is unbounded and the error is +inf, which always asks for refinement.

The texel of a node is its texture patch's texel (``textures.patch.patch_texel_sizes``) when
the Engine has a texture pyramid, else its data spacing (``texel_sizes``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from approxtree.render.frame_state import FrameState


@njit(cache=True, inline="always")
def _project(m: np.ndarray, x: float, y: float, z: float, vw: float, vh: float):
    """World point → (pixel x, pixel y, clip w) through the column-vector clip matrix m."""
    cx = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
    cy = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
    cw = m[3, 0] * x + m[3, 1] * y + m[3, 2] * z + m[3, 3]
    if cw <= 0.0:
        return 0.0, 0.0, cw
    return (cx / cw * 0.5 + 0.5) * vw, (cy / cw * 0.5 + 0.5) * vh, cw


@njit(cache=True, inline="always")
def _nadir_gain(box: np.ndarray, eye: np.ndarray, lens: np.ndarray) -> float:
    """max over B_N of d / (d² + z²), display units: d horizontal distance, z height gap."""
    sx, sy, sz = lens[1], lens[2], lens[3]
    # Nearest and farthest horizontal distances from the eye to the box's footprint.
    nx = max(box[0] - eye[0], 0.0, eye[0] - box[3]) * sx
    ny = max(box[1] - eye[1], 0.0, eye[1] - box[4]) * sy
    fx = max(abs(eye[0] - box[0]), abs(eye[0] - box[3])) * sx
    fy = max(abs(eye[1] - box[1]), abs(eye[1] - box[4])) * sy
    dmin = math.hypot(nx, ny)
    dmax = math.hypot(fx, fy)
    gap = max(box[2] - eye[2], 0.0, eye[2] - box[5]) * sz
    if gap == 0.0:
        return np.inf if dmin == 0.0 else 1.0 / dmin
    # d / (d² + z²) rises up to d = z and falls after it.
    d = min(max(gap, dmin), dmax)
    return d / (d * d + gap * gap)


@njit(cache=True)
def node_visual_errors(
    box: np.ndarray,
    error: float,
    tw: float,
    th: float,
    eye: np.ndarray,
    m: np.ndarray,
    vw: float,
    vh: float,
    lens: np.ndarray,
) -> tuple[float, float]:
    """(α_N, γ_N) of one node: box (6,) world B_N, error ε_T(N), texel tw × th (world units),
    eye (3,) world, m (4, 4) world → clip, viewport vw × vh pixels, lens (4,) focal length
    in pixels and the display scale (FrameState.lens)."""
    # 1. The nearest point: clamping per axis is the same in world and display units because
    #    the display scale is diagonal and positive.
    px = min(max(eye[0], box[0]), box[3])
    py = min(max(eye[1], box[1]), box[4])
    pz = min(max(eye[2], box[2]), box[5])
    # 2. α: the vertical segment of length ε centred at p. An exact patch is 0 px at any depth.
    if error == 0.0:
        alpha = 0.0
    elif not np.isfinite(error):
        alpha = np.inf
    else:
        ax, ay, aw = _project(m, px, py, pz - 0.5 * error, vw, vh)
        bx, by, bw = _project(m, px, py, pz + 0.5 * error, vw, vh)
        alpha = np.inf if (aw <= 0.0 or bw <= 0.0) else np.hypot(bx - ax, by - ay)
        alpha = max(alpha, error * lens[3] * lens[0] * _nadir_gain(box, eye, lens))
    # 3. γ: the tw × th rectangle centred at p, parallel to the xy-plane; shoelace area.
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
    for i in range(n):
        alpha[i], gamma[i] = node_visual_errors(
            bboxes[i], errors[i], texels[i, 0], texels[i, 1], eye, m, vw, vh, lens
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
    return _visual_errors_many(
        np.ascontiguousarray(bboxes, dtype=np.float64),
        np.ascontiguousarray(errors, dtype=np.float64),
        np.ascontiguousarray(texels, dtype=np.float64),
        np.ascontiguousarray(frame.eye, dtype=np.float64),
        np.ascontiguousarray(frame.world_to_clip),
        float(vw),
        float(vh),
        frame.lens,
    )


def texel_sizes(tree) -> np.ndarray:
    """(n, 2) float64 texel width and height of every node, in world x, y units.

    Without a texture pyramid the "texel" is the node's data spacing:
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
