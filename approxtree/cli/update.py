"""``approxtree update``: replace part of a stored tree's terrain by a raster, transactionally,
and re-bake the texture pyramid tiles the change reaches (or the whole shading, for a new light)."""

from __future__ import annotations

from typing import Any

import click

from approxtree.cli.common import _emit, _reports_errors
from approxtree.cli.options import json_option


@click.command()
@click.argument("store", type=click.Path(exists=True, file_okay=False))
@click.argument("patch", required=False, type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--textures",
    type=click.Path(exists=True, file_okay=False),
    default=None,
    help="Texture pyramid baked from STORE's terrain: re-bake the tiles the change reaches.",
)
@click.option("--azimuth", type=float, default=None, help="New light for --textures, degrees.")
@click.option("--altitude", type=float, default=None, help="New light for --textures, degrees.")
@click.option(
    "--water-level",
    type=float,
    default=None,
    help="New flood level for --textures (a pyramid baked with --water-level): the tiles "
    "between the old and the new shore line are re-baked.",
)
@click.option(
    "--no-verify",
    is_flag=True,
    help="Skip checking every patch checksum of the store before the update.",
)
@json_option
@_reports_errors
def update(
    store: str,
    patch: str | None,
    textures: str | None,
    azimuth: float | None,
    altitude: float | None,
    water_level: float | None,
    no_verify: bool,
    as_json: bool,
) -> None:
    """Replace the cells of STORE's terrain that PATCH (a georeferenced raster on the
    terrain's cells: same CRS and cell size, corners on cell edges) covers, and rebuild only
    the tree nodes the change reaches. The store is swapped in one atomic step: a reader sees
    the old tree or the new one, and a killed update leaves the old store.

    --textures DIR then re-bakes only the pyramid tiles the change reaches, on every level,
    and swaps the pyramid in one atomic step too (after the store: a kill between the two
    leaves the new tree under the old textures; `approxtree update STORE --textures DIR`
    re-bakes them whole). Without PATCH, --textures re-bakes the pyramid whole from STORE's
    terrain, with the new light of --azimuth / --altitude if given; --water-level moves a
    flood (only the tiles between the two shore lines are re-baked).
    """
    from approxtree.errors import InvalidParameterError, TerrainFormatError
    from approxtree.geometry.grid import Grid
    from approxtree.io import read_grid
    from approxtree.render.context import hardware_gl, optional_context
    from approxtree.textures.pyramid import TexturePyramid
    from approxtree.textures.rebake import rebake
    from approxtree.tree.approximation_tree import ApproximationTree
    from approxtree.tree.store_update import patch_window, update_store

    light = {k: v for k, v in (("azimuth", azimuth), ("altitude", altitude)) if v is not None}
    if patch is None and textures is None:
        raise InvalidParameterError("Nothing to update: give a PATCH raster, --textures, or both.")
    if (light or water_level is not None) and textures is None:
        raise InvalidParameterError(
            "--azimuth, --altitude and --water-level re-bake --textures; give it."
        )
    # The pyramid is opened (and its recipe checked) before the store changes.
    pyramid = TexturePyramid(textures) if textures is not None else None
    figures: dict[str, Any] = {"store": store}
    rect = None
    if patch is not None:
        patch_grid = read_grid(patch)
        report = update_store(store, patch_grid, verify=not no_verify)
        figures |= {"patch": patch, **report.as_dict()}
        if not as_json:
            r0, r1, c0, c1 = report.window
            figures["window"] = f"rows {r0}..{r1}, columns {c0}..{c1}"
    if pyramid is not None:
        terrain = ApproximationTree.load(store, verify=patch is None and not no_verify).terrain
        if not isinstance(terrain, Grid):
            raise TerrainFormatError(
                f"{store} holds a tree over a {type(terrain).__name__}; only a grid's pyramid "
                "is re-baked."
            )
        if patch is not None:
            rect = patch_window(terrain, patch_grid)
        recipe = pyramid.recipe or {}
        with optional_context(bool(recipe.get("gl")) and hardware_gl()) as context:
            done = rebake(
                pyramid, terrain, rect, light or None, context=context, water_level=water_level
            )
        figures["textures"] = done.as_dict() if as_json else _tiles_line(done.as_dict())
    _emit(figures, as_json)


def _tiles_line(figures: dict[str, Any]) -> str:
    """The re-bake's figures on one line for the text output."""
    how = "whole" if figures["whole"] else "tiles reached"
    return (
        f"{figures['tiles']} of {figures['tiles_total']} tiles re-baked ({how}) "
        f"in {figures['seconds']:.3f} s"
    )
