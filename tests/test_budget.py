"""Triangle budget mode: the cut of smallest largest α within max_triangles (EGL renders)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from approxtree import ApproximationTree, InvalidParameterError
from approxtree.cli import main
from approxtree.datasets import fractal_terrain
from approxtree.render import Camera, Cut, Engine
from approxtree.render.budget import node_triangles, select_budget
from approxtree.render.context import create_context
from approxtree.render.selector import select

SIZE = (160, 120)


@pytest.fixture(scope="module")
def tree() -> ApproximationTree:
    """A 129² fractal, quadtree of 17² patches, exact leaves."""
    terrain = fractal_terrain(129, seed=3, relief=200.0)
    return ApproximationTree.build(terrain, epsilon=0.0, max_points=17 * 17, progress=False)


@pytest.fixture(scope="module")
def engine(tree):
    """An offscreen engine on its own EGL context."""
    ctx = create_context()
    eng = Engine(tree, context=ctx, offscreen=True)
    yield eng
    eng.release()
    ctx.release()


def view(tree) -> Camera:
    c = tree.terrain.domain.center
    return Camera.look_at((c[0] - 40, c[1] - 200, 160), (c[0], c[1], 0), fov=60)


def test_budget_is_met_and_alpha_never_grows(engine, tree):
    """Frames never exceed the budget (drawn triangles, skirts included); α falls as it grows."""
    cam = view(tree)
    counts = node_triangles(tree)
    lo = int(counts[0])
    budgets = np.unique(np.linspace(lo, int(counts[tree.leaves].sum()) + 10, 9).astype(int))
    reached = []
    for n in budgets:
        frame = engine.render(cam, SIZE, Cut(max_triangles=int(n)))
        assert frame.stats["triangles"] <= n
        assert frame.stats["triangles"] == frame.selection.stats["budget_triangles"]
        reached.append(frame.stats["max_alpha"])
        assert frame.image[..., 3].any()
    assert np.all(np.diff(reached) <= 1e-12)
    assert reached[-1] < reached[0]


def test_budget_alpha_beats_threshold_at_equal_triangles(engine, tree):
    """With the triangles a threshold frame drew, budget mode reaches an α no larger."""
    cam = view(tree)
    for alpha in (0.5, 2.0, 8.0):
        thr = engine.render(cam, SIZE, Cut(alpha=alpha, gamma=float("inf")))
        bud = engine.render(cam, SIZE, Cut(max_triangles=thr.stats["triangles"]))
        assert bud.stats["triangles"] <= thr.stats["triangles"]
        assert bud.stats["max_alpha"] <= thr.stats["max_alpha"] + 1e-12


def test_budget_cut_is_optimal_among_threshold_cuts(engine, tree):
    """No threshold cut within the budget has a smaller largest α than the budget cut."""
    cam = view(tree)
    fs = engine.frame_state(cam, SIZE)
    counts = node_triangles(tree)
    budget = int(counts[0]) * 6
    sel = select_budget(tree, fs, budget, counts)
    for alpha in np.geomspace(0.05, 50, 25):
        thr = select(tree, fs, float(alpha), float("inf"))
        if counts[thr.nodes].sum() <= budget:
            assert sel.stats["alpha_reached"] <= thr.stats["max_alpha"] + 1e-12


def test_budget_errors(engine, tree):
    """A budget below the coarsest cut, or not a positive int, raises a clear error."""
    cam = view(tree)
    with pytest.raises(InvalidParameterError, match="coarsest cut"):
        engine.render(cam, SIZE, Cut(max_triangles=3))
    with pytest.raises(InvalidParameterError, match="max_triangles"):
        engine.render(cam, SIZE, Cut(max_triangles=0))


def test_cli_render_max_triangles(tree, tmp_path):
    """approxtree render --max-triangles keeps the frame within the budget."""
    path = tmp_path / "t.zarr"
    tree.save(path)
    out = CliRunner().invoke(
        main,
        [
            "render",
            str(path),
            "--size",
            "96x64",
            "--max-triangles",
            "3000",
            "--out",
            str(tmp_path / "f.png"),
            "--json",
        ],
    )
    assert out.exit_code == 0, out.output
    stats = json.loads(out.output)
    assert 0 < stats["triangles"] <= 3000
