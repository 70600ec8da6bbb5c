"""``approxtree view``: Open an interactive window over a tree file or a DEM (F1 in the window:
keys).
"""

from __future__ import annotations

import json
from typing import Any

import click

from approxtree.cli.common import _reports_errors, _tree_of
from approxtree.cli.options import (
    BuildChoices,
    _size,
    build_options,
    cartographic_options,
    fov_option,
    ground_surface_option,
    quiet_option,
    reader_options,
    textures_option,
    threshold_options,
)


@click.command()
@click.argument("source", type=click.Path())
@textures_option(
    "Baked texture pyramid folder (repeat for several; TAB cycles, T toggles); "
    "--textures DETAIL@LEVEL after one refines it with the pyramid DETAIL for nodes at tree "
    "level >= LEVEL inside DETAIL's footprint.",
    most=None,
)
@click.option(
    "--size", callback=_size, default="1280x720", show_default=True, help="Window size WxH."
)
@threshold_options
@fov_option
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
    "--screenshot-name",
    default="approxtree-{time}.png",
    show_default=True,
    help="File name of P's screenshots (in the working folder): {time} and {n} (1, 2, ...) "
    "are filled in, e.g. nc-{n:03d}.png.",
)
@click.option(
    "--screenshot-furniture",
    is_flag=True,
    help="Keep the map furniture (legend, scale bar, north arrow; not the panels) in the "
    "pictures of P and --screenshots [default: the 3D view alone].",
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
    "--follow/--no-follow",
    default=True,
    help="Show the updates another process makes to a tree store SOURCE and its --textures "
    "folders (approxtree update) live [default: follow].",
)
@click.option(
    "--bookmarks",
    "bookmarks_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Bookmark file [default: $XDG_CONFIG_HOME/approxtree/bookmarks.json].",
)
@cartographic_options
@build_options
@reader_options
@ground_surface_option
@quiet_option
@_reports_errors
def view(
    source: str,
    textures: list[Any],
    size: tuple[int, int],
    alpha: float,
    gamma: float,
    fov: float,
    script_path: str | None,
    stats_path: str | None,
    screenshots: str | None,
    screenshot_name: str,
    screenshot_furniture: bool,
    keys_text: str,
    frames: int | None,
    max_uploads: int,
    upload_ms: float | None,
    legend: str | None,
    follow: bool,
    bookmarks_path: str | None,
    style: dict[str, Any],
    build: BuildChoices,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    quiet: bool,
) -> None:
    """Open an interactive window over a tree file or a DEM (F1 in the window: keys). A
    terrain file's build shows a bar on a terminal (-q: none)."""
    from approxtree.io.output_path import check_output_file, check_output_folder
    from approxtree.render.cut import Cut
    from approxtree.viewer import load_script, parse_key_presses, script_frames
    from approxtree.viewer.app import Viewer
    from approxtree.viewer.map_tools import screenshot_name as screenshot_file_name

    Cut(alpha, gamma)  # bad thresholds fail before the window opens
    screenshot_file_name(screenshot_name, 1)
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
    tree = _tree_of(source, build, **reader)
    with Viewer(
        tree,
        textures=textures,
        size=size,
        alpha=alpha,
        gamma=gamma,
        fov=fov,
        max_uploads=max_uploads,
        budget_ms=upload_ms,
        legend=legend,
        bookmarks=bookmarks_path,
        source=source,
        follow=follow,
        screenshot_name=screenshot_name,
        furniture_in_shots=screenshot_furniture,
        **style,
    ) as viewer:
        drawn = viewer.run(script, presses, stats_path, screenshots, max_frames=frames)
    if script is not None:
        click.echo(json.dumps({"frames": drawn, "stats": stats_path, "screenshots": screenshots}))
