"""The store room's front door: every saved tree is opened and written through here.

- ``open_store(path)``: the ``TreeSource`` of a saved tree, whatever its format: a tree store
  (a folder ``NAME.zarr``, a zip ``NAME.zarr.zip``, an fsspec URL: ``tree_store``) or a legacy
  .atree file (read only: ``atree``); its meta data checked (a terrain kind and strategies this
  version knows).
- ``save(tree, path)``: the tree as a tree store, written atomically; a .atree path is refused
  (that format is read only now: ``approxtree convert OLD.atree NEW.zarr`` copies one).

The tree classes build themselves from a TreeSource (``ApproximationTree.from_source``,
``PointQuadtree.from_source``) and never look at formats; ``tree.loading.load_tree`` opens a
saved tree of either kind. The room, bottom up: ``zarr_store`` (locations, atomic writing,
checksummed reading), ``tree_store`` (a tree's layout in a store), ``atree`` (the legacy
reader), this module.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from approxtree.errors import StoreError
from approxtree.geometry import TERRAIN_TYPES
from approxtree.geometry.base import GeometryData
from approxtree.patches import STRATEGIES
from approxtree.patches.records import Batch
from approxtree.tree.atree import TreeFile, is_legacy_file, refuse_legacy_target
from approxtree.tree.tree_store import TreeStoreSource, save_quadtree, save_tree
from approxtree.tree.zarr_store import StoreReader

if TYPE_CHECKING:
    from approxtree.tree.approximation_tree import ApproximationTree
    from approxtree.tree.point_quadtree import PointQuadtree


class TreeSource(Protocol):
    """A saved tree opened for reading (``TreeStoreSource``, ``TreeFile``).

    meta: the tree's meta data (tree_kind, terrain_kind, params, strategy_names, library).
    Every array read is checked against its checksum; ``verify`` checks them all now.
    """

    location: str
    meta: dict[str, Any]

    @property
    def tree_kind(self) -> str:
        """The tree kind: "approximation_tree" or "point_quadtree"."""
        ...

    def terrain(self) -> GeometryData:
        """The terrain the tree was built over."""
        ...

    def node_arrays(self) -> dict[str, np.ndarray]:
        """An approximation tree's node table: rects (n, 4), errors (n,), bboxes (n, 6),
        levels, parents, child_start, child_count, strategies (n,)."""
        ...

    def quadtree_arrays(self) -> dict[str, np.ndarray]:
        """A point quadtree's arrays (``PointQuadtree.to_sections``)."""
        ...

    def patch_record(self, i: int) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """({}, arrays) of node i's patch record (``GeometryPatch.to_record``)."""
        ...

    def records(self, nodes: np.ndarray, strategy: str) -> Batch:
        """The patch records of ``nodes`` (k,), all of one strategy, as one batch."""
        ...

    def verify(self) -> None:
        """StoreError now if any patch or node array fails its checksum."""
        ...


#: Tree kind → the writer of its layout in a store.
_WRITERS: dict[str, Callable[[Any, str | os.PathLike], int]] = {
    "approximation_tree": save_tree,
    "point_quadtree": save_quadtree,
}


def open_store(path: str | os.PathLike) -> TreeSource:
    """The saved tree at ``path`` opened for reading: a tree store or a legacy .atree file.

    StoreError when it is missing, damaged, of an unknown format version, or holds a terrain
    kind or strategies this version does not know.
    """
    source: TreeSource
    if is_legacy_file(path):
        source = TreeFile(path)
    else:
        source = TreeStoreSource(StoreReader(path))
    kind = source.meta.get("terrain_kind")
    if kind not in TERRAIN_TYPES:
        raise StoreError(f"{path} holds an unknown terrain kind {kind!r}.")
    if source.tree_kind == "approximation_tree":
        unknown = set(source.meta.get("strategy_names", [])) - set(STRATEGIES)
        if unknown:
            raise StoreError(f"{path} uses strategies unknown to this version: {sorted(unknown)}.")
    return source


def save(tree: ApproximationTree | PointQuadtree, path: str | os.PathLike) -> int:
    """Write ``tree`` (terrain included) as a tree store at ``path`` atomically; returns the
    bytes stored. InvalidParameterError for a .atree path."""
    refuse_legacy_target(path)
    return _WRITERS[tree.tree_kind](tree, path)
