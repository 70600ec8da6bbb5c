"""The ``approxtree`` command line (click). Every command with --json prints one JSON object.

Errors of the ApproxTreeError hierarchy are printed as one line on stderr (exit code 2), never
as a traceback.
"""

from __future__ import annotations

import functools
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from approxtree.errors import ApproxTreeError, ApproxTreeWarning


def _reports_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn an ApproxTreeError into a one-line message on stderr and exit code 2.

    An ApproxTreeWarning is printed as one ``Warning:`` line on stderr when it is raised.
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with warnings.catch_warnings():
            shown = warnings.showwarning

            def show(message, category, filename, lineno, file=None, line=None):
                if issubclass(category, ApproxTreeWarning):
                    click.echo(f"Warning: {message}", err=True)
                else:
                    shown(message, category, filename, lineno, file, line)

            warnings.showwarning = show
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
    """Options that choose how a terrain file is read (shared by the commands taking a terrain).

    Every default is "not given": each format reads with its own defaults, and an option given
    explicitly to a format that does not take it is an error.
    """
    fn = click.option(
        "--encoding",
        type=click.Choice(["terrain-rgb", "terrarium"]),
        help="Height encoding of an RGB PNG.",
    )(fn)
    fn = click.option(
        "--nodata",
        "nodata_policy",
        type=click.Choice(["mask", "fill"]),
        default=None,
        help="Grids: leave nodata out of the terrain (mask) or fill the holes by interpolation "
        "[default: mask].",
    )(fn)
    fn = click.option(
        "--ground-only", is_flag=True, help="Point clouds: keep ground points (class 2) only."
    )(fn)
    fn = click.option(
        "--height-scale", type=float, help="16-bit grayscale PNG: metres per grey level."
    )(fn)
    # Kept in the click context (not a parameter of every command): _open reads it.
    fn = click.option(
        "--windowed",
        type=click.Choice(["auto", "on", "off"]),
        default=None,
        expose_value=False,
        callback=_remember_windowed,
        help="GDAL rasters: read by windows on demand (on), into memory (off), or windowed when "
        "the band exceeds 1 GiB (auto; APPROXTREE_WINDOWED_BYTES overrides) [default: auto].",
    )(fn)
    return fn


def _remember_windowed(ctx: click.Context, _param: click.Parameter, value: str | None) -> None:
    """Keep --windowed in the context for _open (None when not given)."""
    ctx.meta["approxtree.windowed"] = value


def _open(
    path: str,
    encoding: str | None,
    nodata_policy: str | None,
    ground_only: bool,
    height_scale: float | None,
):
    """Read a terrain file, passing only the reader options the user gave.

    An option left at its default is "not given", so every format reads with its own defaults;
    an option given explicitly that the format does not take is an InvalidParameterError.
    """
    from approxtree.io import open_terrain

    options = _given_reader_options(encoding, nodata_policy, ground_only, height_scale)
    ctx = click.get_current_context(silent=True)
    windowed = ctx.meta.get("approxtree.windowed") if ctx is not None else None
    # "auto" is the reader's default: it is passed on only as an explicit on or off.
    if windowed in ("on", "off"):
        options["windowed"] = windowed == "on"
    _check_reader_flags(path, options)
    return open_terrain(path, **options)


#: The reader options of the command line, by the keyword the readers take.
_READER_FLAGS = {
    "encoding": "--encoding",
    "nodata": "--nodata",
    "ground_only": "--ground-only",
    "height_scale": "--height-scale",
    "windowed": "--windowed",
}


def _given_reader_options(
    encoding: str | None, nodata_policy: str | None, ground_only: bool, height_scale: float | None
) -> dict[str, Any]:
    """The reader options given on the command line, as open_terrain keywords."""
    options: dict[str, Any] = {}
    if nodata_policy is not None:
        options["nodata"] = nodata_policy
    if encoding:
        options["encoding"] = encoding
    if ground_only:
        options["ground_only"] = True
    if height_scale is not None:
        options["height_scale"] = height_scale
    return options


def _check_reader_flags(path: str, options: dict[str, Any]) -> None:
    """InvalidParameterError, worded with the command's flags, for a given reader option that
    the file's format does not take (the readers word it with their keyword names)."""
    from approxtree.errors import InvalidParameterError
    from approxtree.io import detect_format
    from approxtree.io._common import existing_file

    if not options:
        return
    fmt = detect_format(existing_file(path), encoding=options.get("encoding"))
    for name in options:
        if name not in fmt.options:
            takes = [flag for key, flag in _READER_FLAGS.items() if key in fmt.options]
            hint = (
                f"its reader options: {', '.join(takes)}" if takes else "it has no reader options"
            )
            raise InvalidParameterError(
                f"{_READER_FLAGS[name]} does not apply to {path}, a {fmt.name} file ({hint}); "
                "leave it out."
            )


def _takes_windowed(path: str, encoding: str | None) -> bool:
    """Whether the reader of ``path``'s format can read it by windows (GDAL rasters)."""
    from approxtree.io import detect_format
    from approxtree.io._common import existing_file

    return "windowed" in detect_format(existing_file(path), encoding=encoding).options


def _is_tree(path: str) -> bool:
    """Whether ``path`` names a saved tree: a tree store (.zarr, .zip, URL, store folder) or a
    legacy .atree file."""
    from approxtree.tree.zarr_store import is_store

    return Path(path).suffix.lower() == ".atree" or is_store(path)


def _check_tree_output(out: str) -> None:
    """StoreError now, before any work, when the tree cannot be written at ``out``."""
    from approxtree.io.output_path import check_output_file, check_output_folder
    from approxtree.tree.zarr_store import is_url, is_zip

    if is_url(out):
        return
    if is_zip(out) or Path(out).suffix.lower() == ".atree":
        check_output_file(out, "tree file")
    else:
        check_output_folder(out, "tree store")


