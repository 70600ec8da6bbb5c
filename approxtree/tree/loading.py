"""load_tree: open any tree (a tree store or a legacy .atree), whichever kind it holds."""

from __future__ import annotations

import os

from approxtree.tree.approximation_tree import ApproximationTree
from approxtree.tree.point_quadtree import TREE_KIND, PointQuadtree
from approxtree.tree.store import TreeFile, is_legacy_file


def load_tree(path: str | os.PathLike, verify: bool = True) -> ApproximationTree | PointQuadtree:
    """The tree in a tree store (``NAME.zarr``, ``.zip``, URL) or a legacy .atree file: an
    ApproximationTree, or a PointQuadtree (tree kind "point_quadtree"). verify: check every
    patch's checksum now (approximation trees)."""
    if not is_legacy_file(path):
        from approxtree.tree.tree_store import load_quadtree_store, load_tree_store
        from approxtree.tree.zarr_store import StoreReader

        # check=False: the loader below opens the store again and checks its chunks then.
        if StoreReader(path).meta.get("tree_kind") == TREE_KIND:
            return load_quadtree_store(path)
        return load_tree_store(path, verify=verify)
    if TreeFile(path).meta.get("tree_kind") == TREE_KIND:
        return PointQuadtree.load(path)
    return ApproximationTree.load(path, verify=verify)


def tree_epsilon(path: str | os.PathLike) -> float | None:
    """The threshold ε a saved tree (store or legacy .atree) was built with; None when it
    records none (the CLI's ``tiles`` and ``serve`` take it as the quantized-mesh leaf error)."""
    if is_legacy_file(path):
        tree = load_tree(path)
        return float(tree.epsilon) if isinstance(tree, ApproximationTree) else None
    from approxtree.tree.zarr_store import StoreReader

    eps = (StoreReader(path).meta.get("params") or {}).get("epsilon")
    return float(eps) if eps else None
