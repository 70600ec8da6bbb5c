"""Grid.window: a sub-grid whose data points are bit-identical to the full grid's."""

import numpy as np
import pytest
from affine import Affine

from approxtree.errors import InvalidParameterError
from approxtree.geometry import Grid
from approxtree.geometry.rect import Rect


def _grid() -> Grid:
    rng = np.random.default_rng(3)
    z = rng.normal(size=(37, 53)).astype(np.float32)
    z[5:9, 40:50] = np.nan
    # Awkward cell sizes and a far origin make round-off visible if coordinates were rebased.
    return Grid(z, Affine(0.1 + 1e-9, 0, 612345.67, 0, -0.3, 4123456.89), "EPSG:32610")


def test_window_points_are_bit_identical():
    g = _grid()
    w = g.window(4, 30, 7, 49)
    assert w.index_offset == (4, 7)
    assert w.shape == (27, 43)
    np.testing.assert_array_equal(w.x_coords, g.x_coords[7:50])
    np.testing.assert_array_equal(w.y_coords, g.y_coords[4:31])
    assert w.domain == g.rect_of(4, 30, 7, 49)
    # The same rectangle finds the same points, in window and full grid alike.
    rect = Rect(*g.rect_of(6, 20, 10, 45).as_tuple())
    np.testing.assert_array_equal(w.points(rect), g.points(rect))
    r0, r1, c0, c1 = w.index_range(rect)
    assert (r0 + 4, r1 + 4, c0 + 7, c1 + 7) == g.index_range(rect)
    assert w.split_position(rect, 0) == g.split_position(rect, 0)
    assert w.split_position(rect, 1) == g.split_position(rect, 1)
    x, y = w.points(rect)[:, 0], w.points(rect)[:, 1]
    np.testing.assert_array_equal(w.height_at(x, y), g.height_at(x, y))


def test_window_of_a_window_and_record():
    g = _grid()
    ww = g.window(2, 30, 3, 50).window(1, 10, 2, 20)
    assert ww.index_offset == (3, 5)
    np.testing.assert_array_equal(ww.heights, g.heights[3:13, 5:24])
    back = Grid.from_record(*ww.to_record())
    assert back.index_offset == (3, 5)
    np.testing.assert_array_equal(back.x_coords, g.x_coords[5:24])


def test_window_of_nodata_only_and_outside():
    g = _grid()
    w = g.window(5, 8, 40, 49)
    assert w.point_count == 0
    assert np.isnan(w.z_range[0])
    with pytest.raises(InvalidParameterError):
        g.window(0, 40, 0, 5)
