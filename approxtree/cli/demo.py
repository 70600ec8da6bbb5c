"""``approxtree demo``: Build the tree of the sample terrain (matplotlib's Jacksboro fault DEM),
bake its hillshade pyramid (next to the tree, <out>_textures/) and render it: the baked
shading over the hypsometric palette, fitted to the frame, in front of a sky.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import click

from approxtree.cli.common import (
    _check_tree_output,
    _emit,
    _render_to_png,
    _reports_errors,
    image_format,
    terrain_figures,
    tree_figures,
)
from approxtree.cli.options import (
    cartographic_options,
    json_option,
    overwrite_option,
    quiet_option,
    replaceable,
)


@click.command()
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
@overwrite_option
@quiet_option
@json_option
@_reports_errors
def demo(
    out: str, epsilon: float, png: str | None, quiet: bool, as_json: bool, style: dict[str, Any]
) -> None:
    """Build the tree of the sample terrain (matplotlib's Jacksboro fault DEM), bake its
    hillshade pyramid (next to the tree, <out>_textures/) and render it: the baked shading
    over the hypsometric palette, fitted to the frame, in front of a sky. The build and the
    bake show bars on a terminal (-q: none)."""
    from approxtree.datasets import sample_terrain
    from approxtree.io.output_path import check_output_file, check_output_folder
    from approxtree.progress import progress_bar
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
    image_format(png_path)
    replaceable(str(png_path), "image")
    check_output_folder(folder, "texture pyramid folder")
    replaceable(str(folder), "texture pyramid")
    terrain = sample_terrain()
    t0 = time.perf_counter()
    with progress_bar("building tree", unit="point", quiet=quiet) as on_progress:
        tree = ApproximationTree.build(terrain, epsilon=epsilon, progress=on_progress)
    seconds = time.perf_counter() - t0
    nbytes = tree.save(out)
    figures: dict[str, Any] = {"terrain": "jacksboro_fault_dem (matplotlib sample data)"}
    figures.update(terrain_figures(terrain))
    figures.update(tree_figures(tree, seconds, nbytes))
    figures["tree_file"] = str(Path(out))
    # Bake the hillshade pyramid next to the tree, then render the oblique overview with it:
    # the baked hillshade is the shading, drawn once (core paper 5.1), over the palette.
    from approxtree.render.context import hardware_gl, optional_context
    from approxtree.textures.bake import bake as bake_textures

    # The baked light is the one asked for (sun and exaggeration, z factor of gdaldem).
    az, alt = style["sun"]
    shading = {"azimuth": az, "altitude": alt, "z_factor": style["exaggeration"]}
    # A GPU bakes the shading; on a CPU-only OpenGL the numba kernels are faster.
    with (
        optional_context(hardware_gl()) as gl_context,
        progress_bar("baking pyramid", unit="row", quiet=quiet) as on_progress,
    ):
        baked = bake_textures(
            terrain, folder, shading_options=shading, context=gl_context, progress=on_progress
        )
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
