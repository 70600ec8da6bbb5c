"""approximate(): one strategy applied to a whole terrain, to an error or a point budget.

This is the standalone use of the strategies (the ``approxtree mesh`` command); inside a tree
the same code builds one patch per node. Exactly one of ``max_error``, ``max_points`` and
``max_triangles`` is the goal; the reported errors are measured, never estimated.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.base import GeometryData
from approxtree.patches.base import GeometryPatch
from approxtree.progress import ProgressCallback, Stages

#: Strategies ``approximate`` knows.
MESH_STRATEGIES = ("grid", "nonregular", "tin", "rtin")


@dataclass
class Mesh:
    """A terrain approximation: world-coordinate mesh and its exact error figures.

    vertices: (n, 3) float64 world x, y, z; triangles: (m, 3) int64, counter-clockwise seen
    from above; max_error / rms_error over all data points; seconds of computation.
    """

    strategy: str
    vertices: np.ndarray
    triangles: np.ndarray
    max_error: float
    rms_error: float
    seconds: float
    patch: GeometryPatch

    def figures(self) -> dict[str, object]:
        """The figures of ``approxtree mesh --json`` (inf reported as None)."""
        return {
            "strategy": self.strategy,
            "vertices": len(self.vertices),
            "triangles": len(self.triangles),
            "max_error": self.max_error if math.isfinite(self.max_error) else None,
            "rms_error": self.rms_error if math.isfinite(self.rms_error) else None,
            "seconds": round(self.seconds, 4),
        }


def check_goal(max_error: float | None, max_points: int | None, max_triangles: int | None) -> None:
    """Raise InvalidParameterError unless exactly one valid goal is given."""
    goals = [g for g in (max_error, max_points, max_triangles) if g is not None]
    if len(goals) != 1:
        raise InvalidParameterError(
            "Give exactly one goal: max_error, max_points or max_triangles "
            f"(got max_error={max_error}, max_points={max_points}, "
            f"max_triangles={max_triangles})."
        )
    if max_error is not None and (not math.isfinite(max_error) or max_error < 0):
        raise InvalidParameterError(f"max_error must be finite and >= 0, got {max_error}.")
    if max_points is not None and max_points < 4:
        raise InvalidParameterError(f"max_points must be >= 4, got {max_points}.")
    if max_triangles is not None and max_triangles < 2:
        raise InvalidParameterError(f"max_triangles must be >= 2, got {max_triangles}.")


def approximate(
    terrain: GeometryData,
    strategy: str = "tin",
    max_error: float | None = None,
    max_points: int | None = None,
    max_triangles: int | None = None,
    data_dependent: bool = False,
    progress: ProgressCallback | None = None,
) -> Mesh:
    """Approximate the whole terrain with one strategy (grid, nonregular, tin or rtin).

    grid: one uniform step in both directions (see ``patches.grid.uniform_step``);
    nonregular: row–column insertion; data_dependent: for ``tin`` on grids, Algorithm IV's
    data-dependent flips. progress(done, total): stages done (the insertion — one numba
    kernel —, then the mesh arrays), ``approxtree.progress``.
    """
    check_goal(max_error, max_points, max_triangles)
    if strategy not in MESH_STRATEGIES:
        raise InvalidParameterError(
            f"Unknown strategy {strategy!r}; choose one of: {', '.join(MESH_STRATEGIES)}."
        )
    if data_dependent and strategy != "tin":
        raise InvalidParameterError(
            f"data_dependent applies to the tin strategy only, not {strategy!r}."
        )
    stages = Stages(progress, 2)
    t0 = time.perf_counter()
    # The strategy table picks the class for this data type (or says it cannot).
    from approxtree.patches.table import patch_class

    cls = patch_class(terrain, strategy)
    patch = cls.approximate(terrain, max_error, max_points, max_triangles, data_dependent)
    seconds = time.perf_counter() - t0
    stages.done()
    vertices = patch.vertices
    triangles = patch.triangles
    stages.done()
    rms = float(getattr(patch, "rms_error", float("nan")))
    return Mesh(strategy, vertices, triangles, patch.error, rms, seconds, patch)
