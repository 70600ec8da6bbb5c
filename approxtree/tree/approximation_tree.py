"""ApproximationTree: the hierarchy A(s,d)(T) of geometry patches over one terrain.

The tree keeps its nodes in flat arrays (breadth-first order, children contiguous) so that
selection can run vectorized over many nodes; ``Node`` is a light view of one entry. Patches
are objects, read from the saved tree (its ``TreeSource``, ``tree.store``) on first access when
the tree was loaded.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.geometry import TIN, Grid, GridRefinement
from approxtree.geometry.base import GeometryData
from approxtree.geometry.dataarray import is_dataarray
from approxtree.geometry.rect import Rect
from approxtree.patches import GeometryPatch, patch_class
from approxtree.patches.records import Batch, concat_records
from approxtree.progress import ProgressCallback, as_callback
from approxtree.tree import store
from approxtree.tree.builder import BuiltLevels, build_levels
from approxtree.tree.cut_mesh import CutMesh, cut_mesh
from approxtree.tree.node import Node
from approxtree.tree.patch_table import PatchTable, as_table
from approxtree.tree.policy import StrategyPolicy
from approxtree.tree.store_regions import HeightRegions
from approxtree.tree.update import KEPT_CHANGES, TreeUpdate, compose_changes, update_tree


def with_microstructures(
    terrain: GeometryData, microstructures: Sequence[TIN | str | os.PathLike]
) -> GridRefinement:
    """The GridRefinement of a Grid by TINs, or by files (TIN files or line layers, which
    become 30 m corridors; call ``io.microstructures.load_microstructures`` for other widths)."""
    from approxtree.io.microstructures import load_microstructures

    if not isinstance(terrain, Grid):
        raise InvalidParameterError(
            f"Microstructures refine a regular Grid, got a {type(terrain).__name__}; "
            "open the terrain grid (e.g. a GeoTIFF DEM) to refine it."
        )
    tins: list[TIN] = []
    for item in microstructures:
        tins.extend([item] if isinstance(item, TIN) else load_microstructures(item, terrain))
    return GridRefinement(terrain, tins)


def _node_arrays(built: BuiltLevels) -> dict[str, Any]:
    """The tree's node arrays and patch table of a build's levels (no patch object made)."""
    # Figures straight from the build's arrays: no patch object is made here.
    table = as_table(built.patches)
    n = len(table)
    names, strategies = table.strategies()
    bboxes = np.empty((n, 6))
    rects = np.asarray(built.rects, dtype=np.float64).reshape(n, 4)
    bboxes[:, [0, 1, 3, 4]] = rects
    bboxes[:, 2], bboxes[:, 5] = table.z_ranges()
    return {
        "rects": rects,
        "errors": table.errors(),
        "bboxes": bboxes,
        "levels": np.array(built.levels, dtype=np.int32),
        "parents": np.array(built.parents, dtype=np.int64),
        "child_start": np.array(built.child_start, dtype=np.int64),
        "child_count": np.array(built.child_count, dtype=np.int64),
        "strategies": strategies,
        "strategy_names": names,
        "patches": table,
    }


class ApproximationTree:
    """Nodes of an approximation tree over ``terrain``, as flat arrays.

    rects: (n, 4) float64 D_N as (xmin, ymin, xmax, ymax).
    errors: (n,) float64 ε_T(N).
    bboxes: (n, 6) float64 B_N as (xmin, ymin, zmin, xmax, ymax, zmax).
    levels: (n,) int32 depth, root = 0. parents: (n,) int64, −1 for the root.
    child_start, child_count: (n,) int64 — children of i are child_start[i] + range(count).
    strategies: (n,) uint8 index into ``strategy_names``.
    origin: (3,) float64 local origin for float32 GPU buffers (domain centre, z_min).
    source: the saved tree its patches are read from (None for a built tree).
    """

    #: What the Engine and the store see: an approximation tree, not a point quadtree.
    tree_kind = "approximation_tree"

    def __init__(
        self,
        terrain: GeometryData,
        rects: np.ndarray,
        errors: np.ndarray,
        bboxes: np.ndarray,
        levels: np.ndarray,
        parents: np.ndarray,
        child_start: np.ndarray,
        child_count: np.ndarray,
        strategies: np.ndarray,
        strategy_names: list[str],
        params: dict[str, Any],
        patches: list[GeometryPatch | None] | PatchTable,
        source: store.TreeSource | None = None,
    ) -> None:
        self.terrain = terrain
        self.rects = rects
        self.errors = errors
        self.bboxes = bboxes
        self.levels = levels
        self.parents = parents
        self.child_start = child_start
        self.child_count = child_count
        self.strategies = strategies
        self.strategy_names = strategy_names
        self.params = params
        self._patches = patches
        self._source = source
        #: Updates applied (``update``); the node maps of the last few, for Engines to follow.
        self.version = 0
        self._changes: list[np.ndarray] = []
        z0 = terrain.z_range[0]
        cx, cy = terrain.domain.center
        self.origin = np.array([cx, cy, z0], dtype=np.float64)

    # -- construction --------------------------------------------------------------------------

    @classmethod
    def build(
        cls,
        terrain: GeometryData,
        epsilon: float = 1.0,
        max_points: int = 33 * 33,
        fanout: int = 4,
        policy: str | StrategyPolicy = "type",
        progress: bool | ProgressCallback | None = None,
        microstructures: Sequence[TIN | str | os.PathLike] | None = None,
        workers: int | None = None,
        scheduler: str | None = None,
        block_size: int | None = None,
        report: str | os.PathLike | None = None,
        regions: HeightRegions | None = None,
    ) -> ApproximationTree:
        """Build A(s,d)(T): split nodes while ε_T(N) > epsilon, patches of at most s points.

        terrain: any GeometryData, or an xarray DataArray (a Grid of it); epsilon: threshold ε
        in z units (>= 0); max_points: s (>= 4); fanout: d (4 quadtree, 2 k-d tree); policy:
        strategy name or "auto"; progress: a ``ProgressCallback`` called with (done, total) —
        points covered by finished leaves, or blocks done in a blocked build —,
        True for a tqdm bar on a terminal, None/False for nothing (``approxtree.progress``).

        Blocked builds (same tree, node for node; Grid terrains): ``workers`` N builds the
        blocks on a dask LocalCluster of N processes, ``scheduler`` "tcp://host:8786" on an
        existing cluster; ``block_size`` (cells per block side, default 2048) alone builds
        block by block in this process, as does a windowed grid without workers; ``report``
        writes a dask performance report (HTML) of a cluster build; ``regions``: where the block
        tasks of a windowed grid write its height chunks for ``save_tree`` to take
        (``tree.store_regions``, the build command's). A script passing ``workers``
        runs its build under ``if __name__ == "__main__":`` (the cluster starts processes that
        import the main module).
        """
        policy_obj = StrategyPolicy.resolve(policy)
        # An xarray DataArray is the Grid its georeference places (geometry.dataarray).
        if is_dataarray(terrain):
            terrain = Grid(terrain)
        if microstructures:
            terrain = with_microstructures(terrain, microstructures)
        blocked = (
            workers is not None
            or scheduler is not None
            or block_size is not None
            or bool(getattr(terrain, "is_windowed", False))
        )
        if report is not None and workers is None and scheduler is None:
            raise InvalidParameterError(
                "A performance report records a dask build: give workers or a scheduler too."
            )
        unit = "block" if blocked else "point"
        on_progress, close = as_callback(progress, "building tree", unit)
        try:
            built = cls._build_nodes(
                terrain,
                epsilon,
                max_points,
                fanout,
                policy_obj,
                blocked,
                workers,
                scheduler,
                block_size,
                report,
                on_progress,
                regions,
            )
        finally:
            close()
        return cls._from_built(terrain, built, epsilon, max_points, fanout, policy_obj)

    @staticmethod
    def _build_nodes(
        terrain: GeometryData,
        epsilon: float,
        max_points: int,
        fanout: int,
        policy_obj: StrategyPolicy,
        blocked: bool,
        workers: int | None,
        scheduler: str | None,
        block_size: int | None,
        report: str | os.PathLike | None,
        on_progress: ProgressCallback,
        regions: HeightRegions | None = None,
    ):
        """The BuiltLevels of a serial or blocked build (``build``)."""
        if blocked:
            from approxtree.tree.blocks import build_blocked

            run = None
            if workers is not None or scheduler is not None:
                from approxtree.tree.distributed import dask_runner

                run = dask_runner(workers, scheduler, report, on_progress)
            return build_blocked(
                terrain,
                epsilon,
                max_points,
                fanout,
                policy_obj,
                block_size,
                run=run,
                progress=on_progress,
                regions=regions,
            )
        return build_levels(terrain, epsilon, max_points, fanout, policy_obj, on_progress)

    @classmethod
    def _from_built(
        cls,
        terrain: GeometryData,
        built,
        epsilon: float,
        max_points: int,
        fanout: int,
        policy_obj: StrategyPolicy,
    ) -> ApproximationTree:
        """The tree of the nodes of a build (``build``)."""
        tree = cls(
            terrain,
            **_node_arrays(built),
            params={
                "epsilon": float(epsilon),
                "max_points": int(max_points),
                "fanout": int(fanout),
                "policy": policy_obj.name,
            },
        )
        tree.build_seconds = built.seconds
        if built.cells is not None:
            # The large patches' per-cell figures: an update (or a save) starts from them.
            tree.__dict__["_cell_cache"] = built.cells
        return tree

    def replace_nodes(self, built: BuiltLevels) -> None:
        """Take the nodes of ``built`` (an update's levels) in place of the tree's own; the
        origin stays (``tree.update``)."""
        for name, value in _node_arrays(built).items():
            setattr(self, "_patches" if name == "patches" else name, value)
        # Every patch is held by the new table now: none is read from a saved tree any more.
        self._source = None

    def update(self, rect: Rect, heights: np.ndarray) -> TreeUpdate:
        """Replace the terrain's cells in ``rect`` (world units, on the grid's cell edges) by
        ``heights`` (rows, cols; north-up as the grid; NaN = no data) and rebuild the nodes
        the window reaches, as a fresh build of the edited terrain would (``tree.update``).
        The terrain (an in-memory Grid) is edited in place; returns what changed."""
        report = update_tree(self, rect, heights)
        self._changes = [*self._changes[-(KEPT_CHANGES - 1) :], report.old_to_new]
        self.version += 1
        return report

    def changes_since(self, version: int) -> np.ndarray | None:
        """(n_then,) int64 the id now of every node of the tree at ``version`` whose patch
        is unchanged since (−1: rebuilt or gone); None when that version is too old."""
        return compose_changes(self._changes, self.version - version)

    build_seconds: float = 0.0

    # -- nodes ---------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.errors)

    @property
    def root(self) -> Node:
        return Node(self, 0)

    def node(self, index: int) -> Node:
        return Node(self, index)

    def nodes(self) -> list[Node]:
        """All nodes in breadth-first order."""
        return [Node(self, i) for i in range(len(self))]

    @property
    def leaves(self) -> np.ndarray:
        """(k,) int64 indices of the leaves."""
        return np.flatnonzero(self.child_count == 0)

    def patch(self, index: int) -> GeometryPatch:
        """T_N of node ``index`` (read from the tree file on first access)."""
        p = self._patches[index]
        if p is None:
            if self._source is None:  # pragma: no cover - built trees hold every patch
                raise StoreError(f"patch of node {index} is missing")
            _, arrays = self._source.patch_record(index)
            kind = self.strategy_names[int(self.strategies[index])]
            rect = Rect(*(float(v) for v in self.rects[index]))
            p = patch_class(self.terrain, kind).from_record(self.terrain, rect, arrays)
            self._patches[index] = p
        return p

    def read_patch(self, index: int) -> GeometryPatch:
        """T_N of node ``index`` without keeping it: read from the tree file each time unless
        already held (a paging renderer's read, so memory stays bounded by its caches)."""
        p = self._patches[index]
        if p is not None or self._source is None:
            return self.patch(index)
        _, arrays = self._source.patch_record(index)
        kind = self.strategy_names[int(self.strategies[index])]
        rect = Rect(*(float(v) for v in self.rects[index]))
        return patch_class(self.terrain, kind).from_record(self.terrain, rect, arrays)

    def cut_mesh(self, nodes: np.ndarray | None = None, skirts: bool = False) -> CutMesh:
        """The patches of a cut as one mesh in world coordinates (``tree.cut_mesh``):
        ``nodes`` (k,) node ids, e.g. ``frame.selection.nodes`` of an Engine frame, or None for
        the leaves; ``skirts`` hangs the renderer's walls. ``.to_trimesh()``/``.to_pyvista()``
        of the result carry z and the node of each face."""
        return cut_mesh(self, nodes, skirts)

    @property
    def epsilon(self) -> float:
        return self.params["epsilon"]

    @property
    def max_points(self) -> int:
        return self.params["max_points"]

    @property
    def fanout(self) -> int:
        return self.params["fanout"]

    @property
    def strategy_counts(self) -> dict[str, int]:
        """Strategy name → how many nodes its patches build (hybrid trees mix several)."""
        counts = np.bincount(self.strategies, minlength=len(self.strategy_names))
        return {name: int(c) for name, c in zip(self.strategy_names, counts, strict=True) if c}

    def stats(self) -> dict[str, Any]:
        """Figures of the tree: nodes, levels, leaves, strategies, max_leaf_error."""
        leaves = self.leaves
        counts = self.strategy_counts
        return {
            "nodes": len(self),
            "levels": int(self.levels.max()) + 1,
            "leaves": len(leaves),
            "strategies": dict(counts),
            "max_leaf_error": float(self.errors[leaves].max()),
        }

    # -- storage -------------------------------------------------------------------------------

    def patch_records(self, nodes: np.ndarray, strategy: str) -> Batch:
        """The patch records of ``nodes`` (k,), all of strategy ``strategy``, as one batch
        (``patches.records``), from wherever they are: a built tree's arrays, the patch
        objects held, or the saved tree it was loaded from."""
        held = self._patches
        if isinstance(held, PatchTable):
            # A built tree's grid patches: records straight from its arrays, no object per node.
            batch = held.records(nodes)
            if batch is not None:
                return batch
        loaded = [p for i in nodes.tolist() if (p := held[i]) is not None]
        if len(loaded) == len(nodes):
            # One patch class per strategy and terrain: its batched gather; else record by record.
            classes = {type(p) for p in loaded}
            if len(classes) == 1:
                return classes.pop().records_many(loaded)
            return concat_records([p.to_record() for p in loaded])
        if self._source is None:  # pragma: no cover - built trees hold every patch
            raise StoreError(f"patches of {strategy!r} are missing")
        return self._source.records(nodes, strategy)

    def save(self, path: str | os.PathLike) -> int:
        """Write the tree (terrain included) atomically as a tree store at ``path``: a folder
        (``NAME.zarr``), a zip (``NAME.zarr.zip``) or an fsspec URL (``tree.store``); returns
        the bytes stored. A .atree path is an InvalidParameterError (that format is read only).
        """
        return store.save(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike, verify: bool = True) -> ApproximationTree:
        """Open a tree store or a legacy .atree file; patches load on first access.

        verify: check the checksum of every patch now (the node table and terrain are always
        checked), so a corrupted file fails here rather than at render time.
        """
        return cls.from_source(store.open_store(path), verify=verify)

    @classmethod
    def from_source(cls, source: store.TreeSource, verify: bool = True) -> ApproximationTree:
        """The tree of a saved tree opened by ``tree.store.open_store``; patches are read from
        ``source`` on first access. verify: as in ``load``."""
        if source.tree_kind != cls.tree_kind:
            raise StoreError(
                f"{source.location} holds a {source.tree_kind!r} tree, not an approximation "
                "tree; open it with approxtree.load_tree."
            )
        if verify:
            source.verify()
        terrain = source.terrain()
        nodes = source.node_arrays()
        return cls(
            terrain,
            **nodes,
            strategy_names=list(source.meta["strategy_names"]),
            params=dict(source.meta["params"]),
            patches=[None] * len(nodes["errors"]),
            source=source,
        )
