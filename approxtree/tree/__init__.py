"""Approximation trees: nodes, subdivision schemes, strategy policies, builder and store."""

from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.node import Node
from approxtree.tree.policy import StrategyPolicy
from approxtree.tree.subdivision import subdivide

__all__ = ["ApproximationTree", "Node", "StrategyPolicy", "subdivide"]
