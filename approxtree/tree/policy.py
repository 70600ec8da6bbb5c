"""StrategyPolicy: which approximation strategy (patch type) builds each node.

This version knows the fixed policies (one strategy for every node) and ``auto``, which picks
the strategy made for the terrain's data type (grid for a Grid, tin for a TIN or TINPointSet).
Policies by level and by data semantics plug in
here by overriding ``strategy_for``.
"""

from __future__ import annotations

from approxtree.errors import InvalidParameterError, UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.geometry.tin import TIN
from approxtree.patches import STRATEGIES, GeometryPatch


class StrategyPolicy:
    """Chooses the patch class of a node from the terrain, the node's level and rectangle."""

    def __init__(self, name: str = "auto") -> None:
        if name != "auto" and name not in STRATEGIES:
            known = ", ".join(["auto", *STRATEGIES])
            raise InvalidParameterError(f"Unknown policy {name!r}; choose one of: {known}.")
        self.name = name

    def strategy_for(self, terrain: GeometryData, level: int, rect: Rect) -> type[GeometryPatch]:
        """The patch class that builds the node at ``level`` covering ``rect``."""
        if self.name != "auto":
            return STRATEGIES[self.name]
        if isinstance(terrain, Grid):
            return STRATEGIES["grid"]
        if isinstance(terrain, TIN) and "tin" in STRATEGIES:
            return STRATEGIES["tin"]
        raise UnsupportedStrategyError(
            f"No approximation strategy for a {type(terrain).__name__} is available in this "
            f"version (strategies: {', '.join(STRATEGIES)}); convert the data to a regular grid."
        )

    @classmethod
    def resolve(cls, policy: str | StrategyPolicy) -> StrategyPolicy:
        """A policy object from a name or an existing policy."""
        return policy if isinstance(policy, StrategyPolicy) else cls(policy)
