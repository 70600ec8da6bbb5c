"""``approxtree mesh``: Approximate a whole terrain with one strategy to exactly one goal (--max-
error, --max-points or --max-triangles); print its exact max and RMS errors, optionally write
it.
"""

from __future__ import annotations

from pathlib import Path

import click

from approxtree.cli.common import _emit, _reports_errors, _terrain_of
from approxtree.cli.options import (
    json_option,
    overwrite_option,
    quiet_option,
    reader_options,
    replaceable,
)


@click.command()
@click.argument("dem", type=click.Path())
@click.option(
    "--strategy",
    type=click.Choice(["grid", "nonregular", "tin", "rtin"]),
    default="tin",
    show_default=True,
    help="Approximation strategy for the whole terrain.",
)
@click.option("--max-error", type=float, help="Goal: largest error allowed (z units).")
@click.option("--max-points", type=int, help="Goal: most vertices.")
@click.option("--max-triangles", type=int, help="Goal: most triangles.")
@click.option(
    "--out",
    type=click.Path(dir_okay=False),
    help="Mesh file to write (.ply, .obj or .glb). PLY and OBJ hold world coordinates; GLB "
    "holds float32 coordinates relative to a local origin (x, y centre, lowest z), stored in "
    "the GLB scene extras as 'origin' and printed in the figures: world = position + origin. "
    "PLY and OBJ are z-up; GLB is glTF's y-up (z-up positions under a root node rotating "
    "z-up to y-up) with vertex normals.",
)
@click.option(
    "--textures",
    type=click.Path(file_okay=False),
    default=None,
    help="GLB: texture pyramid folder (approxtree bake); the patch covering the terrain is "
    "embedded with texture coordinates.",
)
@click.option(
    "--skirts",
    is_flag=True,
    help="Hang a wall from the mesh's border down to its lowest z minus its max error.",
)
@click.option(
    "--data-dependent",
    is_flag=True,
    help="tin on grids: data-dependent triangulation (edge flips by error) instead of Delaunay.",
)
@reader_options
@overwrite_option
@quiet_option
@json_option
@_reports_errors
def mesh(
    dem: str,
    strategy: str,
    max_error: float | None,
    max_points: int | None,
    max_triangles: int | None,
    out: str | None,
    textures: str | None,
    skirts: bool,
    data_dependent: bool,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    quiet: bool,
    as_json: bool,
) -> None:
    """Approximate a whole terrain with one strategy to exactly one goal (--max-error,
    --max-points or --max-triangles); print its exact max and RMS errors, optionally write it."""
    from approxtree.io.mesh_file import mesh_format, write_mesh
    from approxtree.patches.approximate import approximate, check_goal
    from approxtree.progress import progress_bar

    # Check the cheap things before reading and approximating the terrain.
    check_goal(max_error, max_points, max_triangles)
    if out is not None:
        kind = mesh_format(out)
        replaceable(out, "mesh file")
        if textures is not None and kind != "glb":
            from approxtree.errors import InvalidParameterError

            raise InvalidParameterError(f"--textures needs a .glb output; {out} is {kind}.")
    elif textures is not None or skirts:
        from approxtree.errors import InvalidParameterError

        raise InvalidParameterError("--textures and --skirts shape the written mesh: give --out.")
    # A lattice strategy of a point cloud is refused from the file's format, before reading it
    # (reading triangulates every point: over a minute for 5 million).
    _check_mesh_strategy(dem, _format_kind(dem, encoding), strategy)
    terrain = _terrain_of(dem, encoding, nodata_policy, ground_only, height_scale)
    from approxtree.geometry import Grid

    _check_mesh_strategy(dem, "grid" if isinstance(terrain, Grid) else terrain.kind, strategy)
    max_points, max_triangles = _bounded_goals(terrain, max_points, max_triangles)
    with progress_bar(f"mesh ({strategy})", unit="stage", quiet=quiet) as on_progress:
        result = approximate(
            terrain,
            strategy,
            max_error,
            max_points,
            max_triangles,
            data_dependent=data_dependent,
            progress=on_progress,
        )
    figures = result.figures()
    if out is not None:
        _as_stored(terrain, result, kind, figures)
        # The claims ``approxtree verify`` checks travel in the file.
        meta = {
            "strategy": strategy,
            "crs": terrain.crs,
            "max_error": figures["max_error"],
            "rms_error": figures["rms_error"],
            "source": Path(dem).name,
        }
        verts, tris = result.vertices, result.triangles
        surface = len(tris)
        if skirts:
            import numpy as np

            from approxtree.patches.skirts import add_skirts

            # One curtain to a common base: the lowest vertex minus the mesh's max error.
            z = np.asarray(verts)[:, 2]
            relief = float(z.max() - z.min())
            claimed = figures["max_error"]
            error = float(claimed) if isinstance(claimed, int | float) else 0.0
            base = float(z.min()) - max(error, 1e-3 * relief, 1e-3)
            verts, tris, _ = add_skirts(verts, tris, np.inf, None, base)
        texture = None
        if textures is not None:
            from approxtree.textures.embed import embedded_texture
            from approxtree.textures.pyramid import TexturePyramid

            d = terrain.domain
            texture = embedded_texture(TexturePyramid(textures), d, verts)
        figures.update(write_mesh(out, verts, tris, meta, surface, texture))
    _emit(figures, as_json)


