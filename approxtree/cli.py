"""The ``approxtree`` command line (click). Every command with --json prints one JSON object.

Errors of the ApproxTreeError hierarchy are printed as one line on stderr (exit code 2), never
as a traceback.
"""

from __future__ import annotations

import functools
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from approxtree.errors import ApproxTreeError


def _reports_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn an ApproxTreeError into a one-line message on stderr and exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except ApproxTreeError as exc:
            click.echo(f"Error: {exc}", err=True)
            sys.exit(2)

    return wrapper


def _finite(value: float) -> float | None:
    """JSON has no inf or NaN: report them as null."""
    return value if math.isfinite(value) else None


def _emit(figures: dict[str, Any], as_json: bool) -> None:
    if as_json:
        click.echo(json.dumps(figures))
    else:
        width = max(len(k) for k in figures)
        for k, v in figures.items():
            click.echo(f"{k:<{width}}  {v}")


def reader_options(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Options that choose how a terrain file is read (shared by info and build)."""
    fn = click.option(
        "--encoding",
        type=click.Choice(["terrain-rgb", "terrarium"]),
        help="Height encoding of an RGB PNG.",
    )(fn)
    fn = click.option(
        "--nodata",
        "nodata_policy",
        type=click.Choice(["mask", "fill"]),
        default="mask",
        show_default=True,
        help="Leave nodata out of the terrain (mask) or fill the holes by interpolation.",
    )(fn)
    fn = click.option(
        "--ground-only", is_flag=True, help="Point clouds: keep ground points (class 2) only."
    )(fn)
    fn = click.option(
        "--height-scale", type=float, help="16-bit grayscale PNG: metres per grey level."
    )(fn)
    return fn


def _open(
    path: str,
    encoding: str | None,
    nodata_policy: str,
    ground_only: bool,
    height_scale: float | None,
):
    from approxtree.io import open_terrain

    options: dict[str, Any] = {"nodata": nodata_policy}
    if encoding:
        options["encoding"] = encoding
    if ground_only:
        options["ground_only"] = True
    if height_scale is not None:
        options["height_scale"] = height_scale
    return open_terrain(path, **options)


def terrain_figures(terrain) -> dict[str, Any]:
    """The figures of ``approxtree info`` for any terrain."""
    from approxtree.geometry import Grid

    z_min, z_max = terrain.z_range
    figures: dict[str, Any] = {"kind": terrain.kind}
    if isinstance(terrain, Grid):
        figures.update(
            width=terrain.width,
            height=terrain.height,
            crs=terrain.crs,
            cell_size=list(terrain.cell_size),
            z_min=z_min,
            z_max=z_max,
            nodata_count=terrain.nodata_count,
        )
    else:
        figures.update(
            width=None,
            height=None,
            crs=terrain.crs,
            cell_size=None,
            z_min=z_min,
            z_max=z_max,
            nodata_count=0,
        )
    d = terrain.domain
    figures.update(points=terrain.point_count, domain=[d.xmin, d.ymin, d.xmax, d.ymax])
    return figures


def tree_figures(tree, seconds: float, nbytes: int) -> dict[str, Any]:
    """The figures of ``approxtree build`` for a built tree."""
    stats = tree.stats()
    stats["max_leaf_error"] = _finite(stats["max_leaf_error"])
    stats.update(
        epsilon=tree.epsilon,
        max_points=tree.max_points,
        fanout=tree.fanout,
        seconds=round(seconds, 4),
        bytes=nbytes,
    )
    return stats


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="approxtree")
def main() -> None:
    """approxtree: approximation trees for real-time terrain visualization."""


@main.command()
@click.argument("dem", type=click.Path(dir_okay=False))
@reader_options
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def info(dem: str, encoding, nodata_policy, ground_only, height_scale, as_json: bool) -> None:
    """Size, CRS, cell size, z range and nodata count of a terrain file."""
    terrain = _open(dem, encoding, nodata_policy, ground_only, height_scale)
    _emit(terrain_figures(terrain), as_json)


@main.command()
@click.argument("dem", type=click.Path(dir_okay=False))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(dir_okay=False),
    help="Tree file to write (.atree).",
)
@click.option(
    "--epsilon",
    type=float,
    default=1.0,
    show_default=True,
    help="Threshold ε: nodes split while their error exceeds it (z units).",
)
@click.option(
    "--max-points",
    type=int,
    default=33 * 33,
    show_default=True,
    help="s: most data points per geometry patch.",
)
@click.option(
    "--fanout",
    type=click.Choice(["2", "4"]),
    default="4",
    show_default=True,
    help="d: children per node (4 quadtree, 2 k-d tree).",
)
@click.option(
    "--policy",
    default="auto",
    show_default=True,
    help="Approximation strategy per node (auto or a strategy name).",
)
@reader_options
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def build(
    dem: str,
    out: str,
    epsilon: float,
    max_points: int,
    fanout: str,
    policy: str,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    as_json: bool,
) -> None:
    """Build the approximation tree of a terrain file and save it."""
    from approxtree.tree import ApproximationTree

    terrain = _open(dem, encoding, nodata_policy, ground_only, height_scale)
    t0 = time.perf_counter()
    tree = ApproximationTree.build(
        terrain, epsilon=epsilon, max_points=max_points, fanout=int(fanout), policy=policy
    )
    seconds = time.perf_counter() - t0
    nbytes = tree.save(out)
    _emit(tree_figures(tree, seconds, nbytes), as_json)


@main.command()
@click.option(
    "--out",
    type=click.Path(dir_okay=False),
    default="demo.atree",
    show_default=True,
    help="Where to save the tree of the sample terrain.",
)
@click.option(
    "--epsilon", type=float, default=1.0, show_default=True, help="Threshold ε in metres."
)
@click.option(
    "--png",
    type=click.Path(dir_okay=False),
    default=None,
    help="Where to write the rendered overview [default: --out with .png, i.e. demo.png].",
)
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def demo(out: str, epsilon: float, png: str | None, as_json: bool) -> None:
    """Build the tree of the sample terrain (matplotlib's Jacksboro fault DEM) and render it."""
    from approxtree.datasets import sample_terrain
    from approxtree.tree import ApproximationTree

    terrain = sample_terrain()
    t0 = time.perf_counter()
    tree = ApproximationTree.build(terrain, epsilon=epsilon)
    seconds = time.perf_counter() - t0
    nbytes = tree.save(out)
    figures = {"terrain": "jacksboro_fault_dem (matplotlib sample data)"}
    figures.update(terrain_figures(terrain))
    figures.update(tree_figures(tree, seconds, nbytes))
    figures["tree_file"] = str(Path(out))
    # Render the oblique overview of the whole terrain and add the frame's figures.
    png_path = Path(png) if png else Path(out).with_suffix(".png")
    figures.update(_render_to_png(tree, png_path, None, None, 45.0, (1280, 720), 1.0, 2.0))
    _emit(figures, as_json)


def _xyz(ctx: click.Context, param: click.Parameter, value: str | None):
    """Parse "X,Y,Z" into three floats (None when the option is absent)."""
    if value is None:
        return None
    parts = value.split(",")
    try:
        xyz = tuple(float(v) for v in parts)
    except ValueError:
        xyz = ()
    if len(xyz) != 3:
        raise click.BadParameter(f"expected X,Y,Z (three numbers), got {value!r}")
    return xyz


def _size(ctx: click.Context, param: click.Parameter, value: str) -> tuple[int, int]:
    """Parse "WxH" into (width, height)."""
    try:
        w, h = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"expected WxH in pixels, e.g. 1280x720, got {value!r}") from None
    return w, h


def _render_to_png(
    tree,
    path: Path,
    eye: tuple[float, float, float] | None,
    target: tuple[float, float, float] | None,
    fov: float,
    size: tuple[int, int],
    alpha: float,
    gamma: float,
    wireframe: bool = False,
    full_resolution: bool = False,
    max_triangles: int | None = None,
) -> dict[str, Any]:
    """Render one frame of ``tree`` to an RGBA PNG at ``path``; returns the frame's stats.

    Without ``eye``: the oblique overview of the whole terrain. Without ``target``: the centre
    of the tree's root box.
    """
    from PIL import Image

    from approxtree.io.atomic import atomic_write
    from approxtree.render import Camera, Engine, overview_camera

    with Engine(tree) as engine:
        box = tree.bboxes[0]
        if eye is None:
            camera = overview_camera(box, engine.scale, fov=fov)
            if target is not None:
                camera.update(target=target)
        else:
            centre = tuple(0.5 * (box[:3] + box[3:]))
            camera = Camera.look_at(eye, target if target is not None else centre, fov=fov)
        frame = engine.render(
            camera,
            size,
            alpha,
            gamma,
            wireframe=wireframe,
            full_resolution=full_resolution,
            max_triangles=max_triangles,
        )
    with atomic_write(path) as f:
        Image.fromarray(frame.image, mode="RGBA").save(f, format="PNG")
    stats = {k: (_finite(v) if isinstance(v, float) else v) for k, v in frame.stats.items()}
    stats["image"] = str(path)
    return stats


@main.command()
@click.argument("tree_file", type=click.Path(exists=True, dir_okay=False))
@click.option("--eye", callback=_xyz, help="Camera position X,Y,Z in world units.")
@click.option("--target", callback=_xyz, help="Point looked at X,Y,Z [default: tree centre].")
@click.option(
    "--fov", type=float, default=45.0, show_default=True, help="Vertical field of view, degrees."
)
@click.option(
    "--size", callback=_size, default="1280x720", show_default=True, help="Image size WxH."
)
@click.option("--alpha", type=float, default=1.0, show_default=True, help="Threshold α, pixels.")
@click.option(
    "--gamma", type=float, default=2.0, show_default=True, help="Threshold γ, pixels² (inf: off)."
)
@click.option("--wireframe", is_flag=True, help="Draw triangle edges.")
@click.option("--full-resolution", is_flag=True, help="Draw the unsimplified terrain (reference).")
@click.option(
    "--max-triangles",
    type=int,
    default=None,
    help="Triangle budget (skirts included) instead of --alpha: smallest α that fits.",
)
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="PNG to write (RGBA).")
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def render(
    tree_file: str,
    eye,
    target,
    fov: float,
    size: tuple[int, int],
    alpha: float,
    gamma: float,
    wireframe: bool,
    full_resolution: bool,
    max_triangles: int | None,
    out: str,
    as_json: bool,
) -> None:
    """Render a tree file to a PNG (alpha 0 where no terrain is drawn) and print the stats."""
    from approxtree.tree import ApproximationTree

    tree = ApproximationTree.load(tree_file)
    stats = _render_to_png(
        tree,
        Path(out),
        eye,
        target,
        fov,
        size,
        alpha,
        gamma,
        wireframe,
        full_resolution,
        max_triangles,
    )
    _emit(stats, as_json)


