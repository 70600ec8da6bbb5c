"""Rate–distortion curves of five methods on one (2^k + 1)² grid, at given triangle counts.

Methods: decimation (constrained G-BFOS), refinement (greedy growing), uniform (RTG), tin
(greedy insertion, Garland & Heckbert) and rtin (RTIN by max error under a triangle budget).
Every figure is measured on the mesh itself over all grid points (``mesh_errors``): the
distortion is the sum of squared errors (sse), the L2 error its root mean (rms_error), the L∞
error the max error, and SNR = 10·log10(e_max / e_m) with e_max the sse of the two-triangle
mesh (Balmelli et al., table 1).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError, UnsupportedStrategyError
from approxtree.geometry.grid import Grid
from approxtree.kernels import bintree_rd as kr
from approxtree.patches.lattice import LatticePatch
from approxtree.progress import ProgressCallback, Stages
from approxtree.rd.bintree import BinTree
from approxtree.rd.sequence import EmbeddedSequence, decimate, refine, uniform

#: Methods compared, in table order.
METHODS = ("decimation", "refinement", "uniform", "tin", "rtin")


def snr_db(e_max: float, e_m: float) -> float | None:
    """10·log10(e_max / e_m); None (JSON null) for an exact mesh."""
    if e_m <= 0.0:
        return None
    return 10.0 * math.log10(e_max / e_m)


def _figures(tree: BinTree, target: int, vx, vy, tv) -> dict[str, Any]:
    sse, emax, count = kr.mesh_errors(tree.heights, vx, vy, tv)
    return {
        "rate": int(target),
        "triangles": len(tv),
        "sse": float(sse),
        "rms_error": math.sqrt(sse / count) if count else None,
        "max_error": float(emax),
        "snr_db": snr_db(tree.root_distortion, float(sse)),
        "covered": int(count),
    }


def _sequence_rows(seq: EmbeddedSequence, rates: Sequence[int]) -> list[dict[str, Any]]:
    rows = []
    for r in rates:
        vx, vy, tv = seq.mesh(seq.index_at_rate(r))
        rows.append(_figures(seq.tree, r, vx, vy, tv))
    return rows


def _strategy_rows(tree: BinTree, strategy: str, rates: Sequence[int]):
    from approxtree.patches.approximate import approximate

    grid = Grid(tree.heights)
    rows = []
    seconds = 0.0
    for r in rates:
        mesh = approximate(grid, strategy, max_triangles=int(r))
        seconds += mesh.seconds
        patch = mesh.patch
        # The curves measure lattice vertices: the tin and rtin strategies on a grid.
        if not isinstance(patch, LatticePatch):
            raise UnsupportedStrategyError(
                f"The {strategy} strategy gives no lattice patch to measure on the bintree."
            )
        vx = patch.ij[:, 1].astype(np.int64)
        vy = patch.ij[:, 0].astype(np.int64)
        rows.append(_figures(tree, r, vx, vy, patch.tris.astype(np.int64)))
    return rows, seconds


def rd_curves(
    terrain: BinTree | np.ndarray,
    rates: Sequence[int] = (512, 1024, 2048, 4096),
    methods: Sequence[str] = METHODS,
    progress: ProgressCallback | None = None,
) -> dict[str, Any]:
    """Figures of every method at every rate (the finest mesh with at most that many triangles).

    Returns {"size", "e_max", "rates", "methods": {name: {"seconds", "rows": [...]}},
    "sequences": {name: EmbeddedSequence}} (sequences are not JSON; drop them to dump).
    progress(done, total): stages done, the binary tree then one per method.
    """
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InvalidParameterError(f"Unknown methods {unknown}; choose from {list(METHODS)}.")
    rates = sorted({int(r) for r in rates})
    if not rates or rates[0] < 2:
        raise InvalidParameterError(f"Rates must be triangle counts >= 2, got {rates}.")
    stages = Stages(progress, 1 + len(methods))
    t0 = time.perf_counter()
    tree = terrain if isinstance(terrain, BinTree) else BinTree(np.asarray(terrain))
    setup = time.perf_counter() - t0
    stages.done()
    out: dict[str, Any] = {
        "size": tree.size,
        "e_max": tree.root_distortion,
        "rates": rates,
        "tree_seconds": round(setup, 4),
        "methods": {},
        "sequences": {},
    }
    makers = {
        "decimation": lambda: decimate(tree),
        "refinement": lambda: refine(tree, max_triangles=rates[-1]),
        "uniform": lambda: uniform(tree),
    }
    for name in methods:
        if name in makers:
            seq = makers[name]()
            out["sequences"][name] = seq
            rows, seconds = _sequence_rows(seq, rates), seq.seconds
        else:
            rows, seconds = _strategy_rows(tree, name, rates)
        out["methods"][name] = {"seconds": round(seconds, 4), "rows": rows}
        stages.done()
    return out


def plot_rd(result: dict[str, Any], path, title: str = "") -> None:
    """SNR (L2) and max error (L∞) against triangles, one line per method, to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from approxtree.io.atomic import atomic_write
    from approxtree.io.own_output import MARK

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    e_max = result["e_max"]
    for name, data in result["methods"].items():
        rows = data["rows"]
        tri = [r["triangles"] for r in rows]
        seq = result.get("sequences", {}).get(name)
        if seq is not None and name != "uniform":
            keep = (seq.rates >= 2) & (seq.distortions > 0) & (seq.rates <= max(tri) * 2)
            snr = 10 * np.log10(e_max / seq.distortions[keep])
            (line,) = ax1.plot(seq.rates[keep], snr, lw=1, label=name)
            ax1.plot(tri, [r["snr_db"] for r in rows], "o", color=line.get_color(), ms=4)
        else:
            ax1.plot(tri, [r["snr_db"] for r in rows], "o-", lw=1, ms=4, label=name)
        ax2.plot(tri, [r["max_error"] for r in rows], "o-", lw=1, ms=4, label=name)
    ax1.set(xscale="log", xlabel="triangles", ylabel="SNR (dB), L2", title=title or "L2")
    ax2.set(xscale="log", yscale="log", xlabel="triangles", ylabel="max error (L∞)")
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_write(path) as f:
        fig.savefig(f, format="png", dpi=110, metadata={"Software": MARK})
    plt.close(fig)


def json_ready(result: dict[str, Any]) -> dict[str, Any]:
    """The result without the sequences (JSON-serializable)."""
    return {k: v for k, v in result.items() if k != "sequences"}
