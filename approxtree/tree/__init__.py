"""Approximation trees: nodes, subdivision schemes, strategy policies, builder and store."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from approxtree.tree.approximation_tree import ApproximationTree
    from approxtree.tree.loading import load_tree
    from approxtree.tree.node import Node
    from approxtree.tree.point_quadtree import PointQuadtree
    from approxtree.tree.policy import StrategyPolicy
    from approxtree.tree.subdivision import subdivide

#: Where each name lives: imported on first use, so that importing a light submodule (the
#: store's ``zarr_store.is_store`` for a bake) does not import the builder, patches and kernels.
_NAMES = {
    "ApproximationTree": "approximation_tree",
    "load_tree": "loading",
    "Node": "node",
    "PointQuadtree": "point_quadtree",
    "StrategyPolicy": "policy",
    "subdivide": "subdivision",
}


def __getattr__(name: str):
    if name in _NAMES:
        return getattr(importlib.import_module(f"approxtree.tree.{_NAMES[name]}"), name)
    raise AttributeError(f"module 'approxtree.tree' has no attribute {name!r}")


__all__ = ["ApproximationTree", "Node", "PointQuadtree", "StrategyPolicy", "load_tree", "subdivide"]
