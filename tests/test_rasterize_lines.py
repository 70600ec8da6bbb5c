"""Line overlays: buffering part by part near the lattice burns the texels a whole-layer buffer
burns."""

from __future__ import annotations

import numpy as np
import pyogrio
import shapely
from affine import Affine
from conftest import data_file
from rasterio.features import rasterize

from approxtree.textures.thematic import rasterize_lines


def test_parts_near_the_lattice_burn_what_the_whole_layer_burns(data_dir) -> None:
    """NC's streams over a window of the NC lattice (lines crossing its edges), at three widths:
    the same texels as the whole layer buffered at once and burnt."""
    streams = data_file(data_dir, "nc/streams.shp")
    _, _, wkb, _ = pyogrio.raw.read(streams, read_geometry=True, columns=[])
    whole = shapely.from_wkb(wkb)
    crs = pyogrio.read_info(streams)["crs"]
    # A 300 × 400 window of 10 m texels inside the layer's extent.
    x0, _, _, y1 = shapely.total_bounds(whole)
    transform = Affine(10.0, 0.0, x0 + 2000.0, 0.0, -10.0, y1 - 3000.0)
    for width in (None, 25.0, 120.0):
        mine = rasterize_lines(streams, transform, (300, 400), crs, width=width)
        w = 10.0 if width is None else width
        expected = rasterize(
            [(shapely.buffer(g, w / 2.0), 1) for g in whole],
            out_shape=(300, 400),
            transform=transform,
            fill=0,
            dtype="uint8",
        )
        assert expected.any() and not expected.all()
        np.testing.assert_array_equal(mine.valid, expected > 0)
