"""Terrain data types: the GeometryData interface and its subclasses (pure numpy)."""

from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.nonregular import NonRegularGrid
from approxtree.geometry.rect import Rect
from approxtree.geometry.refinement import GridRefinement
from approxtree.geometry.tin import TIN, TINPointSet
from approxtree.geometry.windowed import ArraySource, HeightSource, WindowedHeights

#: Terrain kind (as stored in tree files) → class. A new data type is one new subclass here.
TERRAIN_TYPES: dict[str, type[GeometryData]] = {
    cls.__name__.lower(): cls for cls in (Grid, NonRegularGrid, TIN, TINPointSet, GridRefinement)
}

__all__ = [
    "TERRAIN_TYPES",
    "TIN",
    "ArraySource",
    "GeometryData",
    "Grid",
    "GridRefinement",
    "HeightSource",
    "NonRegularGrid",
    "Rect",
    "TINPointSet",
    "WindowedHeights",
]