def _no_reader_flags_for_tree(path: str, options: dict[str, Any]) -> None:
    """InvalidParameterError when reader options are given with a saved tree."""
    from approxtree.errors import InvalidParameterError

    if options:
        flags = ", ".join(_READER_FLAGS[name] for name in options)
        raise InvalidParameterError(
            f"{flags} choose how a terrain file is read; {path} is a saved tree, "
            "already built. Leave them out."
        )


def _refine(terrain, files, width: float, depth: float, profile: str, spacing: float | None):
    """The GridRefinement of a grid by the microstructures of ``files``."""
    from approxtree.errors import InvalidParameterError
    from approxtree.geometry import Grid, GridRefinement
    from approxtree.io.microstructures import load_microstructures

    if not isinstance(terrain, Grid):
        raise InvalidParameterError(
            f"--microstructures refines a regular grid, got a {type(terrain).__name__}."
        )
    tins = []
    for f in files:
        tins.extend(
            load_microstructures(
                f, terrain, width=width, profile=profile, depth=depth, spacing=spacing
            )
        )
    return GridRefinement(terrain, tins)


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
            # A windowed raster's z range and counts come from one blockwise scan.
            windowed=terrain.is_windowed,
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


def _tree_info(path: str) -> dict[str, Any]:
    """Figures of a saved tree: a store's layout, or a legacy .atree's tree statistics."""
    from approxtree.tree.store import is_legacy_file
    from approxtree.tree.tree_store import store_info

    if not is_legacy_file(path):
        return store_info(path)
    from approxtree.tree import load_tree
    from approxtree.tree.store import FORMAT_VERSION

    tree = load_tree(path)
    figures = {"tree_file": path, "format": f"atree {FORMAT_VERSION}"}
    figures.update(tree.stats())
    figures["bytes"] = Path(path).stat().st_size
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


def quiet_option(fn: Callable[..., Any]) -> Callable[..., Any]:
    """-q/--quiet (keyword ``quiet``): no progress bar. Without it a command shows its bar on
    stderr only when stderr is a terminal; use it as
    ``with progress_bar("desc", unit="…", quiet=quiet) as report: work(..., progress=report)``
    (``approxtree.progress``)."""
    return click.option(
        "-q", "--quiet", is_flag=True, help="No progress bar (none either off a terminal)."
    )(fn)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="approxtree")
def main() -> None:
    """approxtree: approximation trees for real-time terrain visualization."""


@main.command()
@click.argument("dem", type=click.Path())
@reader_options
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def info(dem: str, encoding, nodata_policy, ground_only, height_scale, as_json: bool) -> None:
    """Size, CRS, cell size, z range and nodata count of a terrain file; of a tree store:
    format version, nodes, levels, strategies, chunk layout and bytes (stored vs raw)."""
    if _is_tree(dem):
        _no_reader_flags_for_tree(
            dem, _given_reader_options(encoding, nodata_policy, ground_only, height_scale)
        )
        figures = _tree_info(dem)
        chunks = figures.pop("chunks", {}) if not as_json else {}
        _emit(figures, as_json)
        # The chunk layout, one array a line under the figures: "shape in chunk chunks (n)".
        for name, a in chunks.items():
            shape, chunk = "×".join(map(str, a["shape"])), "×".join(map(str, a["chunks"]))
            click.echo(f"  {name}: {shape} in {chunk} chunks ({a['nchunks']})")
        return
    terrain = _open(dem, encoding, nodata_policy, ground_only, height_scale)
    _emit(terrain_figures(terrain), as_json)


@main.command()
@click.argument("dem", type=click.Path(dir_okay=False))
@click.option(
    "--out",
    "out",
    default=None,
    type=click.Path(),
    help="Tree store to write: a folder NAME.zarr, a single file NAME.zarr.zip, an fsspec URL, "
    "or a legacy NAME.atree file [default: the DEM's name with .zarr, here].",
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
    default="type",
    show_default=True,
    help="Strategy per node: type, auto, a name, level:grid@0-3,tin or semantic:tin@4,grid.",
)
@click.option(
    "--microstructures",
    "microstructure_files",
    multiple=True,
    type=click.Path(dir_okay=False),
    help="TIN microstructures refining the grid: any TIN file, or a line layer "
    "(shapefile, GeoPackage, GeoJSON) turned into corridors. Repeatable.",
)
@click.option(
    "--microstructure-width",
    type=float,
    default=30.0,
    show_default=True,
    help="Corridor width around lines (map units).",
)
@click.option(
    "--microstructure-depth",
    type=float,
    default=2.0,
    show_default=True,
    help="Channel depth of incised corridors (z units).",
)
@click.option(
    "--microstructure-profile",
    type=click.Choice(["incised", "resampled"]),
    default="incised",
    show_default=True,
    help="Corridor heights: incised channel, or the grid resampled bicubically.",
)
@click.option(
    "--microstructure-spacing",
    type=float,
    default=None,
    help="Corridor sample spacing (map units) [default: a third of the grid cell].",
)
@click.option(
    "--kind",
    type=click.Choice(["approximation-tree", "point-quadtree"]),
    default="approximation-tree",
    show_default=True,
    help="Tree to build: the approximation tree, or the point quadtree of scattered points "
    "(seed 003; --max-points is its δ, default 50; ε, fanout and policy do not apply).",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=None,
    help="Build the blocks on a local dask cluster of N processes [default: in this process "
    "for terrains read whole, the core count for windowed ones].",
)
@click.option(
    "--scheduler",
    default=None,
    help="Build the blocks on an existing dask cluster: its scheduler address "
    "(e.g. tcp://host:8786).",
)
@click.option(
    "--block-size",
    type=click.IntRange(min=1),
    default=None,
    help="Cells per block side of a blocked build (its window reads one line more) "
    "[default: 2048].",
)
@click.option(
    "--report",
    type=click.Path(dir_okay=False),
    default=None,
    help="Write the dask performance report (task stream of the blocks) to this HTML file.",
)
@reader_options
@quiet_option
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def build(
    dem: str,
    out: str | None,
    epsilon: float,
    max_points: int,
    fanout: str,
    policy: str,
    microstructure_files: tuple[str, ...],
    microstructure_width: float,
    microstructure_depth: float,
    microstructure_profile: str,
    microstructure_spacing: float | None,
    kind: str,
    workers: int | None,
    scheduler: str | None,
    block_size: int | None,
    report: str | None,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    quiet: bool,
    as_json: bool,
) -> None:
    """Build the approximation tree of a terrain file and save it."""
    from approxtree.progress import progress_bar
    from approxtree.tree import ApproximationTree

    if out is None:
        out = Path(dem).stem + ".zarr"
    _check_tree_output(out)
    terrain = _open(dem, encoding, nodata_policy, ground_only, height_scale)
    if kind == "point-quadtree":
        given = click.get_current_context().get_parameter_source("max_points")
        delta = None if given == click.core.ParameterSource.DEFAULT else max_points
        _emit(_build_point_quadtree(dem, terrain, delta, out), as_json)
        return
    if microstructure_files:
        terrain = _refine(
            terrain,
            microstructure_files,
            microstructure_width,
            microstructure_depth,
            microstructure_profile,
            microstructure_spacing,
        )
    if workers is None and scheduler is None and getattr(terrain, "is_windowed", False):
        # A windowed terrain is large: build its blocks on every core.
        workers = os.cpu_count() or 1
    t0 = time.perf_counter()
    # The bar counts data points covered by finished leaves, or blocks of a blocked build.
    blocked = workers is not None or scheduler is not None or block_size is not None
    unit = "block" if blocked or getattr(terrain, "is_windowed", False) else "point"
    with progress_bar("building tree", unit=unit, quiet=quiet) as on_progress:
        tree = ApproximationTree.build(
            terrain,
            epsilon=epsilon,
            max_points=max_points,
            fanout=int(fanout),
            policy=policy,
            workers=workers,
            scheduler=scheduler,
            block_size=block_size,
            report=report,
            progress=on_progress,
        )
    seconds = time.perf_counter() - t0
    nbytes = tree.save(out)
    _emit(tree_figures(tree, seconds, nbytes), as_json)


