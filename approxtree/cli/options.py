"""Option groups shared by the commands (click decorators and callbacks)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import click


def fov_option(fn: Callable[..., Any]) -> Callable[..., Any]:
    """--fov, the same on render, view."""
    fn = click.option(
        "--fov",
        type=float,
        default=45.0,
        show_default=True,
        help="Vertical field of view, degrees.",
    )(fn)
    return fn


def json_option(fn: Callable[..., Any]) -> Callable[..., Any]:
    """--json, the same on info, build, demo, fractal, render, mesh, tiles, bake, convert, rd."""
    fn = click.option(
        "--json", "as_json", is_flag=True, help="Print the figures as one JSON object."
    )(fn)
    return fn


def overwrite_option(fn: Callable[..., Any]) -> Callable[..., Any]:
    """--overwrite, the same on every command that writes a file or folder (rio's convention):
    without it an existing output approxtree did not write is refused (``replaceable``)."""
    return click.option(
        "--overwrite",
        is_flag=True,
        default=False,
        expose_value=False,
        callback=_remember,
        help="Replace an existing output even when approxtree did not write it (a symbolic "
        "link never is).",
    )(fn)


def replaceable(out: str, what: str) -> None:
    """StoreError before any work unless ``out`` may be written as a ``what``
    (``own_output.check_replaceable``: new, empty, or this kind of approxtree output, or
    anything but a link with --overwrite); with --overwrite, the command's writers may then
    replace it (``own_output.overwriting``, until the command ends)."""
    from approxtree.io.own_output import check_replaceable, overwriting

    ctx = click.get_current_context()
    overwrite = bool(ctx.meta.get("approxtree.overwrite"))
    check_replaceable(out, what, overwrite)
    if overwrite:
        ctx.with_resource(overwriting(out))


def threshold_options(fn: Callable[..., Any]) -> Callable[..., Any]:
    """--alpha, --gamma, the same on render, view."""
    fn = click.option(
        "--gamma",
        type=float,
        default=2.0,
        show_default=True,
        help="Threshold γ, pixels² (inf: off).",
    )(fn)
    fn = click.option(
        "--alpha", type=float, default=1.0, show_default=True, help="Threshold α, pixels."
    )(fn)
    return fn


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
    # --crs, --cell-size and --windowed are kept in the click context as "approxtree.NAME"
    # (not parameters of every command): _given_reader_options and _open read them.
    fn = click.option(
        "--crs",
        default=None,
        expose_value=False,
        callback=_remember,
        help="CRS of a file that carries none or a wrong one (EPSG:4326, a PROJ string or a "
        "WKT); e.g. a .npz, PGM or PNG in degrees.",
    )(fn)
    fn = click.option(
        "--cell-size",
        default=None,
        expose_value=False,
        callback=_remember_cell_size,
        help="Grid cell size D or DX,DY in CRS units, for a file without a georeference "
        "(SCAPE .stm, PGM, PNG, arrays: cell size 1 otherwise).",
    )(fn)
    fn = click.option(
        "--windowed",
        type=click.Choice(["auto", "on", "off"]),
        default=None,
        expose_value=False,
        callback=_remember,
        help="GDAL rasters: read by windows on demand (on), into memory (off), or windowed when "
        "the band exceeds 1 GiB (auto; APPROXTREE_WINDOWED_BYTES overrides) [default: auto].",
    )(fn)
    return fn


@dataclass(frozen=True)
class BuildChoices:
    """How a terrain file given where a tree is meant is built into one (``build_options``).

    given: the flags the user gave explicitly (a saved tree refuses them: it is built already).
    """

    epsilon: float
    max_points: int
    fanout: int
    policy: str
    given: tuple[str, ...] = ()

    def kwargs(self) -> dict[str, Any]:
        """The keywords of ``ApproximationTree.build``."""
        return {
            "epsilon": self.epsilon,
            "max_points": self.max_points,
            "fanout": self.fanout,
            "policy": self.policy,
        }


#: The build options of the commands that take a tree or a terrain file, by keyword: the flag,
#: the default (the same as ``approxtree build``'s) and the help text.
BUILD_OPTIONS = {
    "epsilon": ("--epsilon", 1.0, "Terrain file: threshold ε of the tree built (z units)."),
    "max_points": ("--max-points", 33 * 33, "Terrain file: s, most data points per patch."),
    "fanout": ("--fanout", "4", "Terrain file: d, children per node (4 quadtree, 2 k-d tree)."),
    "policy": (
        "--policy",
        "type",
        "Terrain file: strategy per node (type, auto, a name, level:…, semantic:…).",
    ),
}


def build_options(fn: Callable[..., Any]) -> Callable[..., Any]:
    """--epsilon, --max-points, --fanout, --policy: how a terrain file (DEM, point cloud, TIN)
    given where a tree is meant is built in memory, with ``approxtree build``'s defaults
    (render, tiles, view). Passed to the command as keyword ``build``, a BuildChoices."""
    types = {"epsilon": float, "max_points": int, "fanout": click.Choice(["2", "4"]), "policy": str}
    for name, (flag, default, text) in reversed(BUILD_OPTIONS.items()):
        fn = click.option(
            flag, name, type=types[name], default=default, show_default=True, help=text
        )(fn)

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        ctx = click.get_current_context()
        given = tuple(
            flag
            for name, (flag, _, _) in BUILD_OPTIONS.items()
            if ctx.get_parameter_source(name) != click.core.ParameterSource.DEFAULT
        )
        kwargs["build"] = BuildChoices(
            epsilon=kwargs.pop("epsilon"),
            max_points=kwargs.pop("max_points"),
            fanout=int(kwargs.pop("fanout")),
            policy=kwargs.pop("policy"),
            given=given,
        )
        return fn(*args, **kwargs)

    return wrapper


def _remember(ctx: click.Context, param: click.Parameter, value: object) -> None:
    """Keep a reader option in the context as "approxtree.NAME" (None when not given)."""
    ctx.meta[f"approxtree.{param.name}"] = value


def quiet_option(fn: Callable[..., Any]) -> Callable[..., Any]:
    """-q/--quiet (keyword ``quiet``, also kept in the click context as "approxtree.quiet"):
    no progress bar and no progress or note lines; errors and warnings stay one line each.
    Without it a command shows its bar on stderr only when stderr is a terminal; use it as
    ``with progress_bar("desc", unit="…", quiet=quiet) as report: work(..., progress=report)``
    (``approxtree.progress``). Every command that shows progress takes it."""
    return click.option(
        "-q",
        "--quiet",
        is_flag=True,
        callback=_remember_and_pass,
        help="No progress bar or progress lines (no bar either off a terminal).",
    )(fn)


def is_quiet() -> bool:
    """Whether the running command was given -q/--quiet (False outside a command)."""
    ctx = click.get_current_context(silent=True)
    return bool(ctx is not None and ctx.meta.get("approxtree.quiet"))


def _remember_and_pass(ctx: click.Context, param: click.Parameter, value: object) -> object:
    """Keep the option in the context like ``_remember`` and pass it to the command too."""
    _remember(ctx, param, value)
    return value


def ground_surface_option(fn: Callable[..., Any]) -> Callable[..., Any]:
    """--all-points, on the commands that draw a picture of a terrain file (render, view):
    without it a point cloud with ground points (class 2) beside others is drawn from its
    ground points, and one ``Note:`` line says so (``common._open``). Kept in the click
    context as "approxtree.all_points" (present: the command draws a ground surface)."""
    return click.option(
        "--all-points",
        is_flag=True,
        default=False,
        expose_value=False,
        callback=_remember,
        help="Point clouds: draw every point (trees, buildings) [default: the ground points, "
        "class 2, when the cloud has them beside others].",
    )(fn)


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
            default="hypsometric",
            show_default=True,
            help="Hypsometric palette: hypsometric (tints over the terrain's own min..max), "
            "relief or atlas (fixed elevations in metres), grey, stretched (the former min..max "
            "ramp).",
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


def _size(ctx: click.Context, param: click.Parameter, value: str) -> tuple[int, int]:
    """Parse "WxH" into (width, height)."""
    try:
        w, h = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"expected WxH in pixels, e.g. 1280x720, got {value!r}") from None
    return w, h


def _remember_cell_size(ctx: click.Context, param: click.Parameter, value: str | None) -> None:
    """Keep --cell-size in the context like _remember: a number, or a pair from "DX,DY"."""
    cell: float | tuple[float, ...] | None = None
    if value is not None:
        try:
            parts = [float(v) for v in value.split(",")]
        except ValueError:
            parts = []
        if len(parts) not in (1, 2) or not all(0.0 < v < float("inf") for v in parts):
            raise click.BadParameter(
                f"{value!r}: give one positive number D or two, DX,DY.", ctx, param
            )
        cell = parts[0] if len(parts) == 1 else tuple(parts)
    _remember(ctx, param, cell)


def parse_rgba(text: str) -> tuple[int, int, int, int]:
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


class _OneLineError(click.ClickException):
    """An ApproxTreeError met while click parses an option: one ``Error:`` line on stderr and
    exit 2, as ``_reports_errors`` says the errors met inside a command."""

    exit_code = 2


def textures_option(help: str, most: int | None = 1) -> Callable[..., Any]:
    """--textures FOLDER [--textures DETAIL@LEVEL] ..., the same on render, view and tiles: the
    command receives ``textures``, a list of drapes (``textures.detail.parse_textures``: an
    opened TexturePyramid, or a DetailTextures where DETAIL@LEVEL follows its base), at most
    ``most`` of them (None: any number). A bad spelling is one ``Error:`` line (exit 2)."""

    def drapes(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> list[Any]:
        from approxtree.errors import ApproxTreeError, InvalidParameterError
        from approxtree.textures.detail import open_drape, parse_textures

        try:
            # Opened here: a missing or broken pyramid fails before any work.
            parsed = [open_drape(drape) for drape in parse_textures(value)]
            if most is not None and len(parsed) > most:
                raise InvalidParameterError(
                    f"{ctx.info_name} drapes one texture pyramid: give one --textures FOLDER, "
                    "optionally followed by --textures DETAIL@LEVEL."
                )
        except ApproxTreeError as exc:
            raise _OneLineError(str(exc)) from exc
        return parsed

    return click.option("--textures", "textures", multiple=True, callback=drapes, help=help)
