"""Approximation trees: nodes, subdivision schemes, strategy policies, builder and store."""

from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.loading import load_tree
from approxtree.tree.node import Node
from approxtree.tree.point_quadtree import PointQuadtree
from approxtree.tree.policy import StrategyPolicy
from approxtree.tree.subdivision import subdivide

__all__ = ["ApproximationTree", "Node", "PointQuadtree", "StrategyPolicy", "load_tree", "subdivide"]
