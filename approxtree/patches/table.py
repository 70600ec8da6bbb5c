"""The strategy table: terrain type × strategy name → patch class.

A strategy name (``grid``, ``tin``, ``rtin``, ``nonregular``) names one approximation method;
the class that runs it depends on the terrain's data type (a greedy TIN over a Grid keeps grid
indices, over scattered points point indices). This one table says which, so builders, tree
loading and ``approximate`` look a class up instead of testing data types one by one. A new
strategy or data type is one more row here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from approxtree.errors import InvalidParameterError, UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.geometry.refinement import GridRefinement
from approxtree.geometry.tin import TIN
from approxtree.patches.base import GeometryPatch
from approxtree.patches.grid import GridPatch
from approxtree.patches.nonregular import NonRegularGridPatch
from approxtree.patches.refined import RefinedTINPatch
from approxtree.patches.rtin import RTINPatch
from approxtree.patches.tin import GridTINPatch
from approxtree.patches.tin_points import PointTINPatch

#: (terrain type, strategy name) → the patch class building that strategy on that data type.
#: Subclasses of a terrain type share its rows (a TINPointSet is a TIN).
PATCH_TABLE: dict[tuple[type[GeometryData], str], type[GeometryPatch]] = {
    (Grid, "grid"): GridPatch,
    (GridRefinement, "grid"): GridPatch,
    (Grid, "tin"): GridTINPatch,
    (TIN, "tin"): PointTINPatch,
    (GridRefinement, "tin"): RefinedTINPatch,
    (Grid, "rtin"): RTINPatch,
    (Grid, "nonregular"): NonRegularGridPatch,
}

#: Strategy names, in the order ``auto`` tries them.
STRATEGY_NAMES: tuple[str, ...] = ("grid", "tin", "rtin", "nonregular")

#: The strategy made for each data type (the ``type`` policy); GridRefinement mixes tin near
#: its microstructures and grid elsewhere (``tree.policy``), other types try every strategy.
TYPE_STRATEGY: dict[type[GeometryData], str] = {Grid: "grid", TIN: "tin"}

_TYPE_WORDS = {Grid: "regular Grid", TIN: "TIN or TINPointSet", GridRefinement: "GridRefinement"}


def patch_class(terrain: GeometryData | type[GeometryData], name: str) -> type[GeometryPatch]:
    """The patch class of strategy ``name`` on ``terrain`` (a terrain or its type).

    Raises InvalidParameterError for an unknown name and UnsupportedStrategyError, naming the
    data types the strategy accepts, for a known strategy that cannot build this data type.
    """
    kind = terrain if isinstance(terrain, type) else type(terrain)
    for cls in kind.__mro__:
        found = PATCH_TABLE.get((cls, name))
        if found is not None:
            return found
    if name not in STRATEGY_NAMES:
        raise InvalidParameterError(
            f"Unknown strategy {name!r}; choose one of: {', '.join(STRATEGY_NAMES)}."
        )
    accepted = [_TYPE_WORDS.get(t, t.__name__) for (t, n) in PATCH_TABLE if n == name]
    raise UnsupportedStrategyError(
        f"The {name} strategy needs a {' or '.join(accepted)}, got a {kind.__name__}; "
        "choose a strategy made for this data type (tin for scattered points)."
    )


def type_strategy(terrain: GeometryData) -> str | None:
    """The strategy made for the terrain's data type, None when the table names none."""
    for cls in type(terrain).__mro__:
        if cls in TYPE_STRATEGY:
            return TYPE_STRATEGY[cls]
    return None


class Strategy(Protocol):
    """A strategy by name (``patches.STRATEGIES``): a patch class, or a class such as
    ``TINPatch`` that hands each call to the table's class for the terrain."""

    @property
    def kind(self) -> str: ...

    def build_many(
        self, terrain: GeometryData, rects: Sequence[Rect], max_points: int, epsilon: float = 0.0
    ) -> Sequence[GeometryPatch]: ...

    def build_level(
        self, terrain: GeometryData, rects: np.ndarray, max_points: int, epsilon: float = 0.0
    ) -> Sequence[GeometryPatch]: ...

    def from_record(
        self, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> GeometryPatch: ...


class TINPatch(GeometryPatch):
    """The ``tin`` strategy by name: greedy insertion TIN, ``GridTINPatch`` on grids,
    ``PointTINPatch`` on point sets, ``RefinedTINPatch`` on refined grids (see the table)."""

    kind = "tin"

    @classmethod
    def build_many(
        cls,
        terrain: GeometryData,
        rects: Sequence[Rect],
        max_points: int,
        epsilon: float = 0.0,
    ) -> Sequence[GeometryPatch]:
        return patch_class(terrain, cls.kind).build_many(terrain, rects, max_points, epsilon)

    @classmethod
    def build_level(
        cls,
        terrain: GeometryData,
        rects: np.ndarray,
        max_points: int,
        epsilon: float = 0.0,
    ) -> Sequence[GeometryPatch]:
        return patch_class(terrain, cls.kind).build_level(terrain, rects, max_points, epsilon)

    @classmethod
    def from_record(
        cls, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> GeometryPatch:
        return patch_class(terrain, cls.kind).from_record(terrain, rect, record)
