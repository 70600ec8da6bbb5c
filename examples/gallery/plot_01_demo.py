"""
The demo: a tree, a baked hillshade, a fitted view
==================================================

What ``approxtree demo`` does, step by step in Python: build the approximation tree of the
sample terrain that ships with matplotlib (the Jacksboro fault DEM, 403 × 344 cells of 3″),
bake its hillshade into a texture pyramid, and render a fitted oblique overview offscreen.
"""

# %%
# Build the tree: every node's patch is within its exact error, leaves within ε = 1 m.
from _gallery import WORK, show

import approxtree as at
from approxtree.datasets import sample_terrain
from approxtree.render import framing_camera
from approxtree.textures.bake import bake

terrain = sample_terrain()
tree = at.ApproximationTree.build(terrain, epsilon=1.0)
print(terrain)
print(tree.stats())

# %%
# Bake the hillshade (gdaldem's Horn algorithm, on the GPU when there is one) into a
# pyramid of GeoTIFF levels.
baked = bake(terrain, WORK / "demo_textures")
print(baked.figures())

# %%
# Render the fitted overview: the baked shading over the hypsometric tints, a sky behind.
size = (960, 540)
with at.Engine(tree, textures=baked.pyramid) as engine:
    camera = framing_camera(tree.bboxes[0], engine.scale, size)
    frame = engine.render(
        camera, size, at.Cut(alpha=1.0, gamma=2.0), style=at.Style(background="sky")
    )
print({k: frame.stats[k] for k in ("patches", "triangles", "max_alpha", "texture_patches")})
show([frame.image], ["approxtree demo: Jacksboro fault, ε = 1 m, α = 1 px"])
