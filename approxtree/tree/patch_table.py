"""PatchTable: the patches of a built tree's nodes, objects made on first access.

A build hands over its levels either as lists of patch objects or as arrays of grid patches
(``GridPatchArrays``, one table per level, no object per node). The table indexes like a list
of the n patches in node order; a node backed by arrays gets its GridPatch when first asked
for (then kept). The tree's figures (errors, z ranges, strategies) and the store's records are
read from the arrays directly, so neither a build nor a save makes an object per node.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import cast

import numpy as np

from approxtree.errors import StoreError
from approxtree.patches.base import GeometryPatch
from approxtree.patches.grid import GridPatchArrays
from approxtree.patches.records import Batch


class PatchTable:
    """n patches in node order: held objects, or rows of one GridPatchArrays made on access.

    row: (n,) int64, the node's row in ``arrays`` (−1: the node's patch is held as an object).
    """

    def __init__(self, parts: Sequence[Sequence[GeometryPatch] | GridPatchArrays]) -> None:
        n = sum(len(p) for p in parts)
        self._held: list[GeometryPatch | None] = [None] * n
        self.row = np.full(n, -1, dtype=np.int64)
        tables: list[GridPatchArrays] = []
        pos = rows = 0
        # Array parts are stacked into one table; list parts are held as they are.
        for part in parts:
            k = len(part)
            if isinstance(part, GridPatchArrays):
                self.row[pos : pos + k] = np.arange(rows, rows + k)
                tables.append(part)
                rows += k
            else:
                self._held[pos : pos + k] = list(part)
            pos += k
        self.arrays = GridPatchArrays.concat(tables) if tables else None
        self._listed = np.flatnonzero(self.row < 0)

    def __len__(self) -> int:
        return len(self._held)

    @property
    def held(self) -> int:
        """How many patch objects the table holds (made on access, or handed over as such)."""
        return len(self._held) - self._held.count(None)

    def __getitem__(self, i: int) -> GeometryPatch:
        p = self._held[i]
        if p is None:
            # Not made yet, so a row of the arrays: the nodes of list parts are held from the start.
            r = int(self.row[i])
            if r < 0 or self.arrays is None:  # pragma: no cover - every node is one or the other
                raise StoreError(f"patch of node {i} is missing")
            p = self._held[i] = self.arrays.patch(r)
        return p

    def __setitem__(self, i: int, patch: GeometryPatch) -> None:
        self._held[i] = patch

    def __iter__(self) -> Iterator[GeometryPatch]:
        self.fill()
        # fill() made every patch not held: no entry is None any more.
        return iter(cast(list[GeometryPatch], list(self._held)))

    def fill(self) -> None:
        """Make every patch not held yet, in one batch (before visiting all of them)."""
        if self.arrays is None:
            return
        held = self._held
        missing = [i for i in np.flatnonzero(self.row >= 0).tolist() if held[i] is None]
        if missing:
            made = self.arrays.patches(self.row[missing])
            for i, p in zip(missing, made, strict=True):
                held[i] = p

    # -- figures of every node, from the arrays where they are -------------------------------

    def _column(self, values: np.ndarray, listed: list[float]) -> np.ndarray:
        out = np.empty(len(self), dtype=np.float64)
        arrayed = self.row >= 0
        out[arrayed] = values[self.row[arrayed]]
        out[self._listed] = listed
        return out

    def errors(self) -> np.ndarray:
        """(n,) float64 ε_T(N) of every node."""
        a = self.arrays
        listed = [self._held[i].error for i in self._listed.tolist()]  # type: ignore[union-attr]
        return self._column(a.error if a is not None else np.empty(0), listed)

    def z_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """(n,) zmin and (n,) zmax float64 of every node's patch."""
        a = self.arrays
        held = [self._held[i].z_range for i in self._listed.tolist()]  # type: ignore[union-attr]
        lo = self._column(a.zmin if a is not None else np.empty(0), [z[0] for z in held])
        hi = self._column(a.zmax if a is not None else np.empty(0), [z[1] for z in held])
        return lo, hi

    def strategies(self) -> tuple[list[str], np.ndarray]:
        """Strategy names in order of first use and (n,) uint8 each node's index into them."""
        arrayed = self.row >= 0
        listed = self._listed.tolist()
        kinds = [self._held[i].kind for i in listed]  # type: ignore[union-attr]
        first: dict[str, int] = {}
        if arrayed.any():
            first[GridPatchArrays.kind] = int(np.argmax(arrayed))
        for i, kind in zip(listed, kinds, strict=True):
            first[kind] = min(first.get(kind, i), i)
        names = sorted(first, key=first.__getitem__)
        codes = np.empty(len(self), dtype=np.uint8)
        if arrayed.any():
            codes[arrayed] = names.index(GridPatchArrays.kind)
        code_of = {name: c for c, name in enumerate(names)}
        codes[self._listed] = [code_of[k] for k in kinds]
        return names, codes

    # -- records for a store ----------------------------------------------------------------

    def records(self, nodes: np.ndarray) -> Batch | None:
        """The batch of records of ``nodes`` when all are grid patches backed by arrays (equal
        to ``GridPatch.records_many`` of their patches), else None."""
        rows = self.row[nodes]
        if self.arrays is None or (rows < 0).any():
            return None
        coarse = np.asarray(nodes)[self.arrays.coarse(rows)]
        lattices = [self[int(i)] for i in coarse]
        return self.arrays.records(rows, lattices)  # type: ignore[arg-type]

    def lattice_holders(self) -> list[GeometryPatch]:
        """The held patches and the array-backed grid patches that store their lattice."""
        out = [p for i in self._listed.tolist() if (p := self._held[i]) is not None]
        if self.arrays is not None:
            coarse = self.arrays.coarse()
            where = np.flatnonzero(self.row >= 0)
            node_of = np.empty(len(self.arrays), dtype=np.int64)
            node_of[self.row[where]] = where
            out.extend(self[int(i)] for i in node_of[coarse])
        return out


def as_table(patches: Sequence[GeometryPatch] | PatchTable) -> PatchTable:
    """A PatchTable of a build's patches (a list of objects is wrapped as it is)."""
    return patches if isinstance(patches, PatchTable) else PatchTable([patches])