def _build_point_quadtree(path: str, terrain, delta: int | None, out: str) -> dict[str, Any]:
    """Build and save the PointQuadtree of a point set (δ = delta, default 50); its figures."""
    from approxtree.errors import InvalidParameterError
    from approxtree.geometry import TIN
    from approxtree.tree import PointQuadtree

    if not isinstance(terrain, TIN):
        raise InvalidParameterError(
            f"--kind point-quadtree needs scattered points or a TIN (LAS/LAZ, quantized-mesh); "
            f"{path} reads as a {terrain.kind}. Build an approximation tree of it instead."
        )
    t0 = time.perf_counter()
    tree = PointQuadtree(terrain) if delta is None else PointQuadtree(terrain, delta)
    seconds = time.perf_counter() - t0
    nbytes = tree.save(out)
    return {**tree.stats(), "seconds": round(seconds, 4), "bytes": nbytes}


def cartographic_options(fn: Callable[..., Any]) -> Callable[..., Any]:
    """The picture options of render and demo: exaggeration, sun, palette, background,
    lighting (passed to the command as keyword ``style``, a dict for ``_render_to_png``)."""
    options = [
        click.option(
            "--exaggeration",
            type=float,
            default=1.0,
            show_default=True,
            help="Vertical exaggeration (z × factor; the α bound accounts for it).",
        ),
        click.option(
            "--sun-azimuth",
            type=float,
            default=315.0,
            show_default=True,
            help="Sun azimuth, degrees clockwise from north (lighting and side walls).",
        ),
        click.option(
            "--sun-altitude",
            type=float,
            default=45.0,
            show_default=True,
            help="Sun altitude, degrees above the horizon.",
        ),
        click.option(
            "--palette",
            "relief_palette",
            default="relief",
            show_default=True,
            help="Hypsometric palette by elevation: relief, atlas, grey or stretched (min..max).",
        ),
        click.option(
            "--background",
            default="sky",
            show_default=True,
            help="Behind the terrain: sky, transparent, a colour name or #rrggbb.",
        ),
        click.option(
            "--lighting",
            type=click.Choice(["auto", "on", "off"]),
            default="auto",
            show_default=True,
            help="Light the colours: auto lights untextured terrain only (baked shading is "
            "drawn once).",
        ),
    ]
    for option in reversed(options):
        fn = option(fn)

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        kwargs["style"] = {
            "exaggeration": kwargs.pop("exaggeration"),
            "sun": (kwargs.pop("sun_azimuth"), kwargs.pop("sun_altitude")),
            "palette": kwargs.pop("relief_palette"),
            "background": kwargs.pop("background"),
            "lighting": kwargs.pop("lighting"),
        }
        return fn(*args, **kwargs)

    return wrapper


