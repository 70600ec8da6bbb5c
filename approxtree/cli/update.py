"""``approxtree update``: replace part of a stored tree's terrain by a raster, transactionally."""

from __future__ import annotations

import click

from approxtree.cli.common import _emit, _reports_errors
from approxtree.cli.options import json_option


@click.command()
@click.argument("store", type=click.Path(exists=True, file_okay=False))
@click.argument("patch", type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--no-verify",
    is_flag=True,
    help="Skip checking every patch checksum of the store before the update.",
)
@json_option
@_reports_errors
def update(store: str, patch: str, no_verify: bool, as_json: bool) -> None:
    """Replace the cells of STORE's terrain that PATCH (a georeferenced raster on the
    terrain's cells: same CRS and cell size, corners on cell edges) covers, and rebuild only
    the tree nodes the change reaches. The store is swapped in one atomic step: a reader sees
    the old tree or the new one, and a killed update leaves the old store."""
    from approxtree.io import read_grid
    from approxtree.tree.store_update import update_store

    report = update_store(store, read_grid(patch), verify=not no_verify)
    figures = {"store": store, "patch": patch, **report.as_dict()}
    if not as_json:
        r0, r1, c0, c1 = report.window
        figures["window"] = f"rows {r0}..{r1}, columns {c0}..{c1}"
    _emit(figures, as_json)
