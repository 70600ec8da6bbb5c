"""Prefetch of the paging renderer, scripted and without GL or clocks (render/prefetch.py,
traversal.py, provider.py).

Loads "complete" when a test says so: each frame, the first N nodes a plan asks for become
resident. So the load order (coarse and most visible first), the prediction (the cut of the
extrapolated camera is requested after the frame's own) and the frames a cut takes to settle
are checked exactly, whatever the machine's speed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from approxtree import ApproximationTree
from approxtree.datasets import fractal_terrain
from approxtree.errors import InvalidParameterError
from approxtree.render import Camera, Paging
from approxtree.render.frame_state import FrameState, display_scale
from approxtree.render.prefetch import FrameBudget, MotionPredictor, Prefetcher
from approxtree.render.provider import Payload, PayloadProvider
from approxtree.render.selector import select
from approxtree.render.traversal import plan_frame, sibling_nodes, upload_order
from approxtree.render.visual_error import texel_sizes, visual_errors

SIZE = (320, 240)
ALPHA = 4.0


@pytest.fixture(scope="module")
def tree():
    """A 257² fractal tree with leaves of 9 × 9 points (five levels)."""
    terrain = fractal_terrain(257, seed=3, relief=300.0)
    return ApproximationTree.build(terrain, epsilon=0.5, max_points=81, progress=False)


def frame_of(tree, eye, target) -> FrameState:
    cam = Camera.look_at(eye, target, fov=60)
    scale = display_scale(tree.terrain)
    return FrameState.from_camera(cam, SIZE, tree.bboxes[0], tree.origin, scale)


def low_view(tree, t: float, start=(0.1, 0.2), heading=(1.0, 0.3)) -> FrameState:
    """A low oblique view at ``t`` (0..1) along a straight leg across the domain."""
    d = tree.terrain.domain
    w = d.xmax - d.xmin
    top = float(tree.bboxes[0][5])
    h = np.asarray(heading) / np.linalg.norm(heading)
    x = d.xmin + w * (start[0] + 0.6 * t * h[0])
    y = d.ymin + w * (start[1] + 0.6 * t * h[1])
    ahead = (x + 0.2 * w * h[0], y + 0.2 * w * h[1], top - 0.1 * w)
    return frame_of(tree, (x, y, top + 0.05 * w), ahead)


def residency(ids: set[int]):
    def resident(nodes: np.ndarray) -> np.ndarray:
        return np.array([int(n) in ids or n == 0 for n in np.asarray(nodes)], dtype=bool)

    return resident


def nothing(nodes: np.ndarray) -> np.ndarray:
    return np.zeros(len(nodes), dtype=bool)


def test_upload_order_loads_coarse_nodes_first_and_the_most_visible_within_a_level(tree):
    """The missing nodes of a cut and their ancestors come coarsest level first and, within
    a level, by decreasing screen-space error α in the frame."""
    fs = low_view(tree, 0.3)
    wanted = select(tree, fs, ALPHA, math.inf)
    texels = texel_sizes(tree)
    levels = tree.levels

    def alpha(ids):
        return visual_errors(tree.bboxes[ids], tree.errors[ids], texels[ids], fs)[0]

    order = upload_order(wanted.nodes, tree.parents, levels, residency(set()), alpha)
    assert len(order) > 8 and order[0] != 0  # the root counts as resident
    assert (np.diff(levels[order]) >= 0).all()
    for level in np.unique(levels[order]):
        a = alpha(order[levels[order] == level])
        assert (np.diff(a) <= 0).all(), f"level {level} not by decreasing α"
    # Every wanted node and every missing ancestor of one is there, once.
    assert set(wanted.nodes.tolist()) - {0} <= set(order.tolist())
    assert len(np.unique(order)) == len(order)


def test_a_scripted_frame_draws_coarse_visible_stand_ins_after_one_frame_of_loads(tree):
    """With N loads completing per frame in the order asked, the first frame after the loads
    already draws a coarser level than the root everywhere (coarse nodes load first)."""
    fs = low_view(tree, 0.3)
    wanted = select(tree, fs, ALPHA, math.inf)
    texels = texel_sizes(tree)
    resident: set[int] = set()
    plan = plan_frame(wanted, fs, tree, texels, residency(resident), nothing)
    n = int(np.count_nonzero(tree.levels[plan.request] == 1))
    resident |= set(plan.request[:n].tolist())
    again = plan_frame(wanted, fs, tree, texels, residency(resident), nothing)
    assert 0 not in again.drawn.nodes.tolist()
    assert set(tree.levels[again.drawn.nodes].tolist()) >= {1}


def test_prediction_extrapolates_the_camera_and_forgets_it_at_a_cut(tree):
    """The predictor extrapolates a camera moving at constant speed k frames ahead exactly,
    and a jump far beyond the recent motion (a cut) leaves it nothing to predict."""
    views = [low_view(tree, t) for t in (0.0, 0.02, 0.04, 0.06)]
    motion = MotionPredictor()
    for fs in views:
        motion.observe(fs)
    predicted = motion.predict(views[-1], 4)
    expected = low_view(tree, 0.14)
    assert np.allclose(predicted.eye, expected.eye)
    forward = FrameState.from_camera(predicted, SIZE, tree.bboxes[0], tree.origin, views[0].scale)
    assert np.allclose(forward.view[2, :3], expected.view[2, :3])
    motion.observe(low_view(tree, 0.9, start=(0.7, 0.7), heading=(-1.0, 0.2)))
    assert motion.cuts == 1 and motion.predict(views[-1], 4) is None


def test_the_predicted_view_is_requested_after_the_frames_own(tree):
    """The cut of the camera extrapolated ``lookahead`` frames ahead (and twice that) is asked
    for after every node of the frame's own request, and it holds the nodes the camera wants
    when it gets there."""
    texels = texel_sizes(tree)
    prefetch = Prefetcher()
    paging = Paging(wait=False, lookahead=6, siblings=False)
    for t in (0.0, 0.03, 0.06):
        fs = low_view(tree, t)
        prefetch.start(0.0, fs, paging, frozen=False)
    view, further = prefetch.views(fs, paging, tree.bboxes[0])
    ahead = select(tree, view, ALPHA, math.inf).nodes
    later = select(tree, low_view(tree, 0.24), ALPHA, math.inf).nodes
    assert set(ahead.tolist()) == set(later.tolist())
    assert np.allclose(further.eye, low_view(tree, 0.42).eye)  # and twice as far ahead
    wanted = select(tree, fs, ALPHA, math.inf)
    plan = plan_frame(wanted, fs, tree, texels, residency(set()), nothing, None, [ahead])
    new = set(ahead.tolist()) - set(plan.request.tolist()) - {0}
    assert new and new <= set(plan.prefetch.tolist())
    assert not set(plan.prefetch.tolist()) & set(plan.request.tolist())


def test_siblings_of_wanted_nodes_are_prefetched_last(tree):
    """Siblings of wanted nodes (not wanted themselves, not resident) follow the predicted
    cut's nodes in the prefetch list."""
    fs = low_view(tree, 0.5)
    wanted = select(tree, fs, ALPHA, math.inf)
    texels = texel_sizes(tree)
    sib = sibling_nodes(wanted.nodes, tree.parents, tree.child_start, tree.child_count)
    assert len(sib) and not set(sib.tolist()) & set(wanted.nodes.tolist())
    assert (tree.parents[sib][:, None] == tree.parents[wanted.nodes][None, :]).any(axis=1).all()
    plan = plan_frame(wanted, fs, tree, texels, residency(set()), nothing, None, (), True)
    assert set(plan.prefetch.tolist()) == set(sib.tolist()) - set(plan.request.tolist())


