"""``approxtree bake``: Bake a terrain's textures (DEM file or saved tree) into a pyramid folder."""

from __future__ import annotations

from typing import Any

import click

from approxtree.cli.common import _emit, _is_tree, _reports_errors, _terrain_of
from approxtree.cli.options import (
    json_option,
    overwrite_option,
    parse_rgba,
    quiet_option,
    reader_options,
    replaceable,
)
from approxtree.io.warp import RESAMPLINGS


def _takes_windowed(path: str, encoding: str | None) -> bool:
    """Whether the reader of ``path``'s format can read it by windows (GDAL rasters)."""
    from approxtree.io import detect_format
    from approxtree.io._common import existing_file

    return "windowed" in detect_format(existing_file(path), encoding=encoding).options


@click.command("bake")
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
@click.option(
    "--image",
    "images",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Image draped (RGB, RGBA, grey or paletted raster in any CRS; repeatable, the first "
    "at the bottom).",
)
@click.option(
    "--resampling",
    type=click.Choice(list(RESAMPLINGS)),
    default="bilinear",
    show_default=True,
    help="How --image rasters are warped onto the texture (gdalwarp -r).",
)
@click.option("--thematic", type=click.Path(exists=True, dir_okay=False), help="Thematic raster.")
@click.option(
    "--palette",
    default=None,
    help="Land-cover legend (nlcd, landclass96), gdaldem colour file or matplotlib colormap "
    "for --thematic [default: its colour table, softened].",
)
@click.option(
    "--lines",
    "--roads",
    "lines",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Line overlay: a vector layer of lines (streams, roads, boundaries) drawn on top "
    "(repeatable; --roads is the same option under its former name).",
)
@click.option(
    "--overlay-colour",
    default="#2864c8",
    show_default=True,
    help="Colour of the --lines overlay (#rrggbb).",
)
@click.option(
    "--overlay-width",
    type=float,
    default=None,
    help="Width of the --lines overlay in world units [default: 2 texels, the least].",
)
@click.option(
    "--water",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Water polygon layer drawn over the --lines overlay (repeatable).",
)
@click.option(
    "--water-level",
    type=float,
    default=None,
    help="A flood: texels of the terrain below this height drawn as water under the shading "
    "(approxtree update --textures --water-level moves it).",
)
@click.option(
    "--blend",
    type=click.Choice(["shade", "multiply", "overlay", "soft-light", "over"]),
    default="shade",
    show_default=True,
    help="How shading combines with the images and thematic layer (shade: their colour on flat "
    "ground).",
)
@click.option("--texel", type=float, default=None, help="Texel size in world units.")
@click.option(
    "--max-texture-size",
    type=int,
    default=4096,
    show_default=True,
    help="Texture size limit (power of two): the pyramid halves until a level fits.",
)
@click.option(
    "--no-gl", is_flag=True, help="Bake with numpy even on a GPU (a CPU-only OpenGL is never used)."
)
@click.option(
    "--out", required=True, type=click.Path(file_okay=False), help="Folder of the pyramid."
)
@reader_options
@overwrite_option
@quiet_option
@json_option
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
    images: tuple[str, ...],
    resampling: str,
    thematic: str | None,
    palette: str | None,
    lines: tuple[str, ...],
    overlay_colour: str,
    overlay_width: float | None,
    water: tuple[str, ...],
    water_level: float | None,
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

    --image rasters are warped onto the texture by GDAL strip by strip (any size), thematic
    layers drawn over them, the shading blended with both (--blend), --roads on top.

    The folder holds pyramid.json and one georeferenced GeoTIFF per level, level0.tif the
    finest: tiled, ZSTD-compressed, the last band alpha; grey + alpha for pure shading, RGBA
    otherwise. `approxtree update --textures` adds small delta files (level0.BUILD.tif)
    holding only the re-baked tiles; pyramid.json lists them.
    """
    from approxtree.errors import InvalidParameterError
    from approxtree.io.output_path import check_output_folder
    from approxtree.progress import progress_bar
    from approxtree.render.context import hardware_gl, optional_context
    from approxtree.textures.bake import bake
    from approxtree.textures.palettes import check_thematic_palette

    check_output_folder(out, "texture pyramid folder")
    replaceable(out, "texture pyramid")
    # A palette nothing takes fails before the terrain is read.
    check_thematic_palette(palette)
    # The hillshade is baked with OpenGL on a GPU; with numpy without one, and on a software
    # rasterizer (llvmpipe), which the numba kernels outrun on the same cores.
    gl = not no_gl and shading == "topographic" and hardware_gl()
    if not _is_tree(source):
        ctx = click.get_current_context()
        if (
            ctx.meta.get("approxtree.windowed") is None
            and not gl
            and shading == "topographic"
            and thematic is None
            and water_level is None
            and not images
            and texel is None
            and _takes_windowed(source, encoding)
        ):
            # A hillshade of the DEM's own lattice is shaded strip by strip: a raster read by
            # windows streams through (read, shade, write overlap; the band is never whole).
            ctx.meta["approxtree.windowed"] = "on"
    terrain = _terrain_of(source, encoding, nodata_policy, ground_only, height_scale)
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
    with (
        optional_context(gl) as gl_context,
        progress_bar("baking pyramid", unit="row", quiet=quiet) as on_progress,
    ):
        result = bake(
            terrain,
            out,
            progress=on_progress,
            shading=None if shading == "none" else shading,
            shading_options=options if shading != "none" else None,
            thematic=thematic,
            images=list(images),
            resampling=resampling,
            palette=palette,
            overlays=list(lines),
            overlay_colour=parse_rgba(overlay_colour),
            overlay_width=overlay_width,
            water=list(water),
            water_level=water_level,
            blend=blend,
            texel_size=texel,
            max_texture_size=max_texture_size,
            gl=gl,
            context=gl_context,
        )
    _emit(result.figures(), as_json)
    # The pyramid is complete and every file closed: the program may skip the teardown.
    from approxtree import cli

    cli.end_without_teardown()
