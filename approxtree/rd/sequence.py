"""Embedded sequences of conforming meshes of the binary tree: decimation, refinement, uniform.

A sequence is stored as one int32 per node, ``birth``: mesh j (0 = coarsest) splits exactly
the nodes with birth < j, so every mesh refines the previous one (embedded) by construction.
``rates[j]`` is its triangle count and ``distortions[j]`` its sum of squared errors over all
grid points, accumulated from the per-node distortions; ``errors(j)`` measures a mesh again
from the heights.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.kernels import bintree_rd as kr
from approxtree.rd.bintree import BinTree


@dataclass
class EmbeddedSequence:
    """Meshes 0..S of one method over a BinTree.

    birth: (2^(2k+2),) int32; rates: (S+1,) int64 increasing; distortions: (S+1,) float64;
    seconds: time of the method (tree set-up excluded).
    """

    method: str
    tree: BinTree
    birth: np.ndarray
    rates: np.ndarray
    distortions: np.ndarray
    seconds: float

    def __len__(self) -> int:
        return len(self.rates)

    def index_at_rate(self, rate: int) -> int:
        """The finest mesh with at most ``rate`` triangles (0 when even mesh 0 has more)."""
        return max(int(np.searchsorted(self.rates, rate, side="right")) - 1, 0)

    def leaves(self, j: int) -> np.ndarray:
        """(m,) int64 node ids of the triangles of mesh j."""
        if not 0 <= j < len(self):
            raise InvalidParameterError(f"Mesh index must be in 0..{len(self) - 1}, got {j}.")
        return kr.cut_leaves(self.birth, j, self.tree.k)

    def mesh(self, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mesh j as (vx (n,), vy (n,) lattice column and row, tv (m, 3) CCW triangles)."""
        n = self.tree.size
        return kr.leaf_mesh(self.leaves(j), self.tree.k, n, n)

    def errors(self, j: int) -> tuple[float, float]:
        """(sum of squared errors, max error) of mesh j, measured over all grid points."""
        vx, vy, tv = self.mesh(j)
        sse, emax, _ = kr.mesh_errors(self.tree.heights, vx, vy, tv)
        return float(sse), float(emax)


def _tree(terrain) -> BinTree:
    return terrain if isinstance(terrain, BinTree) else BinTree(np.asarray(terrain))


def refine(terrain, max_triangles: int | None = None) -> EmbeddedSequence:
    """Greedy tree growing from two triangles up to ``max_triangles`` (None: the full grid).

    terrain: a BinTree or a (2^k + 1)² height array.
    """
    tree = _tree(terrain)
    t0 = time.perf_counter()
    best = kr.subtree_slopes(tree.d, tree.k)
    birth, rates, dist = kr.refine_kernel(
        tree.gain, tree.mate, best, tree.root_distortion, tree.k, int(max_triangles or 0)
    )
    return EmbeddedSequence("refinement", tree, birth, rates, dist, time.perf_counter() - t0)


def decimate(terrain, min_triangles: int = 2) -> EmbeddedSequence:
    """Constrained G-BFOS from the full grid down to ``min_triangles`` (default: two)."""
    tree = _tree(terrain)
    t0 = time.perf_counter()
    birth, rates, dist = kr.decimate_kernel(
        tree.gain, tree.mate, tree.root_distortion, tree.k, int(min_triangles)
    )
    return EmbeddedSequence("decimation", tree, birth, rates, dist, time.perf_counter() - t0)


def uniform(terrain) -> EmbeddedSequence:
    """The regular triangulated grids (RTG): mesh j is the 2^(j+1) triangles of level j + 1."""
    tree = _tree(terrain)
    t0 = time.perf_counter()
    top = 2 * tree.k + 1
    ids = np.arange(1 << (top + 1))
    level = np.zeros(len(ids), dtype=np.int32)
    level[1:] = np.floor(np.log2(ids[1:])).astype(np.int32)
    birth = np.where(level < top, level - 1, kr.NEVER).astype(np.int32)
    birth[0] = kr.NEVER
    birth[1] = -1
    rates = 2 ** np.arange(1, top + 1, dtype=np.int64)
    dist = np.array([tree.d[1 << lev : 1 << (lev + 1)].sum() for lev in range(1, top + 1)])
    return EmbeddedSequence("uniform", tree, birth, rates, dist, time.perf_counter() - t0)