@pytest.mark.parametrize("per_frame", [8, 32])
def test_after_a_cut_the_frame_settles_within_the_frames_its_loads_take(tree, per_frame):
    """Fly a leg, cut to another leg; with ``per_frame`` loads completing per frame in the
    order asked (prefetch included), the frame after the cut settles within
    ceil(missing / per_frame) + 1 frames, and within 10 frames at 32 loads a frame."""
    texels = texel_sizes(tree)
    prefetch = Prefetcher()
    paging = Paging(wait=False)
    resident: set[int] = set()

    def frame(fs):
        prefetch.start(0.0, fs, paging, frozen=False)
        views = prefetch.views(fs, paging, tree.bboxes[0])
        ahead = [select(tree, v, ALPHA, math.inf).nodes for v in views]
        wanted = select(tree, fs, ALPHA, math.inf)
        plan = plan_frame(wanted, fs, tree, texels, residency(resident), nothing, None, ahead, True)
        # This frame's loads complete: the first per_frame asked for, prefetches last.
        asked = np.concatenate([plan.request, plan.prefetch])
        resident.update(asked[:per_frame].tolist())
        return plan

    for t in np.linspace(0.0, 0.3, 10):
        frame(low_view(tree, float(t)))
    leg = [low_view(tree, float(t), (0.8, 0.8), (-1.0, -0.4)) for t in np.linspace(0, 0.3, 30)]
    wanted = select(tree, leg[0], ALPHA, math.inf).nodes
    missing = len(upload_order(wanted, tree.parents, tree.levels, residency(resident)))
    assert missing > per_frame  # the cut lands on a view with loads to wait for
    settle = next(k for k, fs in enumerate(leg) if frame(fs).pending == 0)
    assert settle <= math.ceil(missing / per_frame) + 1
    if per_frame >= 32:
        assert settle <= 10
    # Once settled, prefetching keeps the leg settled.
    assert all(frame(fs).pending == 0 for fs in leg[settle + 1 :])


