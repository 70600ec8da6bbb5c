"""load_tree: open any saved tree (a tree store or a legacy .atree), whichever kind it holds."""

from __future__ import annotations

import os

from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.point_quadtree import TREE_KIND, PointQuadtree
from approxtree.tree.store import open_store


def load_tree(path: str | os.PathLike, verify: bool = True) -> ApproximationTree | PointQuadtree:
    """The tree in a tree store (``NAME.zarr``, ``.zip``, URL) or a legacy .atree file: an
    ApproximationTree, or a PointQuadtree (tree kind "point_quadtree"). verify: check every
    patch's checksum now (approximation trees; a point quadtree's are always checked)."""
    source = open_store(path)
    if source.tree_kind == TREE_KIND:
        return PointQuadtree.from_source(source)
    return ApproximationTree.from_source(source, verify=verify)


def tree_epsilon(path: str | os.PathLike) -> float | None:
    """The threshold ε a saved tree (store or legacy .atree) was built with; None when it
    records none (the CLI's ``tiles`` and ``serve`` take it as the quantized-mesh leaf error)."""
    eps = (open_store(path).meta.get("params") or {}).get("epsilon")
    return float(eps) if eps else None
