"""Web tiles of an approximation tree: OGC 3D Tiles (tileset3d) and Cesium quantized-mesh."""

from approxtree.tiles.earth import EarthFrame
from approxtree.tiles.tileset3d import write_3dtiles

__all__ = ["EarthFrame", "write_3dtiles"]
