"""approxtree: real-time terrain visualization with approximation trees."""

from approxtree._version import __version__
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

#: Names of approxtree.tree: its patches and kernels cost a third of the import, and commands
#: that never build nor load a tree (bake, mesh of a DEM) do without them.
_TREE_NAMES = ("ApproximationTree", "Node", "PointQuadtree", "StrategyPolicy", "load_tree")


def _notebook_png(obj: object) -> bytes | None:
    from approxtree.notebook import repr_png

    return repr_png(obj)


def _register_notebook_formatters() -> None:
    """Inside IPython (a notebook), show trees and terrains as PNG previews
    (``approxtree.notebook``); the classes are named, nothing heavy is imported here."""
    import sys

    ipython = sys.modules.get("IPython")
    ip = ipython.get_ipython() if ipython is not None else None
    if ip is None:
        return
    png = ip.display_formatter.formatters["image/png"]
    for module, name in (
        ("approxtree.tree.approximation_tree", "ApproximationTree"),
        ("approxtree.tree.point_quadtree", "PointQuadtree"),
        ("approxtree.geometry.base", "GeometryData"),
    ):
        png.for_type_by_name(module, name, _notebook_png)


_register_notebook_formatters()


def __getattr__(name: str):
    if name in _TREE_NAMES:
        from approxtree import tree

        return getattr(tree, name)
    # The readers pull in rasterio, laspy and friends: import them on first use only.
    if name == "open_terrain":
        from approxtree.io import open_terrain

        return open_terrain
    # verify reads every output format (zarr, pygltflib, pyproj): on first use only.
    if name == "verify":
        from approxtree.verify import verify

        return verify
    # The renderer pulls in pyrr, and the Engine moderngl: import them on first use too.
    if name in ("Camera", "Cut", "Engine", "Frame", "FrameState", "Paging", "Style"):
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
    "Cut",
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
    "Paging",
    "PointQuadtree",
    "Rect",
    "StoreError",
    "StrategyPolicy",
    "Style",
    "TINPointSet",
    "TerrainDataWarning",
    "TerrainFormatError",
    "UnsupportedStrategyError",
    "WholeBandError",
    "__version__",
    "load_tree",
    "open_terrain",
    "verify",
]
