"""Web tiles: the terrain as the tilesets web clients stream.

- ``quantized_mesh``: Cesium terrain (``layer.json`` + ``z/x/y.terrain``), one greedy TIN per
  tile of Cesium's geographic tiling, each within its level's geometric error.
"""

from approxtree.tiles.quantized_mesh import write_quantized_mesh

__all__ = ["write_quantized_mesh"]
