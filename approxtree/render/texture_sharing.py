"""Ancestor texture sharing (core paper, 4.2): fewer texture patches per frame.

A selected node N may be textured with the texture patch of an ancestor, since that patch
covers D_N too. Per selected node the renderer takes the ancestor closest to the root whose
visual texture error γ' is within the threshold γ; when none qualifies N keeps its own patch.
With a detail pyramid (textures/detail.py) only an ancestor textured from the same pyramid
qualifies: a node that uses the detail never takes its base ancestors' patches.
Ancestors of a selected node were all visited (and refined), so their γ' is known from the
selection. Pure and GL-free.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from approxtree.kernels._jit import readonly
from approxtree.render.selector import Selection


def texture_nodes(
    parents: np.ndarray,
    selection: Selection,
    gamma: float,
    share: bool = True,
    sources: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(k,) int64 node whose texture patch textures each selected node, and (k,) its γ.

    parents: (n,) int64 parent of every node (−1 at the root); selection: the frame's cut;
    gamma: the γ threshold (px²). share=False gives every node its own patch. sources: (n,)
    int64 pyramid of every node's patch (0 base, 1 detail; None: all 0): a node shares only
    an ancestor's of its own pyramid.
    """
    nodes = np.ascontiguousarray(selection.nodes, dtype=np.int64)
    if not share or selection.visited_gammas is None or len(nodes) == 0:
        return nodes.copy(), np.asarray(selection.gammas, dtype=np.float64).copy()
    g = np.full(len(parents), np.inf)
    g[selection.visited] = selection.visited_gammas
    if sources is None:
        sources = np.zeros(len(parents), dtype=np.int64)
    # Read-only views: one compiled signature for built and memory-mapped trees.
    parents, sources = readonly(parents, np.int64), readonly(sources, np.int64)
    out = _closest_to_root(readonly(nodes), parents, readonly(g), float(gamma), sources)
    return out, g[out]


@njit(cache=True)
def _closest_to_root(nodes, parents, g, gamma, sources):
    """Per node: the first node on the path root → node (node excluded) with γ <= gamma and
    the node's source, else the node itself."""
    out = nodes.copy()
    chain = np.empty(64, dtype=np.int64)
    for j in range(nodes.shape[0]):
        depth = 0
        i = parents[nodes[j]]
        while i >= 0:
            if depth == chain.shape[0]:
                bigger = np.empty(2 * depth, dtype=np.int64)
                # A loop, not a slice assignment (no shape-error code to compile).
                for k in range(depth):
                    bigger[k] = chain[k]
                chain = bigger
            chain[depth] = i
            depth += 1
            i = parents[i]
        # chain runs from the parent up to the root: test it from the root down.
        for d in range(depth - 1, -1, -1):
            if g[chain[d]] <= gamma and sources[chain[d]] == sources[nodes[j]]:
                out[j] = chain[d]
                break
    return out
