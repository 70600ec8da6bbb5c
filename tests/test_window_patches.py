"""Patches built on a window of a grid equal those built on the full grid, records included.

A blocked build builds each block's nodes on the window of its rectangle, so a patch's record
must hold the full raster's indices, and ``from_record`` on the full grid must rebuild it.
"""

import numpy as np
import pytest
from affine import Affine

from approxtree.geometry import Grid
from approxtree.patches import STRATEGIES

STRATEGY_NAMES = ["grid", "nonregular", "rtin", "tin"]


def _grid() -> Grid:
    rng = np.random.default_rng(7)
    z = np.cumsum(np.cumsum(rng.normal(size=(71, 83)), 0), 1).astype(np.float32) * 0.1
    z[40:47, 10:30] = np.nan
    return Grid(z, Affine(0.5, 0, 512345.25, 0, -0.5, 4123456.75))


def _assert_same(a, b) -> None:
    assert a.kind == b.kind
    assert a.error == b.error
    np.testing.assert_array_equal(a.z_range, b.z_range)
    assert a.data_count == b.data_count
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.triangles, b.triangles)
    ra, rb = a.to_record(), b.to_record()
    assert ra.keys() == rb.keys()
    for key in ra:
        np.testing.assert_array_equal(ra[key], rb[key], err_msg=key)


@pytest.mark.parametrize("name", STRATEGY_NAMES)
def test_patch_on_window_equals_patch_on_full_grid(name):
    g = _grid()
    # A node rectangle over nodata and data, and a window reaching beyond it on every side.
    rect = g.rect_of(30, 62, 5, 50)
    window = g.window(25, 70, 2, 60)
    cls = STRATEGIES[name]
    full = cls.build(g, rect, 400, 0.05)
    local = cls.build(window, rect, 400, 0.05)
    assert 0 < len(full.vertices) < full.data_count
    _assert_same(local, full)
    # The record of the window's patch rebuilds the same patch on the full grid and back.
    _assert_same(cls.from_record(g, rect, local.to_record()), full)
    _assert_same(cls.from_record(window, rect, full.to_record()), full)


def test_refined_grid_patch_records_are_global():
    from approxtree.geometry import TIN, GridRefinement

    g = _grid()
    window = g.window(20, 70, 0, 82)
    xs, ys = g.x_coords[[40, 60, 50]], g.y_coords[[30, 30, 50]]
    tin = TIN(np.column_stack([xs, ys, [1.0, 2.0, 3.0]]), np.array([[0, 1, 2]]))
    refined = GridRefinement(g, [tin])
    rect = g.rect_of(25, 60, 30, 70)
    full = STRATEGIES["grid"].build(refined, rect, 9 * 9)
    local = STRATEGIES["grid"].build(window, rect, 9 * 9)
    rec_full, rec_local = full.to_record(), local.to_record()
    np.testing.assert_array_equal(rec_full["index"], rec_local["index"])
    back = STRATEGIES["grid"].from_record(refined, rect, rec_local)
    np.testing.assert_array_equal(back.vertices, full.vertices)
