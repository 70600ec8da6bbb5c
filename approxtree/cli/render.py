"""``approxtree render``: Render a saved tree or any terrain file to a PNG (or JPEG) and print
the stats."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from approxtree.cli.common import _emit, _render_to_png, _reports_errors, _tree_of, image_format
from approxtree.cli.options import (
    BuildChoices,
    _size,
    build_options,
    cartographic_options,
    fov_option,
    ground_surface_option,
    json_option,
    overwrite_option,
    quiet_option,
    reader_options,
    replaceable,
    textures_option,
    threshold_options,
)

#: Largest camera coordinate accepted (world units): a million km, beyond any terrain's frame.
MAX_COORDINATE = 1e9


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
    # Beyond this the camera's matrices overflow (and no terrain is that far).
    if not all(abs(v) <= MAX_COORDINATE for v in xyz):
        raise click.BadParameter(
            f"expected finite coordinates within ±{MAX_COORDINATE:g} world units, got {value!r}"
        )
    return xyz


@click.command()
@click.argument("tree_file", type=click.Path())
@click.option("--eye", callback=_xyz, help="Camera position X,Y,Z in world units.")
@click.option("--target", callback=_xyz, help="Point looked at X,Y,Z [default: tree centre].")
@fov_option
@click.option(
    "--size", callback=_size, default="1280x720", show_default=True, help="Image size WxH."
)
@threshold_options
@click.option("--wireframe", is_flag=True, help="Draw triangle edges.")
@click.option("--full-resolution", is_flag=True, help="Draw the unsimplified terrain (reference).")
@click.option(
    "--max-triangles",
    type=int,
    default=None,
    help="Triangle budget (skirts included) instead of --alpha: smallest α that fits.",
)
@click.option(
    "--out",
    required=True,
    type=click.Path(dir_okay=False),
    help="Image to write: .png (RGBA) or .jpg (RGB, composited on the background).",
)
@textures_option(
    "Folder of a texture pyramid (approxtree bake) to texture the terrain with; a second "
    "--textures DETAIL@LEVEL refines it with the pyramid DETAIL for nodes at tree level >= "
    "LEVEL inside DETAIL's footprint."
)
@click.option("--no-lighting", is_flag=True, help="Same as --lighting off (decal mode).")
@cartographic_options
@build_options
@reader_options
@ground_surface_option
@overwrite_option
@quiet_option
@json_option
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
    textures: list[Any],
    no_lighting: bool,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    quiet: bool,
    as_json: bool,
    style: dict[str, Any],
    build: BuildChoices,
) -> None:
    """Render a saved tree (store or .atree), or any terrain file built into a tree in memory
    (--epsilon, ...), to a PNG (or JPEG) and print the stats. Without --eye the terrain is
    fitted to the frame, seen from the south; --background transparent leaves alpha 0 where no
    terrain is drawn (a PNG's). A terrain file's build shows a bar on a terminal (-q: none)."""
    from approxtree.io.output_path import check_output_file

    check_output_file(out, "image")
    image_format(out)
    replaceable(out, "image")
    tree = _tree_of(tree_file, build, encoding, nodata_policy, ground_only, height_scale)
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
        textures=textures[0] if textures else None,
        max_triangles=max_triangles,
        style={**style, "lighting": "off" if no_lighting else style["lighting"]},
    )
    _emit(stats, as_json)
