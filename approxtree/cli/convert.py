"""``approxtree convert``: Copy a saved tree into another form: a legacy OLD.atree into a store
NEW.zarr, a store folder into a single-file NEW.zarr.zip (or back), or to/from an fsspec URL.
"""

from __future__ import annotations

import os
import time

import click

from approxtree.cli.common import _check_tree_output, _emit, _is_tree, _reports_errors
from approxtree.cli.options import json_option, overwrite_option


@click.command()
@click.argument("source", type=click.Path())
@click.argument("target", type=click.Path())
@overwrite_option
@json_option
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
