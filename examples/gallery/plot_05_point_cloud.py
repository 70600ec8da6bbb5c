"""
A lidar point cloud: the point quadtree
=======================================

``autzen_trim.laz`` (110,000 lidar points over Autzen stadium, Oregon, in feet) read as
scattered data points, and drawn through the point quadtree of Feng & Qi (seed paper 003):
the square around the points is split while a node holds more than δ = 50 points, the
quadtree restricted so that neighbouring leaves differ by at most one level, and each leaf
records the order in which its points are inserted, largest error first. A view refines
nodes while their projected error exceeds α, and the drawn leaves insert their points until
they are within it.

Left, the ground (LAS class 2, 26,107 points); right, every point (buildings and trees
included). The same as ``approxtree build autzen_trim.laz --kind point-quadtree --out
autzen.zarr`` then ``approxtree render autzen.zarr --out autzen.png``.
"""

# %%
from _gallery import data_file, placeholder, show

import approxtree as at
from approxtree.render import framing_camera

laz = data_file("lidar/autzen_trim.laz")
if laz is None:
    placeholder("Lidar data absent (shared/data/lidar): no picture")
else:
    clouds = {
        "ground (class 2)": at.open_terrain(laz, ground_only=True),
        "all points": at.open_terrain(laz),
    }
    size = (640, 400)
    images, titles = [], []
    for name, points in clouds.items():
        quadtree = at.PointQuadtree(points, max_points=50)
        with at.Engine(quadtree) as engine:
            camera = framing_camera(quadtree.bboxes[0], engine.scale, size)
            frame = engine.render(camera, size, at.Cut(alpha=1.0), style=at.Style(background="sky"))
        print(name, quadtree.stats(), frame.stats["triangles"], "triangles drawn")
        images.append(frame.image)
        titles.append(f"{name}: {len(points.vertices):,} points")
    show(images, titles)
