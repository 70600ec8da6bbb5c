"""The pixel bound α holds in every view: measured on real and fractal DEMs, no GL.

For a cut selected at threshold alpha, every data point (x, y, h_T) of every selected patch that
lies inside the view frustum is projected with the frame's own clip matrix, together with the
point (x, y, h_patch) of the patch above or below it (h_patch from matplotlib's linear
interpolation on the patch's triangles, not from our kernels). The distance in pixels of the
two projections must not exceed alpha, nor the α_N of the node. Only the part of the segment
inside the frustum is on screen, so a segment leaving the frustum is cut at its boundary.

Views: oblique, grazing, straight overhead, near-overhead (the view where the bound used to
break at the image edges), overhead-low, close-up and a 100° wide field of view; trees are built
with ε = 0 so that leaves are exact and every drawn simplified patch has α_N <= alpha.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from affine import Affine
from conftest import data_file
from matplotlib.tri import LinearTriInterpolator, Triangulation

import approxtree as at
from approxtree import ApproximationTree, Grid
from approxtree.datasets import fractal_terrain
from approxtree.geometry.rect import Rect
from approxtree.render import Camera, FrameState, display_scale, overview_camera, select
from approxtree.render.visual_error import texel_sizes, visual_errors

SIZE = (480, 320)
ALPHAS = (1.0, 2.0, 4.0)
VIEWS = ("oblique", "grazing", "overhead", "near_overhead", "overhead_low", "close_up", "wide")
#: DEM name → (file under shared/data or None for the fractal, crop row, crop column).
DEMS = {
    "fractal": (None, 0, 0),
    "crater": ("scape/crater.stm", 100, 60),
    "srtm": ("srtm/N44W072.hgt", 750, 710),
    "nc": ("nc/elev_ned_30m.tif", 100, 120),
}
CROP = 257
#: Float noise of the interpolation and projection, pixels.
TOLERANCE = 1e-6


def crop(terrain: Grid, r0: int, c0: int, n: int) -> Grid:
    """The n × n window of a grid starting at row r0, column c0, same georeference."""
    transform = terrain.transform @ Affine.translation(c0, r0)
    return Grid(np.asarray(terrain.heights[r0 : r0 + n, c0 : c0 + n]), transform, terrain.crs)


class Dem:
    """A tree with exact leaves over one DEM, and the error segments of its nodes (cached)."""

    def __init__(self, terrain: Grid) -> None:
        self.tree = ApproximationTree.build(terrain, epsilon=0.0, max_points=17 * 17)
        self.scale = display_scale(terrain)
        self.texels = texel_sizes(self.tree)
        self._segments: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def segments(self, node: int) -> tuple[np.ndarray, np.ndarray]:
        """((k, 3) data points, (k, 3) the same points at the patch's height) of ``node``."""
        if node not in self._segments:
            pts = self.tree.terrain.points(Rect(*self.tree.rects[node]))
            patch = self.tree.patch(node)
            v = patch.vertices
            tri = Triangulation(v[:, 0], v[:, 1], patch.triangles)
            h = LinearTriInterpolator(tri, v[:, 2])(pts[:, 0], pts[:, 1])
            # Data points are inside the patch's footprint: none may fall outside its triangles.
            assert not np.ma.getmaskarray(h).any()
            on_patch = pts.copy()
            on_patch[:, 2] = np.ma.getdata(h)
            self._segments[node] = (pts, on_patch)
        return self._segments[node]

    def frame(self, view: str) -> FrameState:
        """The FrameState of the named view (see the module docstring)."""
        tree, s = self.tree, self.scale
        box = tree.bboxes[0]
        (cx, cy), top, bottom = tree.terrain.domain.center, box[5], box[2]
        w = tree.terrain.domain.width * s[0]

        def at_(dx: float, dy: float, z: float) -> tuple[float, float, float]:
            # Display-unit offsets from the centre (metres, also on geographic DEMs).
            return (cx + dx * w / s[0], cy + dy * w / s[1], z)

        cameras = {
            "oblique": overview_camera(box, s),
            "grazing": Camera.look_at(at_(0, -0.6, top + 0.02 * w), at_(0, 0.2, bottom), 60),
            "overhead": Camera.look_at(at_(0, 0, top + w), at_(0, 1e-3, bottom), 60),
            "near_overhead": Camera.look_at(
                at_(0, -0.117, top + 0.78 * w), at_(0, 0.234, bottom), 60
            ),
            "overhead_low": Camera.look_at(at_(0, 0, top + 0.15 * w), at_(0, 1e-3, bottom), 60),
            "close_up": Camera.look_at(at_(0.1, -0.1, top + 0.03 * w), at_(0.2, 0.1, bottom), 60),
            "wide": Camera.look_at(at_(0, -0.1, top + 0.2 * w), at_(0, 0.1, bottom), 100),
        }
        return FrameState.from_camera(cameras[view], SIZE, box, tree.origin, s)


def screen_errors(dem: Dem, frame: FrameState, nodes: np.ndarray) -> list[np.ndarray]:
    """Per node, the pixel lengths of its on-screen error segments whose data point is in
    the frustum (the segment cut where it leaves the frustum)."""
    out = []
    for node in nodes:
        p, q = dem.segments(int(node))
        planes = frame.planes
        sp = p @ planes[:, :3].T + planes[:, 3]
        sq = q @ planes[:, :3].T + planes[:, 3]
        inside = (sp >= 0.0).all(axis=1)
        p, q, sp, sq = p[inside], q[inside], sp[inside], sq[inside]
        # The segment p + λ (q − p) stays inside every plane up to λ = sp / (sp − sq).
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = np.where(sq < 0.0, sp / (sp - sq), 1.0).min(axis=1, initial=1.0)
        q = p + lam[:, None] * (q - p)
        a, _ = frame.world_to_pixels(p)
        b, _ = frame.world_to_pixels(q)
        out.append(np.hypot(*(a - b).T))
    return out


_DEMS: dict[str, Dem] = {}


@pytest.fixture(params=list(DEMS))
def dem(request) -> Dem:
    """One of the DEMs of DEMS, built once per test session (real ones skip without data)."""
    name = request.param
    if name not in _DEMS:
        path, r0, c0 = DEMS[name]
        if path is None:
            terrain = fractal_terrain(CROP, seed=5, relief=300.0)
        else:
            data_dir = request.getfixturevalue("data_dir")
            terrain = crop(at.open_terrain(data_file(data_dir, path)), r0, c0, CROP)
        _DEMS[name] = Dem(terrain)
    return _DEMS[name]


@pytest.mark.parametrize("view", VIEWS)
def test_screen_error_of_every_data_point_within_alpha(dem, view):
    """For alpha in {1, 2, 4}: every on-screen error segment of the cut is at most alpha and
    at most its node's α_N pixels long; the view shows error (largest >= alpha / 4)."""
    frame = dem.frame(view)
    shown = 0.0
    for alpha in ALPHAS:
        sel = select(dem.tree, frame, alpha=alpha, gamma=math.inf, texels=dem.texels)
        assert len(sel.nodes) > 0 and sel.stats["max_alpha"] <= alpha
        lengths = screen_errors(dem, frame, sel.nodes)
        for node, a_node, d in zip(sel.nodes, sel.alphas, lengths, strict=True):
            largest = float(d.max(initial=0.0))
            assert largest <= a_node + TOLERANCE, (view, alpha, int(node), largest, a_node)
        largest = max(float(d.max(initial=0.0)) for d in lengths)
        print(f"{view} alpha = {alpha}: largest screen error {largest:.3f} px")
        assert largest <= alpha + TOLERANCE, (view, alpha, largest)
        shown = max(shown, largest / alpha)
    assert shown >= 0.25


def test_alpha_bounds_vertical_segments_anywhere_in_the_box():
    """Random boxes and cameras (narrow to 100° fields of view, overhead to grazing): the
    screen length of any vertical segment of length ε inside B_N ∩ frustum is at most α_N,
    and for boxes seen under less than 1° α_N is within 5 % of the largest sampled length."""
    rng = np.random.default_rng(13)
    loose = []
    for _ in range(300):
        eye = rng.uniform([-500, -500, 50], [500, 500, 3000])
        target = np.array([*rng.uniform(-400, 400, 2), 0.0])
        fov = float(rng.choice([20.0, 60.0, 100.0]))
        cam = Camera.look_at(eye, target, fov)
        frame = FrameState.from_camera(
            cam, (640, 360), np.array([-1e3, -1e3, -1e3, 1e3, 1e3, 1e3]), np.zeros(3), np.ones(3)
        )
        # A box somewhere in the view: a random frustum point, random size.
        ndc = rng.uniform(-1, 1, 2)
        depth = rng.uniform(0.05, 1.0) * np.linalg.norm(eye - target)
        proj = frame.projection
        on_axis = [ndc[0] / proj[0, 0] * depth, ndc[1] / proj[1, 1] * depth, -depth, 1.0]
        centre = (np.linalg.inv(frame.view) @ on_axis)[:3]
        half = depth * 10.0 ** rng.uniform(-3.5, -0.5, 3)
        box = np.concatenate([centre - half, centre + half])
        if (box[:3] <= eye).all() and (eye <= box[3:]).all():
            continue
        eps = 2 * half[2] * rng.uniform(0.2, 1.0)
        alpha_n = visual_errors(box[None], np.array([eps]), np.ones((1, 2)), frame)[0][0]
        # Vertical segments of length eps with both ends in the box: x, y anywhere, low end
        # anywhere from the bottom to top − eps; corners and edges included.
        n = 4000
        xy = rng.uniform(box[:2], box[3:5], (n, 2))
        xy[:8] = [[box[i], box[j]] for i in (0, 3) for j in (1, 4)] * 2
        z0 = box[2] + rng.uniform(0, 1, n) * (box[5] - box[2] - eps)
        z0[:4], z0[4:8] = box[2], box[5] - eps
        p = np.column_stack([xy, z0])
        q = np.column_stack([xy, z0 + eps])
        planes = frame.planes
        inside = ((p @ planes[:, :3].T + planes[:, 3]) >= 0).all(axis=1) & (
            (q @ planes[:, :3].T + planes[:, 3]) >= 0
        ).all(axis=1)
        if inside.sum() < 100:
            continue
        a, _ = frame.world_to_pixels(p[inside])
        b, _ = frame.world_to_pixels(q[inside])
        largest = float(np.hypot(*(a - b).T).max())
        assert largest <= alpha_n * (1 + 1e-9), (eye, target, fov, box, largest, alpha_n)
        if half.max() < depth * math.tan(math.radians(0.5)) and inside.all():
            loose.append(alpha_n / largest)
    assert len(loose) >= 20
    assert max(loose) <= 1.05, max(loose)
