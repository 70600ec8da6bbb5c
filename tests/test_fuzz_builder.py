"""Property-based fuzzing of ApproximationTree.build (hypothesis; cases in tests/fuzzing.py).

Small grids with NaN, ±inf and huge heights, random georeference, ε, max points s, fanout d
and policy: the build returns a tree with finite errors whose leaves meet ε (unless a leaf is a
single cell), or raises an ApproxTreeError subclass. Fixed, derandomized CI profile.
"""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from fuzzing import build_case, builder_case, fuzz_settings, warm_up_builder
from hypothesis import given

#: Cases per CI run.
CI_CASES = 1000


def test_fuzz_builder():
    """Random small grids and parameters: a valid tree or an ApproxTreeError."""
    warm_up_builder()

    @fuzz_settings(CI_CASES)
    @given(builder_case())
    def case(builder_case):
        outcomes[build_case(builder_case)] += 1

    outcomes: Counter[str] = Counter()
    case()
    # The cases exercise both sides: trees built and parameters or grids refused.
    print(dict(outcomes))
    assert outcomes["ok"] >= CI_CASES // 4 and outcomes.total() - outcomes["ok"] >= CI_CASES // 10


# -- regressions found by the fuzzing above ----------------------------------------------------


@pytest.mark.parametrize("policy", ["tin", "rtin", "nonregular"])
def test_far_origin_small_cells(policy):
    """Cells of 1 cm..5 m at x, y ≈ 1e9: every leaf is exact at ε = 0 (was: leaves of error inf
    or UnsupportedStrategyError, as border points fell out of their nodes by round-off)."""
    from affine import Affine

    from approxtree.geometry import Grid
    from approxtree.tree import ApproximationTree

    rng = np.random.default_rng(0)
    for _ in range(12):
        rows, cols, cell = int(rng.integers(2, 10)), int(rng.integers(2, 10)), rng.uniform(0.01, 5)
        heights = rng.normal(size=(rows, cols)).astype(np.float32)
        grid = Grid(heights, Affine(cell, 0, 1e9, 0, -cell, 1e9 + rows * cell))
        for fanout in (2, 4):
            tree = ApproximationTree.build(
                grid, epsilon=0.0, max_points=int(rng.integers(4, 50)), fanout=fanout,
                policy=policy, progress=False,
            )  # fmt: skip
            leaves = np.asarray(tree.child_count) == 0
            assert np.all(np.asarray(tree.errors)[leaves] == 0.0)
            assert sum(len(tree.node(int(i)).patch.vertices) > 0 for i in np.flatnonzero(leaves))


def test_unresolvable_cells_refused():
    """Cells that float64 cannot tell apart at the grid's coordinates are a TerrainFormatError."""
    from affine import Affine

    from approxtree.errors import TerrainFormatError
    from approxtree.geometry import Grid

    with pytest.raises(TerrainFormatError, match="too small for float64"):
        Grid(np.zeros((2, 2), np.float32), Affine(1.21875, 0, 1e15, 0, -1.21875, 1e15 + 2.4375))