@main.command()
@click.option(
    "--out",
    type=click.Path(),
    default="demo.zarr",
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
@cartographic_options
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def demo(out: str, epsilon: float, png: str | None, as_json: bool, style: dict[str, Any]) -> None:
    """Build the tree of the sample terrain (matplotlib's Jacksboro fault DEM), bake its
    hillshade pyramid (next to the tree, <out>_textures/) and render it: the baked shading
    over the hypsometric palette, fitted to the frame, in front of a sky."""
    from approxtree.datasets import sample_terrain
    from approxtree.io.output_path import check_output_file, check_output_folder
    from approxtree.render.style import Background, Sun
    from approxtree.textures.palettes import get_palette
    from approxtree.tree import ApproximationTree

    # Bad picture options fail before the build and the bake.
    Sun(*style["sun"])
    Background.parse(style["background"])
    get_palette(style["palette"])
    png_path = Path(png) if png else Path(out).with_suffix(".png")
    folder = Path(out).with_name(Path(out).stem + "_textures")
    _check_tree_output(out)
    check_output_file(png_path, "image")
    check_output_folder(folder, "texture pyramid folder")
    terrain = sample_terrain()
    t0 = time.perf_counter()
    tree = ApproximationTree.build(terrain, epsilon=epsilon)
    seconds = time.perf_counter() - t0
    nbytes = tree.save(out)
    figures = {"terrain": "jacksboro_fault_dem (matplotlib sample data)"}
    figures.update(terrain_figures(terrain))
    figures.update(tree_figures(tree, seconds, nbytes))
    figures["tree_file"] = str(Path(out))
    # Bake the hillshade pyramid next to the tree, then render the oblique overview with it:
    # the baked hillshade is the shading, drawn once (core paper 5.1), over the palette.
    from approxtree.textures.bake import bake as bake_textures

    # The baked light is the one asked for (sun and exaggeration, z factor of gdaldem).
    az, alt = style["sun"]
    shading = {"azimuth": az, "altitude": alt, "z_factor": style["exaggeration"]}
    baked = bake_textures(terrain, folder, shading_options=shading)
    figures.update(textures=str(folder), bake_seconds=round(baked.seconds, 4), bake_gl=baked.gl)
    figures.update(
        _render_to_png(
            tree,
            png_path,
            None,
            None,
            45.0,
            (1280, 720),
            1.0,
            2.0,
            textures=str(folder),
            style=style,
        )
    )
    _emit(figures, as_json)


@main.command()
@click.argument("out", type=click.Path(dir_okay=False))
@click.option("--size", type=int, required=True, help="Rows (and columns, unless --cols).")
@click.option("--cols", type=int, default=None, help="Columns [default: --size].")
@click.option("--seed", type=int, default=0, show_default=True, help="Noise seed.")
@click.option(
    "--cell-size", type=float, default=1.0, show_default=True, help="Cell edge (map units)."
)
@click.option("--crs", default=None, help="CRS written in the file (EPSG:NNNN, WKT, PROJ).")
@click.option(
    "--hurst",
    type=float,
    default=0.9,
    show_default=True,
    help="Roughness: octave amplitude ∝ wavelength^hurst.",
)
@click.option(
    "--relief",
    type=float,
    default=500.0,
    show_default=True,
    help="Amplitude of the longest octave (z units); heights lie around relief ± relief.",
)
@click.option(
    "--wavelength",
    type=float,
    default=8192.0,
    show_default=True,
    help="Longest octave's wavelength (cells).",
)
@click.option(
    "--holes", type=float, default=0.0, show_default=True, help="Fraction of nodata cells."
)
@click.option(
    "--compress",
    type=click.Choice(["deflate", "zstd", "lzw", "none"]),
    default="deflate",
    show_default=True,
    help="Tile compression (with the floating-point predictor).",
)
@click.option("--cog", is_flag=True, help="Cloud Optimized GeoTIFF with overviews.")
@click.option("--workers", type=int, default=None, help="Threads [default: the core count].")
@click.option(
    "--block",
    type=int,
    default=2048,
    show_default=True,
    help="Cells per computed block edge (a multiple of 512).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def fractal(
    out: str,
    size: int,
    cols: int | None,
    seed: int,
    cell_size: float,
    crs: str | None,
    hurst: float,
    relief: float,
    wavelength: float,
    holes: float,
    compress: str,
    cog: bool,
    workers: int | None,
    block: int,
    as_json: bool,
) -> None:
    """Write a seeded fractal DEM of any size as a tiled, compressed GeoTIFF, block by block
    (memory stays at a few blocks). Heights depend on (row, col, seed) only: a smaller DEM of
    the same seed is a crop of a larger one."""
    from approxtree.datasets import write_fractal_terrain
    from approxtree.io.output_path import check_output_file

    check_output_file(out, "GeoTIFF")
    t0 = time.perf_counter()
    path = write_fractal_terrain(
        out,
        size,
        cols,
        seed=seed,
        hurst=hurst,
        relief=relief,
        wavelength=wavelength,
        holes=holes,
        cell_size=cell_size,
        crs=crs,
        compress=compress,
        cog=cog,
        workers=workers,
        block=block,
        progress=not as_json,
    )
    seconds = time.perf_counter() - t0
    rows, ncols = size, size if cols is None else cols
    nbytes = path.stat().st_size
    figures = {
        "path": str(path),
        "rows": rows,
        "cols": ncols,
        "seed": seed,
        "seconds": round(seconds, 3),
        "bytes": nbytes,
        "float32_bytes": rows * ncols * 4,
        "compression_ratio": round(rows * ncols * 4 / nbytes, 3),
    }
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
    textures: str | None = None,
    lighting: bool | str = "auto",
    max_triangles: int | None = None,
    style: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Render one frame of ``tree`` to an RGBA PNG at ``path``; returns the frame's stats.

    Without ``eye``: the terrain fitted to the frame (``framing_camera``, from the south).
    Without ``target``: the centre of the tree's root box. textures: folder of a texture
    pyramid; lighting: "auto", "on"/True or "off"/False (decal). style: exaggeration, sun,
    palette, background, lighting (``cartographic_options``; its lighting wins).
    """
    from PIL import Image

    from approxtree.io.atomic import atomic_write
    from approxtree.render import Camera, Engine, framing_camera
    from approxtree.render.engine import EmptyFrameWarning
    from approxtree.render.style import Background, Sun

    style = dict(style or {})
    lighting = style.pop("lighting", lighting)
    # Bad style values fail before any GL work.
    sun = Sun(*style.pop("sun", (315.0, 45.0)))
    background = Background.parse(style.pop("background", "transparent"))
    # An empty frame is reported below as one Warning line, not as Python's warning text.
    with (
        warnings.catch_warnings(),
        Engine(
            tree,
            textures=textures,
            exaggeration=style.pop("exaggeration", 1.0),
            palette=style.pop("palette", None),
        ) as engine,
    ):
        warnings.simplefilter("ignore", EmptyFrameWarning)
        box = tree.bboxes[0]
        if eye is None:
            camera = framing_camera(box, engine.scale, size, fov=fov)
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
            lighting=lighting,
            max_triangles=max_triangles,
            sun=sun,
            background=background,
        )
    with atomic_write(path) as f:
        Image.fromarray(frame.image, mode="RGBA").save(f, format="PNG")
    stats = {k: (_finite(v) if isinstance(v, float) else v) for k, v in frame.stats.items()}
    stats["image"] = str(path)
    if stats.get("warning"):
        click.echo(f"Warning: {stats['warning']}", err=True)
    return stats


@main.command()
@click.argument("tree_file", type=click.Path())
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
@click.option(
    "--textures",
    type=click.Path(file_okay=False),
    default=None,
    help="Folder of a texture pyramid (approxtree bake) to texture the terrain with.",
)
@click.option("--no-lighting", is_flag=True, help="Same as --lighting off (decal mode).")
@cartographic_options
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
    textures: str | None,
    no_lighting: bool,
    as_json: bool,
    style: dict[str, Any],
) -> None:
    """Render a saved tree (store or .atree) to a PNG and print the stats. Without --eye the
    terrain is fitted to the frame, seen from the south; --background transparent leaves
    alpha 0 where no terrain is drawn."""
    from approxtree.io.output_path import check_output_file
    from approxtree.tree import load_tree

    check_output_file(out, "image")
    tree = load_tree(tree_file)
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
        textures=textures,
        max_triangles=max_triangles,
        style={**style, "lighting": "off" if no_lighting else style["lighting"]},
    )
    _emit(stats, as_json)


@main.command()
@click.argument("dem", type=click.Path(dir_okay=False))
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
@quiet_option
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
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
        if textures is not None and kind != "glb":
            from approxtree.errors import InvalidParameterError

            raise InvalidParameterError(f"--textures needs a .glb output; {out} is {kind}.")
    elif textures is not None or skirts:
        from approxtree.errors import InvalidParameterError

        raise InvalidParameterError("--textures and --skirts shape the written mesh: give --out.")
    terrain = _open(dem, encoding, nodata_policy, ground_only, height_scale)
    _check_mesh_strategy(dem, terrain, strategy)
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
        meta = {"strategy": strategy, "crs": terrain.crs, "max_error": figures["max_error"]}
        verts, tris = result.vertices, result.triangles
        surface = len(tris)
        if skirts:
            import numpy as np

            from approxtree.patches.skirts import add_skirts

            # One curtain to a common base: the lowest vertex minus the mesh's max error.
            z = np.asarray(verts)[:, 2]
            relief = float(z.max() - z.min())
            base = float(z.min()) - max(float(figures["max_error"] or 0.0), 1e-3 * relief, 1e-3)
            verts, tris, _ = add_skirts(verts, tris, np.inf, None, base)
        texture = None
        if textures is not None:
            from approxtree.textures.embed import embedded_texture
            from approxtree.textures.pyramid import TexturePyramid

            d = terrain.domain
            texture = embedded_texture(TexturePyramid(textures), d, verts)
        figures.update(write_mesh(out, verts, tris, meta, surface, texture))
    _emit(figures, as_json)


def _check_mesh_strategy(path: str, terrain, strategy: str) -> None:
    """InvalidParameterError for a lattice strategy asked of a TIN or a point cloud."""
    from approxtree.errors import InvalidParameterError
    from approxtree.geometry import Grid

    if strategy != "tin" and not isinstance(terrain, Grid):
        raise InvalidParameterError(
            f"--strategy {strategy} needs a raster grid; {path} reads as a {terrain.kind} "
            "(scattered points or triangles): use --strategy tin."
        )


def _store_epsilon(path: str) -> float | None:
    """The ε a tree store (or legacy tree) was built with; None for a raster."""
    if not _is_tree(path):
        return None
    if Path(path).suffix.lower() == ".atree":
        from approxtree.tree import load_tree

        return float(load_tree(path).epsilon)
    from approxtree.tree.tree_store import StoreReader

    eps = (StoreReader(path).meta.get("params") or {}).get("epsilon")
    return float(eps) if eps else None


def _tiles_terrain(path: str, reader: dict[str, Any]):
    """The terrain to tile: a tree store's stored terrain (windowed), a legacy tree's, or a
    raster DEM read now."""
    if _is_tree(path):
        _no_reader_flags_for_tree(path, _given_reader_options(**reader))
        if Path(path).suffix.lower() == ".atree":
            from approxtree.tree import load_tree

            return load_tree(path).terrain
        from approxtree.tree.tree_store import load_store_terrain

        return load_store_terrain(path)
    return _open(path, **reader)


@main.command()
@click.argument("tree", type=click.Path())
@click.option("--out", required=True, type=click.Path(file_okay=False), help="Folder to write.")
@click.option(
    "--format",
    "tile_format",
    type=click.Choice(["3dtiles", "quantized-mesh"]),
    required=True,
    help="3dtiles: tileset.json + one GLB per node; quantized-mesh: Cesium terrain "
    "(layer.json + z/x/y.terrain, gzip).",
)
@click.option(
    "--samples",
    type=click.Choice(["32", "152", "218"]),
    default="152",
    show_default=True,
    help="quantized-mesh: samples along a tile side (samples − 1 divides 32767, so every "
    "sample has an exact quantized position).",
)
@click.option(
    "--minzoom",
    type=int,
    default=0,
    show_default=True,
    help="quantized-mesh: shallowest level written (CesiumJS asks for level 0).",
)
@click.option(
    "--maxzoom",
    type=int,
    help="quantized-mesh: deepest level [default: where the sample spacing reaches the DEM's "
    "cell].",
)
@click.option(
    "--max-error",
    type=float,
    help="quantized-mesh: go deeper than the DEM's cell until the deepest level's error "
    "(77 067 m / 2^level, CesiumJS's) is at most this many metres.",
)
@click.option(
    "--water-mask",
    type=click.Path(dir_okay=False),
    help="quantized-mesh: land/water raster (nonzero = water) for the water-mask extension.",
)
@click.option(
    "--textures",
    type=click.Path(file_okay=False),
    default=None,
    help="3dtiles: texture pyramid folder (approxtree bake); each node's texture patch is "
    "embedded in its GLB.",
)
@click.option(
    "--texture-format",
    type=click.Choice(["png", "jpeg"]),
    default="png",
    show_default=True,
    help="3dtiles: encoding of the embedded textures.",
)
@click.option(
    "--origin",
    nargs=2,
    type=float,
    default=(0.0, 0.0),
    show_default=True,
    metavar="LON LAT",
    help="3dtiles, terrain without a CRS: where the local east-north-up frame (metres) sits "
    "on the WGS84 ellipsoid (degrees).",
)
@click.option("--no-skirts", is_flag=True, help="3dtiles: leave the skirts out of the tiles.")
@click.option(
    "--leaf-error",
    type=float,
    default=None,
    help="quantized-mesh: the deepest level's tiles (CesiumJS keeps showing them as the camera "
    "comes closer) are within this many metres of the terrain [default: the tree store's ε, "
    "1 m for a raster DEM].",
)
@click.option(
    "--workers",
    type=int,
    default=1,
    show_default=True,
    help="Write the tiles as dask tasks on a local cluster of N processes (1: in this process).",
)
@click.option(
    "--scheduler",
    default=None,
    help="Write the tiles as dask tasks on an existing cluster: its scheduler address "
    "(e.g. tcp://host:8786); its workers must see --out.",
)
@reader_options
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def tiles(
    tree: str,
    out: str,
    tile_format: str,
    samples: str,
    minzoom: int,
    maxzoom: int | None,
    max_error: float | None,
    water_mask: str | None,
    textures: str | None,
    texture_format: str,
    origin: tuple[float, float],
    no_skirts: bool,
    leaf_error: float | None,
    workers: int,
    scheduler: str | None,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    as_json: bool,
) -> None:
    """Write TREE (a tree store from `approxtree build`; for quantized-mesh also a raster DEM)
    as web tiles into the folder --out, replaced as a whole when done."""

    reader = {
        "encoding": encoding,
        "nodata_policy": nodata_policy,
        "ground_only": ground_only,
        "height_scale": height_scale,
    }
    if tile_format == "3dtiles":
        _tiles_3dtiles(
            tree, out, textures, texture_format, origin, no_skirts, workers, scheduler, as_json
        )
        return
    from approxtree.tiles import write_quantized_mesh
    from approxtree.tiles.quantized_mesh import DEFAULT_LEAF_ERROR, check_output

    # The output folder is checked before the terrain is read.
    check_output(out)
    t0 = time.perf_counter()
    terrain = _tiles_terrain(tree, reader)
    if leaf_error is None:
        leaf_error = _store_epsilon(tree) or DEFAULT_LEAF_ERROR
    figures = write_quantized_mesh(
        terrain,
        out,
        samples=int(samples),
        minzoom=minzoom,
        maxzoom=maxzoom,
        max_error=max_error,
        workers=workers,
        water_mask=water_mask,
        leaf_error=leaf_error,
        scheduler=scheduler,
    )
    figures.pop("results")
    figures["seconds"] = round(time.perf_counter() - t0, 3)
    _emit(figures, as_json)


def _tiles_3dtiles(
    tree_path: str,
    out: str,
    textures: str | None,
    texture_format: str,
    origin: tuple[float, float],
    no_skirts: bool,
    workers: int,
    scheduler: str | None,
    as_json: bool,
) -> None:
    """`approxtree tiles --format 3dtiles`: the 3D Tiles tileset of a tree store."""
    from approxtree.tiles import write_3dtiles
    from approxtree.tiles.parallel import check_workers
    from approxtree.tree import load_tree

    check_workers(workers, scheduler)
    # verify=False: the patches are read one by one as the tiles are written.
    tree = load_tree(tree_path, verify=False)
    figures = write_3dtiles(
        tree,
        out,
        textures=textures,
        workers=workers,
        origin=tuple(origin),
        skirts=not no_skirts,
        image_format=texture_format,
        scheduler=scheduler,
    )
    _emit(figures, as_json)


@main.command("bake")
@click.argument("source", type=click.Path())
@click.option(
    "--shading",
    type=click.Choice(["topographic", "phong", "gouraud", "none"]),
    default="topographic",
    show_default=True,
    help="Shading layer (none: thematic and overlays only).",
)
@click.option("--azimuth", type=float, default=315.0, show_default=True, help="Light, degrees.")
@click.option("--altitude", type=float, default=45.0, show_default=True, help="Light, degrees.")
@click.option("--z-factor", type=float, default=1.0, show_default=True, help="Exaggeration.")
@click.option(
    "--alg",
    type=click.Choice(["Horn", "ZevenbergenThorne"]),
    default=None,
    help="Topographic gradient (gdaldem -alg) [default: Horn].",
)
@click.option("--combined", is_flag=True, help="Topographic: gdaldem -combined.")
@click.option("--multidirectional", is_flag=True, help="Topographic: gdaldem -multidirectional.")
@click.option("--thematic", type=click.Path(exists=True, dir_okay=False), help="Thematic raster.")
@click.option(
    "--palette",
    default=None,
    help="Land-cover legend (nlcd, landclass96), gdaldem colour file or matplotlib colormap "
    "for --thematic [default: its colour table, softened].",
)
@click.option(
    "--roads",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Vector layer drawn on top (repeatable).",
)
@click.option(
    "--overlay-colour",
    default="#2864c8",
    show_default=True,
    help="Colour of the --roads lines (#rrggbb).",
)
@click.option(
    "--overlay-width",
    type=float,
    default=None,
    help="Width of the --roads lines in world units [default: 2 texels, the least].",
)
@click.option(
    "--water",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Water polygon layer drawn over the --roads lines (repeatable).",
)
@click.option(
    "--blend",
    type=click.Choice(["shade", "multiply", "overlay", "soft-light", "over"]),
    default="shade",
    show_default=True,
    help="How shading combines with the thematic layer (shade: legend colour on flat ground).",
)
@click.option("--texel", type=float, default=None, help="Texel size in world units.")
@click.option(
    "--max-texture-size",
    type=int,
    default=4096,
    show_default=True,
    help="Texture size limit (power of two): the pyramid halves until a level fits.",
)
@click.option("--no-gl", is_flag=True, help="Bake with numpy even when OpenGL is available.")
@click.option(
    "--out", required=True, type=click.Path(file_okay=False), help="Folder of the pyramid."
)
@reader_options
@quiet_option
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def bake_command(
    source: str,
    shading: str,
    azimuth: float,
    altitude: float,
    z_factor: float,
    alg: str | None,
    combined: bool,
    multidirectional: bool,
    thematic: str | None,
    palette: str | None,
    roads: tuple[str, ...],
    overlay_colour: str,
    overlay_width: float | None,
    water: tuple[str, ...],
    blend: str,
    texel: float | None,
    max_texture_size: int,
    no_gl: bool,
    out: str,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    quiet: bool,
    as_json: bool,
) -> None:
    """Bake a terrain's textures (DEM file or saved tree) into a pyramid folder.

    A point cloud or TIN is shaded from its heights sampled on a lattice (--texel, default its
    mean point spacing).

    The folder holds pyramid.json and one georeferenced GeoTIFF per level, level0.tif the
    finest: tiled, ZSTD-compressed, the last band alpha; grey + alpha for pure shading, RGBA
    otherwise.
    """
    from approxtree.errors import InvalidParameterError
    from approxtree.io.output_path import check_output_folder
    from approxtree.progress import progress_bar
    from approxtree.textures.bake import bake

    check_output_folder(out, "texture pyramid folder")
    if _is_tree(source):
        from approxtree.tree import ApproximationTree

        _no_reader_flags_for_tree(
            source, _given_reader_options(encoding, nodata_policy, ground_only, height_scale)
        )
        terrain = ApproximationTree.load(source).terrain
    else:
        ctx = click.get_current_context()
        if (
            ctx.meta.get("approxtree.windowed") is None
            and no_gl
            and shading == "topographic"
            and thematic is None
            and texel is None
            and _takes_windowed(source, encoding)
        ):
            # A hillshade of the DEM's own lattice is shaded strip by strip: a raster read by
            # windows streams through (read, shade, write overlap; the band is never whole).
            ctx.meta["approxtree.windowed"] = "on"
        terrain = _open(source, encoding, nodata_policy, ground_only, height_scale)
    options: dict[str, Any] = {"azimuth": azimuth, "altitude": altitude, "z_factor": z_factor}
    if shading == "topographic":
        if alg is not None:
            options["algorithm"] = {"Horn": "horn", "ZevenbergenThorne": "zevenbergen-thorne"}[alg]
        options.update(combined=combined, multidirectional=multidirectional)
    elif alg is not None or combined or multidirectional:
        raise InvalidParameterError(
            "--alg, --combined and --multidirectional apply to --shading topographic only."
        )
    if palette is not None and thematic is None:
        raise InvalidParameterError("--palette colours a --thematic raster; give one.")
    with progress_bar("baking pyramid", unit="row", quiet=quiet) as on_progress:
        result = bake(
            terrain,
            out,
            progress=on_progress,
            shading=None if shading == "none" else shading,
            shading_options=options if shading != "none" else None,
            thematic=thematic,
            palette=palette,
            overlays=list(roads),
            overlay_colour=_rgba(overlay_colour),
            overlay_width=overlay_width,
            water=list(water),
            blend=blend,
            texel_size=texel,
            max_texture_size=max_texture_size,
            gl=not no_gl,
        )
    _emit(result.figures(), as_json)


def _rgba(text: str) -> tuple[int, int, int, int]:
    """ "#rrggbb" (or a Background colour name) as an opaque RGBA tuple 0..255."""
    # "#rrggbb" (the default) without importing the renderer, a tenth of bake's import time.
    if len(text) == 7 and text[0] == "#":
        try:
            return (int(text[1:3], 16), int(text[3:5], 16), int(text[5:7], 16), 255)
        except ValueError:
            pass
    from approxtree.render.style import Background

    bg = Background.parse(text)
    if bg.kind != "colour":
        from approxtree.errors import InvalidParameterError

        raise InvalidParameterError(f"Expected a colour (#rrggbb or a name), got {text!r}.")
    r, g, b = (round(v * 255) for v in bg.colour)
    return (r, g, b, 255)


def _open_tree(path: str, epsilon: float, reader: dict[str, Any]):
    """A saved tree (store or .atree), or any terrain file built into a tree now.

    reader: the reader options given (encoding, nodata_policy, ground_only, height_scale).
    """
    from approxtree.tree import ApproximationTree, load_tree

    if _is_tree(path):
        _no_reader_flags_for_tree(path, _given_reader_options(**reader))
        return load_tree(path)
    return ApproximationTree.build(_open(path, **reader), epsilon=epsilon, progress=False)


@main.command()
@click.argument("source", type=click.Path())
@click.option(
    "--textures",
    "textures",
    multiple=True,
    type=click.Path(exists=True, file_okay=False),
    help="Baked texture pyramid folder (repeat for several; TAB cycles, T toggles).",
)
@click.option(
    "--epsilon", type=float, default=1.0, show_default=True, help="ε when SOURCE is a DEM."
)
@click.option(
    "--size", callback=_size, default="1280x720", show_default=True, help="Window size WxH."
)
@click.option("--alpha", type=float, default=1.0, show_default=True, help="Threshold α, pixels.")
@click.option(
    "--gamma", type=float, default=2.0, show_default=True, help="Threshold γ, pixels² (inf: off)."
)
@click.option(
    "--fov", type=float, default=45.0, show_default=True, help="Vertical field of view, degrees."
)
@click.option(
    "--script",
    "script_path",
    type=click.Path(dir_okay=False),
    help='Replay a camera path: JSON list of {"eye", "target", "frames", "keys"}; exit at the end.',
)
@click.option(
    "--stats", "stats_path", type=click.Path(dir_okay=False), help="JSON line of stats per frame."
)
@click.option(
    "--screenshots",
    type=click.Path(file_okay=False),
    help="Folder for one PNG per keyframe of --script.",
)
@click.option(
    "--keys",
    "keys_text",
    default="",
    help='Scripted key presses "FRAME:KEY,...", e.g. "0:L,5:shift+PAGE_UP".',
)
@click.option(
    "--frames", type=int, default=None, help="Stop after this many frames (without --script)."
)
@click.option(
    "--max-uploads",
    type=int,
    default=32,
    show_default=True,
    help="Patch meshes uploaded per frame at most (0: no limit).",
)
@click.option(
    "--upload-ms",
    type=float,
    default=None,
    help="Stop uploading meshes after this many milliseconds in a frame (after one).",
)
@click.option(
    "--legend",
    type=click.Choice(["nlcd", "landclass96"]),
    default=None,
    help="Land-cover legend of the --textures layer (default: the elevation palette's).",
)
@click.option(
    "--bookmarks",
    "bookmarks_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Bookmark file [default: $XDG_CONFIG_HOME/approxtree/bookmarks.json].",
)
@cartographic_options
@reader_options
@_reports_errors
def view(
    source: str,
    textures: tuple[str, ...],
    epsilon: float,
    size: tuple[int, int],
    alpha: float,
    gamma: float,
    fov: float,
    script_path: str | None,
    stats_path: str | None,
    screenshots: str | None,
    keys_text: str,
    frames: int | None,
    max_uploads: int,
    upload_ms: float | None,
    legend: str | None,
    bookmarks_path: str | None,
    style: dict[str, Any],
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
) -> None:
    """Open an interactive window over a tree file or a DEM (F1 in the window: keys)."""
    from approxtree.io.output_path import check_output_file, check_output_folder
    from approxtree.render.selector import check_thresholds
    from approxtree.viewer import load_script, parse_key_presses, script_frames
    from approxtree.viewer.app import Viewer

    check_thresholds(alpha, gamma)
    if stats_path is not None:
        check_output_file(stats_path, "stats file")
    if screenshots is not None:
        check_output_folder(screenshots, "screenshot folder")
    from approxtree.render.style import Background, Sun

    # Bad picture options fail before the window opens.
    Sun(*style["sun"])
    Background.parse(style["background"])
    presses = parse_key_presses(keys_text)
    script = script_frames(load_script(script_path)) if script_path else None
    reader = dict(
        encoding=encoding,
        nodata_policy=nodata_policy,
        ground_only=ground_only,
        height_scale=height_scale,
    )
    tree = _open_tree(source, epsilon, reader)
    with Viewer(
        tree,
        textures=list(textures),
        size=size,
        alpha=alpha,
        gamma=gamma,
        fov=fov,
        max_uploads=max_uploads,
        budget_ms=upload_ms,
        legend=legend,
        bookmarks=bookmarks_path,
        source=source,
        **style,
    ) as viewer:
        drawn = viewer.run(script, presses, stats_path, screenshots, max_frames=frames)
    if script is not None:
        click.echo(json.dumps({"frames": drawn, "stats": stats_path, "screenshots": screenshots}))


@main.command()
@click.argument("source", type=click.Path())
@click.argument("target", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object.")
@_reports_errors
def convert(source: str, target: str, as_json: bool) -> None:
    """Copy a saved tree into another form: a legacy OLD.atree into a store NEW.zarr, a store
    folder into a single-file NEW.zarr.zip (or back), or to/from an fsspec URL. The source is
    verified (every checksum) first; the target is written atomically."""
    from approxtree.errors import InvalidParameterError
    from approxtree.tree import load_tree

    if not _is_tree(source):
        raise InvalidParameterError(
            f"{source} is not a saved tree (.atree, .zarr, .zip or a URL); build one with "
            "`approxtree build`."
        )
    if os.path.realpath(source) == os.path.realpath(target):
        raise InvalidParameterError(f"convert writes a new tree: {target} is {source} itself.")
    _check_tree_output(target)
    t0 = time.perf_counter()
    tree = load_tree(source)
    nbytes = tree.save(target)
    figures = {
        "source": source,
        "target": target,
        "nodes": len(tree),
        "bytes": nbytes,
        "seconds": round(time.perf_counter() - t0, 4),
    }
    _emit(figures, as_json)


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
@quiet_option
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
    quiet: bool,
    as_json: bool,
) -> None:
    """Rate–distortion comparison: binary-tree decimation and refinement, uniform grid, TIN
    and RTIN at the same triangle counts (L2, max error, SNR in dB, seconds)."""
    from approxtree.geometry import Grid
    from approxtree.progress import progress_bar
    from approxtree.rd import lattice_heights, rd_curves
    from approxtree.rd.curves import json_ready, plot_rd

    if plot:
        from approxtree.io.output_path import check_output_file

        check_output_file(plot, "plot")
    terrain = _open(dem, encoding, nodata_policy, ground_only, height_scale)
    if not isinstance(terrain, Grid):
        from approxtree.errors import InvalidParameterError

        raise InvalidParameterError(
            f"The rd command needs a raster grid, {dem} reads as a {terrain.kind}."
        )
    heights = lattice_heights(terrain, size)
    names = [m.strip() for m in methods.split(",") if m.strip()]
    with progress_bar("rate-distortion", unit="stage", quiet=quiet) as on_progress:
        result = rd_curves(heights, rates, names, progress=on_progress)
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