def _rates(ctx: click.Context, param: click.Parameter, value: str) -> list[int]:
    """Parse "512,1024" into triangle counts."""
    try:
        rates = [int(v) for v in value.split(",") if v.strip()]
    except ValueError:
        rates = []
    if not rates or min(rates) < 2:
        raise click.BadParameter(f"expected triangle counts >= 2 like 512,1024, got {value!r}")
    return rates


@main.command()
@click.argument("dem", type=click.Path(dir_okay=False))
@click.option(
    "--rates",
    callback=_rates,
    default="512,1024,2048,4096",
    show_default=True,
    help="Triangle counts at which every method is measured.",
)
@click.option(
    "--size",
    type=int,
    default=None,
    help="Side 2^k + 1 of the centred window used [default: the largest that fits].",
)
@click.option(
    "--methods",
    default="decimation,refinement,uniform,tin,rtin",
    show_default=True,
    help="Methods to compare (comma-separated).",
)
@click.option("--plot", type=click.Path(dir_okay=False), help="PNG of the L2 and L∞ curves.")
@reader_options
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def rd(
    dem: str,
    rates: list[int],
    size: int | None,
    methods: str,
    plot: str | None,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    as_json: bool,
) -> None:
    """Rate–distortion comparison: binary-tree decimation and refinement, uniform grid, TIN
    and RTIN at the same triangle counts (L2, max error, SNR in dB, seconds)."""
    from approxtree.geometry import Grid
    from approxtree.rd import lattice_heights, rd_curves
    from approxtree.rd.curves import json_ready, plot_rd

    terrain = _open(dem, encoding, nodata_policy, ground_only, height_scale)
    if not isinstance(terrain, Grid):
        from approxtree.errors import InvalidParameterError

        raise InvalidParameterError(
            f"The rd command needs a raster grid, {dem} reads as a {terrain.kind}."
        )
    heights = lattice_heights(terrain, size)
    result = rd_curves(heights, rates, [m.strip() for m in methods.split(",") if m.strip()])
    if plot:
        plot_rd(result, plot, title=f"{Path(dem).name} ({heights.shape[0]}²)")
    figures = json_ready(result)
    figures["dem"] = str(dem)
    if as_json:
        click.echo(json.dumps(figures))
        return
    click.echo(f"{Path(dem).name}: {heights.shape[0]}² grid, SNR (dB) / max error")
    click.echo("method       " + "".join(f"{r:>16}" for r in figures["rates"]) + "   seconds")
    for name, data in figures["methods"].items():
        cells = "".join(
            f"{(row['snr_db'] or float('inf')):>8.2f} /{row['max_error']:>6.1f}"
            for row in data["rows"]
        )
        click.echo(f"{name:<13}{cells}   {data['seconds']}")
