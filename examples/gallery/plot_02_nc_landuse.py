"""
North Carolina: land use and streams over the shading
=====================================================

The cartographic case of the core paper: a 30 m DEM (500 × 450 cells), a land-use raster of
10 m cells (GRASS's landclass96 legend) and 8,294 stream lines, baked into one texture
pyramid (hillshade × land use, streams on top, water drawn over them) and rendered from the
tree. The same as::

    approxtree build nc/elev_ned_30m.tif --out nc.zarr
    approxtree bake nc/elev_ned_30m.tif --thematic nc/landuse_r.tif --palette landclass96 \\
        --lines nc/streams.shp --out nc_lu
    approxtree render nc.zarr --textures nc_lu --out nc.png
"""

# %%
from _gallery import WORK, data_file, placeholder, show

import approxtree as at
from approxtree.render import Camera, framing_camera
from approxtree.textures.bake import bake

dem = data_file("nc/elev_ned_30m.tif")
if dem is None:
    placeholder("North Carolina data absent (shared/data/nc): no picture")
else:
    terrain = at.open_terrain(dem)
    tree = at.ApproximationTree.build(terrain, epsilon=1.0)
    baked = bake(
        terrain,
        WORK / "nc_landuse",
        thematic=dem.with_name("landuse_r.tif"),
        palette="landclass96",
        overlays=[dem.with_name("streams.shp")],
    )
    print(tree.stats())
    print(baked.figures())

# %%
# The fitted overview, and a low oblique view from the south-west with the relief
# exaggerated five times (100 m of relief over 15 km).
if dem is not None:
    size = (800, 450)
    with at.Engine(tree, textures=baked.pyramid) as engine:
        overview = framing_camera(tree.bboxes[0], engine.scale, size)
        frame = engine.render(
            overview, size, at.Cut(alpha=1.0, gamma=2.0), style=at.Style(background="sky")
        )
    with at.Engine(tree, textures=baked.pyramid, exaggeration=5.0) as engine:
        low = Camera.look_at((634000, 211500, 1800), (639000, 221000, 0), fov=45.0)
        oblique = engine.render(
            low, size, at.Cut(alpha=1.0, gamma=2.0), style=at.Style(background="sky")
        )
    show(
        [frame.image, oblique.image],
        ["fitted overview", "from the south-west, exaggeration × 5"],
    )
