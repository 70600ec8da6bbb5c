"""Verify a mesh file of ``approxtree mesh --out`` (GLB, PLY, OBJ) against its source terrain.

The claim is the max error the file records (GLB scene extras ``max_error``, PLY comment or
OBJ header ``approxtree {"max_error": ...}``; ``max_error`` given explicitly otherwise), and
its RMS when recorded. Measured: the true max |mesh − h_T| over the source's data points under
the mesh's triangles (its footprint), with the file's own coordinates (GLB: float32 positions
plus the origin), so their rounding counts; the RMS is a figure beside the claimed one. Data
points of the mesh's bounding box that no
triangle holds are counted (``uncovered``), not measured.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from approxtree.verify.measure import GridMeasure, measure_for
from approxtree.verify.mesh_read import read_mesh
from approxtree.verify.report import VerifyReport, claims_hold

#: Inside slack for the file's rounded vertices: cells of a raster, or this fraction of the
#: extent of a point set.
TOL_CELLS = 1e-3
TOL_EXTENT = 1e-6


def measure_tolerance(measure: Any, extent: float) -> float:
    """The inside slack of ``measure`` for coordinates rounded to float32."""
    return TOL_CELLS if isinstance(measure, GridMeasure) else TOL_EXTENT * max(extent, 1.0)


def verify_mesh(path: Path, terrain: Any, report: VerifyReport, max_error: float | None) -> None:
    parse = report.check("parse", "the file parses as a triangle mesh")
    parse.items = 1
    verts, tris, claims, kind = read_mesh(path)
    report.figures.update({"format": kind, "vertices": len(verts), "triangles": len(tris)})
    for key in ("strategy", "source", "crs"):
        if key in claims:
            report.figures[f"claimed_{key}"] = claims[key]
    if len(tris) == 0:
        parse.fail(str(path), "triangles", 0)
        return
    claimed = max_error if max_error is not None else claims.get("max_error", "none")
    if claimed is None:
        claimed = np.inf  # recorded as null: the writer measured an infinite error
    if claimed == "none":
        report.not_checked.append(
            "errors: the file records no max error (older approxtree); give --max-error"
        )
        claimed = np.inf
    if terrain is None:
        return
    soup = verts[tris].reshape(-1, 9)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    rect = np.array([[lo[0], lo[1], hi[0], hi[1]]])
    measure = measure_for(terrain)
    tol = measure_tolerance(measure, float(max(hi[0] - lo[0], hi[1] - lo[1])))
    found = measure.errors(rect, lambda owners: (soup, np.zeros(len(soup), dtype=np.int64)), tol)
    measured = float(max(found.err[0], 0.0))
    rms = float(found.rms[0])
    report.figures.update(
        {
            "claimed_max_error": float(claimed),
            "measured_max_error": measured,
            "measured_rms_error": rms,
            "data_points": int(found.measured[0]),
            "uncovered": int(found.uncovered[0]),
        }
    )
    slack = 1e-9 * (1.0 + max(abs(v) for v in terrain.z_range))
    errors = report.check("errors", "the max error the file claims is the true max or more")
    errors.items = 1
    where = found.worst[0]
    address = f"mesh at ({where[0]:.6g}, {where[1]:.6g})" if np.isfinite(where).all() else "mesh"
    if not claims_hold(np.array([measured]), np.array([float(claimed)]), slack)[0]:
        errors.fail(address, float(claimed), measured, measured - float(claimed))
    if claims.get("rms_error") is not None:
        report.figures["claimed_rms_error"] = float(claims["rms_error"])
