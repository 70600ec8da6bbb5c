"""approxtree: real-time terrain visualization with approximation trees."""

from approxtree.errors import (
    ApproxTreeError,
    ApproxTreeWarning,
    ContextUnavailableError,
    EmptyTerrainError,
    InvalidParameterError,
    StoreError,
    TerrainDataWarning,
    TerrainFormatError,
    UnsupportedStrategyError,
    WholeBandError,
)
from approxtree.geometry import (
    TIN,
    GeometryData,
    Grid,
    GridRefinement,
    NonRegularGrid,
    Rect,
    TINPointSet,
)

__version__ = "0.1.0"

#: Names of approxtree.tree: its patches and kernels cost a third of the import, and commands
#: that never build nor load a tree (bake, mesh of a DEM) do without them.
_TREE_NAMES = ("ApproximationTree", "Node", "PointQuadtree", "StrategyPolicy", "load_tree")


def __getattr__(name: str):
    if name in _TREE_NAMES:
        from approxtree import tree

        return getattr(tree, name)
    # The readers pull in rasterio, laspy and friends: import them on first use only.
    if name == "open_terrain":
        from approxtree.io import open_terrain

        return open_terrain
    # The renderer pulls in pyrr, and the Engine moderngl: import them on first use too.
    if name in ("Camera", "Engine", "Frame", "FrameState"):
        from approxtree import render

        return getattr(render, name)
    raise AttributeError(f"module 'approxtree' has no attribute {name!r}")


__all__ = [
    "TIN",
    "ApproxTreeError",
    "ApproxTreeWarning",
    "ApproximationTree",
    "Camera",
    "ContextUnavailableError",
    "EmptyTerrainError",
    "Engine",
    "Frame",
    "FrameState",
    "GeometryData",
    "Grid",
    "GridRefinement",
    "InvalidParameterError",
    "Node",
    "NonRegularGrid",
    "PointQuadtree",
    "Rect",
    "StoreError",
    "StrategyPolicy",
    "TINPointSet",
    "TerrainDataWarning",
    "TerrainFormatError",
    "UnsupportedStrategyError",
    "WholeBandError",
    "__version__",
    "load_tree",
    "open_terrain",
]
