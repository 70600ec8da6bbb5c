"""Strategy policies: fixed, by level, by data semantics and auto (smallest patch meeting ε)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from test_tree import check_invariants

from approxtree import ApproximationTree, InvalidParameterError
from approxtree.cli import main
from approxtree.datasets import fractal_terrain
from approxtree.patches import STRATEGIES
from approxtree.tree.policy import LevelPolicy, StrategyPolicy


@pytest.fixture(scope="module")
def terrain():
    return fractal_terrain(129, 161, seed=3, relief=300.0)


def test_level_policy_counts_match_levels(terrain):
    """level:grid@0-1,tin builds levels 0–1 with grid and all deeper nodes with tin."""
    tree = ApproximationTree.build(terrain, 2.0, 9 * 9, policy="level:grid@0-1,tin")
    check_invariants(tree, 2.0)
    names = np.array([tree.node(i).strategy for i in range(len(tree))])
    assert set(names[tree.levels <= 1]) == {"grid"}
    assert set(names[tree.levels >= 2]) == {"tin"}
    assert tree.strategy_counts == {
        "grid": int(np.count_nonzero(tree.levels <= 1)),
        "tin": int(np.count_nonzero(tree.levels >= 2)),
    }
    assert tree.stats()["strategies"] == tree.strategy_counts


def test_python_level_api_equals_the_parsed_form(terrain):
    """StrategyPolicy.by_level builds the same tree as its string form."""
    a = ApproximationTree.build(
        terrain, 2.0, 81, policy=StrategyPolicy.by_level({range(0, 2): "grid"}, default="tin")
    )
    b = ApproximationTree.build(terrain, 2.0, 81, policy="level:grid@0-1,tin")
    assert a.params["policy"] == b.params["policy"] == "level:grid@0-1,tin"
    np.testing.assert_array_equal(a.errors, b.errors)
    assert a.strategy_counts == b.strategy_counts


def test_auto_keeps_the_smallest_patch_meeting_epsilon(terrain):
    """auto: each node's patch is the smallest (nbytes) candidate with error ≤ ε, else the best."""
    eps, s = 2.0, 9 * 9
    tree = ApproximationTree.build(terrain, eps, s, policy="auto")
    assert len(tree.strategy_counts) >= 2
    assert sum(tree.strategy_counts.values()) == len(tree)
    for i in range(0, len(tree), max(1, len(tree) // 25)):
        node = tree.node(i)
        options = [STRATEGIES[n].build(terrain, node.rect, s, eps) for n in STRATEGIES]
        meeting = [p for p in options if p.error <= eps]
        assert node.patch.point_count <= s
        if meeting:
            assert node.error <= eps
            assert node.patch.nbytes == min(p.nbytes for p in meeting)
        else:
            assert node.error == min(p.error for p in options)


def test_auto_on_point_sets_drops_grid_only_strategies():
    """auto on scattered points builds with the strategies that accept them (tin)."""
    from approxtree import TINPointSet

    rng = np.random.default_rng(2)
    pts = np.column_stack([rng.uniform(0, 40, (200, 2)), rng.uniform(0, 3, 200)])
    tree = ApproximationTree.build(TINPointSet(pts), epsilon=0.5, max_points=32, policy="auto")
    assert set(tree.strategy_counts) == {"tin"}


@pytest.mark.parametrize(
    "text",
    [
        "level:grid@0-3",
        "level:grid@x-3,tin",
        "level:grid@3-1,tin",
        "level:nope@0,tin",
        "magic",
        "semantic:tin,grid",
        "semantic:tin@a,grid",
        "level:grid,tin",
    ],
)
def test_bad_policies_are_clear_errors(text):
    """Malformed or unknown policies raise InvalidParameterError saying what to write."""
    with pytest.raises(InvalidParameterError):
        StrategyPolicy.parse(text)


def test_parse_round_trips_names():
    """Parsed policies keep a canonical name, stored in the tree's params."""
    assert StrategyPolicy.parse("level:grid@0-3,rtin@4-5,tin").name == "level:grid@0-3,rtin@4-5,tin"
    assert StrategyPolicy.parse("semantic:tin@4,grid").name == "semantic:tin@4,grid"
    assert isinstance(StrategyPolicy.parse("level:tin@2-,grid"), LevelPolicy)


def test_cli_build_reports_strategy_counts(tmp_path, terrain):
    """build --policy level:... --json reports per-strategy node counts matching the file."""
    dem = tmp_path / "f.npy"
    np.save(dem, terrain.heights)
    out = tmp_path / "f.zarr"
    result = CliRunner().invoke(
        main,
        [
            "build",
            str(dem),
            "--out",
            str(out),
            "--epsilon",
            "2",
            "--max-points",
            "81",
            "--policy",
            "level:grid@0-1,tin",
            "--json",
        ],
    )
    assert result.exit_code == 0, result.output
    figures = json.loads(result.output)
    tree = ApproximationTree.load(out)
    assert figures["strategies"] == tree.strategy_counts
    assert set(figures["strategies"]) == {"grid", "tin"}
