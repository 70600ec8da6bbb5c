"""``approxtree info``: Size, CRS, cell size, z range and nodata count of a terrain file; of a
tree store: format version, nodes, levels, strategies, chunk layout and bytes (stored vs raw).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from approxtree.cli import common
from approxtree.cli.common import (
    _emit,
    _given_reader_options,
    _is_tree,
    _no_reader_flags_for_tree,
    _reports_errors,
    terrain_figures,
)
from approxtree.cli.options import json_option, reader_options


def _tree_info(path: str) -> dict[str, Any]:
    """Figures of a saved tree: a store's layout, or a legacy .atree's tree statistics."""
    from approxtree.tree import load_tree
    from approxtree.tree.atree import TreeFile, is_legacy_file
    from approxtree.tree.tree_store import store_info

    if not is_legacy_file(path):
        return store_info(path)
    tree = load_tree(path)
    figures: dict[str, Any] = {"tree_file": path, "format": f"atree {TreeFile(path).version}"}
    figures.update(tree.stats())
    figures["bytes"] = Path(path).stat().st_size
    return figures


@click.command()
@click.argument("dem", type=click.Path())
@reader_options
@json_option
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
    terrain = common._open(dem, encoding, nodata_policy, ground_only, height_scale)
    _emit(terrain_figures(terrain), as_json)
