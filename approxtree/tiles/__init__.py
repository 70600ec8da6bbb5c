"""Web tiles: the terrain as the tilesets web clients stream.

- ``quantized_mesh``: Cesium terrain (``layer.json`` + ``z/x/y.terrain``), one greedy TIN per
  tile of Cesium's geographic tiling, each within its level's geometric error.
- ``tileset3d``: OGC 3D Tiles 1.1 (``tileset.json`` + one GLB per node of an approximation
  tree, geometricError = the node's exact error plus its content's quantization bound;
  explicit or implicit tiling); ``tile_content``: a node's GLB (float32, Draco or meshopt,
  ``lattice``); ``implicit``: quadtree addresses and subtree files; ``earth``: terrain
  coordinates → ECEF.
- ``terrain3d``: the quantized-mesh TINs as the implicit 3D Tiles CesiumJS's
  Cesium3DTilesTerrainProvider reads as terrain.
- ``imagery`` (a texture pyramid) and ``raster_dem`` (Terrarium, Terrain-RGB) map tiles in
  the tilings of ``schemes`` (geographic TMS, Web Mercator XYZ), written by ``map_tiles`` to a
  folder or a PMTiles archive; ``web_maps`` opens them by format name.
- ``serve``: the ASGI app making every one of them on request from a tree store.
"""

from approxtree.tiles.earth import EarthFrame
from approxtree.tiles.quantized_mesh import write_quantized_mesh
from approxtree.tiles.terrain3d import check_terrain_options, write_3dtiles_terrain
from approxtree.tiles.tileset3d import write_3dtiles

__all__ = [
    "EarthFrame",
    "check_terrain_options",
    "write_3dtiles",
    "write_3dtiles_terrain",
    "write_quantized_mesh",
]