def test_frame_budget_spends_the_margin_over_the_median_frame():
    """The upload allowance is the recent median frame time without uploads plus the margin,
    less the last frame's own time, never below the margin: a quick frame leaves the next
    one more, a slow one leaves it the margin."""
    budget = FrameBudget(margin_ms=5.0, window=5)
    assert budget.start(0.0) is None  # no history yet: no limit
    now = 0.0
    for rest in (20.0, 20.0, 20.0):
        budget.uploaded(3.0)
        now += (rest + 3.0) / 1e3
        allowance = budget.start(now)
    assert allowance == pytest.approx(5.0)
    budget.uploaded(5.0)
    now += (30.0 + 5.0) / 1e3  # a frame 10 ms slower than the median
    assert budget.start(now) == pytest.approx(5.0)
    now += 12.0 / 1e3  # a quick frame without uploads
    assert budget.start(now) == pytest.approx(20.0 + 5.0 - 12.0)


def test_prefetched_payloads_never_evict_the_frames_own():
    """A prefetched payload is cached only where it evicts no key of the current request;
    once nothing wanted needs the room, it is cached like any other."""
    provider = PayloadProvider(lambda key: Payload(texels=np.zeros(100, np.uint8)), 250)
    try:
        provider.load("a")
        provider.load("b")
        provider.request(["a", "b"], ahead=["c"])
        provider.wait()
        assert "a" in provider and "b" in provider and "c" not in provider
        provider.request([], ahead=["c"])
        provider.wait()
        assert "c" in provider and len(provider) == 2
    finally:
        provider.close()


def test_paging_checks_its_prefetch_fields():
    """lookahead and frame_margin_ms refuse bad values with an InvalidParameterError."""
    with pytest.raises(InvalidParameterError):
        Paging(lookahead=-1)
    with pytest.raises(InvalidParameterError):
        Paging(frame_margin_ms=math.nan)
    assert Paging(path=[]).path == ()
