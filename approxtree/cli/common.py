"""Helpers of several commands: errors, output, reading terrains, trees."""

from __future__ import annotations

import functools
import json
import math
import sys
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
            # A figure that does not apply (a point set's width, no warning) reads as a dash,
            # not as Python's None; --json keeps null.
            click.echo(f"{k:<{width}}  {'—' if v is None else v}")


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
    meta = ctx.meta if ctx is not None else {}
    windowed = meta.get("approxtree.windowed")
    # "auto" is the reader's default: it is passed on only as an explicit on or off.
    if windowed in ("on", "off"):
        options["windowed"] = windowed == "on"
    _check_reader_flags(path, options)
    if "approxtree.all_points" in meta:
        surface = _ground_surface(path, options, bool(meta["approxtree.all_points"]))
        if surface is not None:
            return surface
    return open_terrain(path, **options)


def _ground_surface(path: str, options: dict[str, Any], all_points: bool):
    """The ground surface of a point cloud drawn by a picture command (``ground_surface_option``):
    its ground points when it has them beside others and neither --ground-only nor
    --all-points was given, with one ``Note:`` line (none with -q); None for any other file
    or choice (the reader's own defaults apply)."""
    from approxtree.cli.options import is_quiet
    from approxtree.errors import InvalidParameterError
    from approxtree.io import detect_format
    from approxtree.io._common import existing_file
    from approxtree.io.pointcloud import read_ground_surface, read_point_cloud

    if all_points and options.get("ground_only"):
        raise InvalidParameterError("--all-points and --ground-only contradict; give one.")
    if all_points or options.get("ground_only"):
        return None
    fmt = detect_format(existing_file(path), encoding=options.get("encoding"))
    if fmt.reader is not read_point_cloud:
        return None
    terrain, kept = read_ground_surface(path, crs=options.get("crs"))
    if kept is not None and not is_quiet():
        click.echo(
            f"Note: {Path(path).name}: drawing its {kept[0]:,} ground points (classification 2) "
            f"of {kept[1]:,}, gaps filled; --all-points draws every point.",
            err=True,
        )
    return terrain


#: The reader options of the command line, by the keyword the readers take.
_READER_FLAGS = {
    "encoding": "--encoding",
    "nodata": "--nodata",
    "ground_only": "--ground-only",
    "height_scale": "--height-scale",
    "windowed": "--windowed",
    "crs": "--crs",
    "cell_size": "--cell-size",
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
    # --crs and --cell-size live in the click context (reader_options), like --windowed.
    ctx = click.get_current_context(silent=True)
    meta = ctx.meta if ctx is not None else {}
    for key in ("crs", "cell_size"):
        if meta.get(f"approxtree.{key}") is not None:
            options[key] = meta[f"approxtree.{key}"]
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


def _is_tree(path: str) -> bool:
    """Whether ``path`` names a saved tree: a tree store (.zarr, .zip, URL, store folder) or a
    legacy .atree file."""
    from approxtree.tree.zarr_store import is_store

    return Path(path).suffix.lower() == ".atree" or is_store(path)


def _check_tree_output(out: str) -> None:
    """StoreError now, before any work, when the tree cannot be written at ``out`` (or would
    replace what approxtree did not write, without --overwrite); InvalidParameterError for a
    legacy .atree path (read only now)."""
    from approxtree.cli.options import replaceable
    from approxtree.io.output_path import check_output_file, check_output_folder
    from approxtree.tree.atree import refuse_legacy_target
    from approxtree.tree.zarr_store import is_url, is_zip

    refuse_legacy_target(out)
    if is_url(out):
        return
    if is_zip(out):
        check_output_file(out, "tree file")
        replaceable(out, "tree file")
    else:
        check_output_folder(out, "tree store")
        replaceable(out, "tree store")


#: Image extensions of a rendered frame → Pillow format.
IMAGE_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}


def image_format(path: str | Path) -> str:
    """The Pillow format an image ``path`` names by its extension; InvalidParameterError for
    another extension."""
    from approxtree.errors import InvalidParameterError

    suffix = Path(path).suffix.lower()
    if suffix not in IMAGE_FORMATS:
        raise InvalidParameterError(
            f"Cannot write the image {path}: unknown extension {suffix or '(none)'!r}; use .png "
            "(RGBA) or .jpg (no transparency)."
        )
    return IMAGE_FORMATS[suffix]


def _save_image(path: Path, image: Any, background: Any) -> None:
    """Write the (h, w, 4) uint8 RGBA frame atomically as the format ``path`` names, with
    approxtree's mark; JPEG has no alpha, so the frame is composited on the background's
    colour (black for a transparent one; the sky is drawn opaque already)."""
    import numpy as np
    from PIL import Image

    from approxtree.io.atomic import atomic_write
    from approxtree.io.own_output import MARK, png_info

    fmt = image_format(path)
    with atomic_write(path) as f:
        if fmt == "PNG":
            Image.fromarray(image, mode="RGBA").save(f, format="PNG", pnginfo=png_info())
            return
        rgba = np.asarray(image, dtype=np.float32) / 255.0
        colour = np.asarray(background.colour, dtype=np.float32)
        rgb = rgba[..., :3] * rgba[..., 3:] + colour * (1.0 - rgba[..., 3:])
        rgb8 = np.round(rgb * 255.0).astype(np.uint8)
        Image.fromarray(rgb8, mode="RGB").save(f, format="JPEG", quality=92, comment=MARK)


