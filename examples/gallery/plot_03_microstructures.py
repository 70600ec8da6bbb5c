"""
A hybrid tree: river-bed microstructures in a grid
==================================================

The core paper's case study: a terrain grid refined by TIN *microstructures* — here corridors
30 m wide along North Carolina's streams, incised 2 m at the centre line and sampled every
15 m. The data points are the grid points outside every corridor plus the corridor vertices,
and every node's error is measured against that combined surface. With the ``auto`` policy
each node keeps the smallest patch that meets ε: grid patches where the ground is plain,
TINs where river beds cross it; in wireframe the river beds show as dense ribbons of
triangles.

A 150 × 150-cell window of the DEM (4.5 km square) keeps the build short; the command line
builds the whole DEM with ``approxtree build nc/elev_ned_30m.tif --microstructures
nc/streams.shp --microstructure-width 30 --microstructure-spacing 15 --out nc.zarr``.
"""

# %%
import shapely
from _gallery import data_file, placeholder, show

import approxtree as at
from approxtree.io.microstructures import corridor_microstructures, read_lines
from approxtree.render import Camera

dem = data_file("nc/elev_ned_30m.tif")
if dem is None:
    placeholder("North Carolina data absent (shared/data/nc): no picture")
else:
    grid = at.open_terrain(dem).window(150, 300, 150, 300)
    d = grid.domain
    # The streams that cross the window, as corridor TINs on the window's grid.
    lines = read_lines(dem.with_name("streams.shp"), grid.crs)
    lines = lines[shapely.intersects(lines, shapely.box(d.xmin, d.ymin, d.xmax, d.ymax))]
    rivers = corridor_microstructures(grid, lines, width=30.0, spacing=15.0)
    tree = at.ApproximationTree.build(grid, epsilon=1.0, microstructures=rivers, policy="auto")
    print(f"{len(lines)} streams, {len(rivers)} microstructure TINs")
    print(tree.stats())

# %%
# The same low view twice: shaded, and in wireframe (α = 2 px). Skirts are left out of the
# wireframe so that only patch triangles show.
if dem is not None:
    size = (800, 500)
    cx, cy = (d.xmin + d.xmax) / 2, (d.ymin + d.ymax) / 2
    camera = Camera.look_at((cx - 300, cy - 2000, 900), (cx, cy - 300, 80), fov=45.0)
    with at.Engine(tree, exaggeration=3.0) as engine:
        shaded = engine.render(camera, size, at.Cut(alpha=2.0), style=at.Style(background="sky"))
    with at.Engine(tree, exaggeration=3.0, skirts=False) as engine:
        wire = engine.render(
            camera, size, at.Cut(alpha=2.0), style=at.Style(wireframe=True, background="white")
        )
    print(shaded.stats["patches"], "patches,", shaded.stats["triangles"], "triangles")
    show(
        [shaded.image, wire.image],
        ["shaded (exaggeration × 3)", "wireframe: river beds as dense TINs"],
    )
