"""load_tree: open any tree file (.atree), whichever kind of tree it holds."""

from __future__ import annotations

import os

from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.point_quadtree import TREE_KIND, PointQuadtree
from approxtree.tree.store import TreeFile


def load_tree(path: str | os.PathLike, verify: bool = True) -> ApproximationTree | PointQuadtree:
    """The tree in a .atree file: an ApproximationTree, or a PointQuadtree (tree kind
    "point_quadtree"). verify: check every patch's checksum now (approximation trees)."""
    if TreeFile(path).meta.get("tree_kind") == TREE_KIND:
        return PointQuadtree.load(path)
    return ApproximationTree.load(path, verify=verify)
