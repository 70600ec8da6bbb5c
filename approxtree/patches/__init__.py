"""Geometry patches = approximation strategies, registered by name for policies and tree files."""

from approxtree.patches.base import GeometryPatch
from approxtree.patches.grid import GridPatch
from approxtree.patches.nonregular import NonRegularGridPatch
from approxtree.patches.rtin import RTINPatch
from approxtree.patches.tin import TINPatch

#: Strategy name → patch class. A new strategy is one new GeometryPatch subclass added here.
STRATEGIES: dict[str, type[GeometryPatch]] = {
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
    "TINPatch",
]
