"""Node: a light view of one node of an ApproximationTree (the tree keeps flat arrays)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from approxtree.geometry.rect import Rect
from approxtree.patches.base import GeometryPatch

if TYPE_CHECKING:
    from approxtree.tree.approximation_tree import ApproximationTree


class Node:
    """Node N: rectangle D_N, geometry patch T_N, error ε_T(N), box B_N, level, children."""

    __slots__ = ("index", "tree")

    def __init__(self, tree: ApproximationTree, index: int) -> None:
        self.tree = tree
        self.index = int(index)

    @property
    def rect(self) -> Rect:
        """D_N in world units."""
        return Rect(*(float(v) for v in self.tree.rects[self.index]))

    @property
    def error(self) -> float:
        """ε_T(N): exact max vertical distance between T and T_N over the data points of D_N."""
        return float(self.tree.errors[self.index])

    @property
    def bbox(self) -> tuple[float, float, float, float, float, float]:
        """B_N as (xmin, ymin, zmin, xmax, ymax, zmax); z is NaN for a node without data."""
        return tuple(float(v) for v in self.tree.bboxes[self.index])  # type: ignore[return-value]

    @property
    def level(self) -> int:
        return int(self.tree.levels[self.index])

    @property
    def strategy(self) -> str:
        return self.tree.strategy_names[int(self.tree.strategies[self.index])]

    @property
    def patch(self) -> GeometryPatch:
        """T_N, loaded from the tree file on first access when the tree was loaded lazily."""
        return self.tree.patch(self.index)

    @property
    def parent(self) -> Node | None:
        p = int(self.tree.parents[self.index])
        return None if p < 0 else Node(self.tree, p)

    @property
    def children(self) -> list[Node]:
        start = int(self.tree.child_start[self.index])
        count = int(self.tree.child_count[self.index])
        return [Node(self.tree, start + k) for k in range(count)]

    @property
    def is_leaf(self) -> bool:
        return int(self.tree.child_count[self.index]) == 0

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Node) and other.tree is self.tree and other.index == self.index

    def __hash__(self) -> int:
        return hash((id(self.tree), self.index))

    def __repr__(self) -> str:
        return (
            f"Node({self.index}, level={self.level}, strategy={self.strategy!r}, "
            f"error={self.error:g}, children={int(self.tree.child_count[self.index])})"
        )
