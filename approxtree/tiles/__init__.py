"""Web tiles of an approximation tree: OGC 3D Tiles (tileset3d) and Cesium quantized-mesh.

- ``quantized_mesh``: Cesium terrain (``layer.json`` + ``z/x/y.terrain``), one greedy TIN per
  tile of Cesium's geographic tiling, each within its level's geometric error.
"""

from approxtree.tiles.earth import EarthFrame
from approxtree.tiles.quantized_mesh import write_quantized_mesh
from approxtree.tiles.tileset3d import write_3dtiles

__all__ = ["EarthFrame", "write_3dtiles", "write_quantized_mesh"]