def _no_reader_flags_for_tree(path: str, options: dict[str, Any]) -> None:
    """InvalidParameterError when reader options are given with a saved tree."""
    from approxtree.errors import InvalidParameterError

    if options:
        flags = ", ".join(_READER_FLAGS[name] for name in options)
        raise InvalidParameterError(
            f"{flags} choose how a terrain file is read; {path} is a saved tree, "
            "already built. Leave them out."
        )


def _tree_of(
    path: str,
    build: Any,
    encoding: str | None,
    nodata_policy: str | None,
    ground_only: bool,
    height_scale: float | None,
    verify: bool = True,
):
    """The tree of any terrain, for the commands that draw or tile one (render, tiles, view).

    A saved tree (store, .zip, URL, legacy .atree) is loaded (``verify``: every patch's
    checksum now); any terrain file (raster DEM, height PNG, array, SCAPE, point cloud, TIN)
    is read with the reader options (as the command received them, see ``_open``) and built
    into a tree in memory, as ``approxtree build`` builds it with the same options. build: the
    command's ``BuildChoices`` (cli/options.py). Reader and build options given with a saved
    tree are an InvalidParameterError: it is read and built already. The build shows the
    "building tree" bar on a terminal unless the command was given -q (``is_quiet``).
    """
    from approxtree.cli.options import is_quiet
    from approxtree.progress import progress_bar
    from approxtree.tree import ApproximationTree, load_tree

    reader = (encoding, nodata_policy, ground_only, height_scale)
    if _is_tree(path):
        _no_reader_flags_for_tree(path, _given_reader_options(*reader))
        _no_build_flags_for_tree(path, build.given)
        return load_tree(path, verify=verify)
    terrain = _open(path, *reader)
    with progress_bar("building tree", unit="point", quiet=is_quiet()) as on_progress:
        return ApproximationTree.build(terrain, **build.kwargs(), progress=on_progress)


def _terrain_of(
    path: str,
    encoding: str | None,
    nodata_policy: str | None,
    ground_only: bool,
    height_scale: float | None,
):
    """The terrain of any terrain file or saved tree, for the commands that work on the
    terrain itself (tiles --format quantized-mesh, bake, mesh, rd).

    A terrain file is read with the reader options (``_open``); a saved tree gives its stored
    terrain, nothing else of the tree loaded (a store's grid heights read by windows). Reader
    options given with a saved tree are an InvalidParameterError.
    """
    reader = (encoding, nodata_policy, ground_only, height_scale)
    if not _is_tree(path):
        return _open(path, *reader)
    _no_reader_flags_for_tree(path, _given_reader_options(*reader))
    from approxtree.tree.store import open_store

    return open_store(path).terrain()


def _no_build_flags_for_tree(path: str, given: tuple[str, ...]) -> None:
    """InvalidParameterError when build options (--epsilon, ...) are given with a saved tree."""
    from approxtree.errors import InvalidParameterError

    if given:
        verb = "chooses" if len(given) == 1 else "choose"
        raise InvalidParameterError(
            f"{', '.join(given)} {verb} how a terrain file is built into a tree; {path} is a "
            "saved tree, already built. Leave them out, or rebuild it with `approxtree build`."
        )


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
    textures: Any = None,
    lighting: bool | str = "auto",
    max_triangles: int | None = None,
    style: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Render one frame of ``tree`` to an RGBA PNG (or a JPEG, by ``path``'s extension) at
    ``path``; returns the frame's stats.

    Without ``eye``: the terrain fitted to the frame (``framing_camera``, from the south).
    Without ``target``: the centre of the tree's root box. textures: folder of a texture
    pyramid or a DetailTextures; lighting: "auto", "on"/True or "off"/False (decal). style:
    exaggeration, sun, palette, background, lighting (``cartographic_options``; its lighting
    wins).
    """
    from approxtree.render import Camera, Cut, Engine, Style, Sun, framing_camera
    from approxtree.render.frame import EmptyFrameWarning

    image_format(path)
    style = dict(style or {})
    # Bad cut and style values fail before any GL work.
    cut = Cut(alpha, gamma, max_triangles, full_resolution)
    look = Style(
        lighting=style.pop("lighting", lighting),
        sun=Sun(*style.pop("sun", (315.0, 45.0))),
        background=style.pop("background", "transparent"),
        wireframe=wireframe,
    )
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
        frame = engine.render(camera, size, cut, style=look)
    _save_image(path, frame.image, look.background)
    stats = {k: (_finite(v) if isinstance(v, float) else v) for k, v in frame.stats.items()}
    stats["image"] = str(path)
    if stats.get("warning"):
        click.echo(f"Warning: {stats['warning']}", err=True)
    return stats
