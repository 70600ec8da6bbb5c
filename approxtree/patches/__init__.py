"""Geometry patches = approximation strategies, registered by name for policies and tree files."""

from approxtree.patches.base import GeometryPatch
from approxtree.patches.grid import GridPatch
from approxtree.patches.nonregular import NonRegularGridPatch
from approxtree.patches.rtin import RTINPatch
from approxtree.patches.table import Strategy, TINPatch, patch_class

#: Strategy name → patch class by name; the class that builds a strategy on a given data type
#: is ``patch_class``'s, from the strategy table (``patches.table``).
STRATEGIES: dict[str, Strategy] = {
    GridPatch.kind: GridPatch,
    TINPatch.kind: TINPatch,
    RTINPatch.kind: RTINPatch,
    NonRegularGridPatch.kind: NonRegularGridPatch,
}

__all__ = [
    "STRATEGIES",
    "GeometryPatch",
    "GridPatch",
    "NonRegularGridPatch",
    "RTINPatch",
    "Strategy",
    "TINPatch",
    "patch_class",
]