def _as_stored(terrain, result, kind: str, figures: dict) -> None:
    """Replace the errors in ``figures`` by those of the mesh as the file stores it, where its
    coordinates differ (GLB: float32 positions): the claim the file carries must hold for
    the mesh a reader gets (a GLB of a 3″ SRTM crop claimed 2.0 m and was 2.0002 m off)."""
    import numpy as np

    from approxtree.io.mesh_file import stored_vertices
    from approxtree.kernels.mesh_errors import mesh_point_errors

    verts = np.asarray(result.vertices, dtype=np.float64)
    stored = stored_vertices(verts, kind)
    if np.array_equal(stored, verts) or figures["max_error"] is None:
        return
    pts = terrain.points()
    tris = np.ascontiguousarray(result.triangles, dtype=np.int64)
    vx, vy, vz = (np.ascontiguousarray(stored[:, k]) for k in range(3))
    qx, qy, qz = (np.ascontiguousarray(pts[:, k]) for k in range(3))
    tri, err = mesh_point_errors(vx, vy, vz, tris, qx, qy, qz, 1e-9)
    # Points the rounding left outside the border keep the unrounded mesh's value.
    inside = err[tri >= 0]
    if len(inside):
        figures["max_error"] = max(float(figures["max_error"]), float(inside.max()))
        figures["rms_error"] = float(np.sqrt(np.mean(inside**2)))


def _format_kind(path: str, encoding: str | None) -> str | None:
    """The terrain kind a file's format always reads as when it is not a grid ("tinpointset"
    for LAS/LAZ, "tin" for quantized-mesh), else None (grids, or decided once read)."""
    from approxtree.errors import ApproxTreeError
    from approxtree.io import detect_format
    from approxtree.io._common import existing_file

    try:
        name = detect_format(existing_file(path), encoding=encoding).name
    except (ApproxTreeError, OSError):
        return None  # the reader says what is wrong with the file
    return {"LAS/LAZ point cloud": "tinpointset", "quantized-mesh tile": "tin"}.get(name)


def _check_mesh_strategy(path: str, kind: str | None, strategy: str) -> None:
    """InvalidParameterError for a lattice strategy asked of a TIN or a point cloud (a terrain
    ``kind`` other than a grid's; None: not known yet)."""
    from approxtree.errors import InvalidParameterError

    if strategy != "tin" and kind not in (None, "grid"):
        raise InvalidParameterError(
            f"--strategy {strategy} needs a raster grid; {path} reads as a {kind} "
            "(scattered points or triangles): use --strategy tin."
        )


def _bounded_goals(terrain, max_points: int | None, max_triangles: int | None):
    """(max_points, max_triangles) clamped to what the terrain has: a mesh has at most its
    data points (a budget above them means all of them) and a triangulation of n points at
    most 2n triangles; a warning line says so."""
    import warnings

    from approxtree.errors import ApproxTreeWarning

    n = int(terrain.point_count)
    if max_points is not None and max_points > n:
        warnings.warn(
            f"--max-points {max_points} is more than the terrain's {n} data points; all of them "
            "are used.",
            ApproxTreeWarning,
            stacklevel=2,
        )
        max_points = n
    if max_triangles is not None and max_triangles > 2 * n:
        warnings.warn(
            f"--max-triangles {max_triangles} is more than the {2 * n} triangles {n} data "
            "points can make; every point is used.",
            ApproxTreeWarning,
            stacklevel=2,
        )
        max_triangles = 2 * n
    return max_points, max_triangles
