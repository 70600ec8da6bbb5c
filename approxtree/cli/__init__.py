"""The ``approxtree`` command line (click). Every command with --json prints one JSON object.

Errors of the ApproxTreeError hierarchy are printed as one line on stderr (exit code 2), never
as a traceback.

One module per command; option groups shared by several commands in options.py, helpers in
common.py.
"""

from __future__ import annotations

import os
import sys

import click

from approxtree.cli import bake, build, convert, demo, fractal, info, mesh, rd, render, tiles, view
from approxtree.cli.common import _is_tree

__all__ = ["_is_tree", "main", "run"]


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="approxtree")
def main() -> None:
    """approxtree: approximation trees for real-time terrain visualization."""


# The commands, in the order of the one-module command line.
main.add_command(info.info)
main.add_command(build.build)
main.add_command(demo.demo)
main.add_command(fractal.fractal)
main.add_command(render.render)
main.add_command(mesh.mesh)
main.add_command(tiles.tiles)
main.add_command(bake.bake_command)
main.add_command(view.view)
main.add_command(convert.convert)
main.add_command(rd.rd)


#: Set by a command whose process may end without the interpreter's teardown (see ``run``).
_ends_without_teardown = False


def end_without_teardown() -> None:
    """Let ``run`` end this process at once when the command succeeds: it has closed its
    files and threads, and the teardown (unloading numba's compiled code, GDAL, every module:
    ~0.6 s after an 8192² bake) would only delay the shell."""
    global _ends_without_teardown
    _ends_without_teardown = True


def run() -> None:
    """The ``approxtree`` program: ``main()``, then, after a successful command that asked
    for it (``end_without_teardown``), ``os._exit(0)`` once stdout and stderr are flushed.
    Other commands (dask clusters, windows) and every failure end as usual."""
    try:
        main()
    except SystemExit as exc:
        if exc.code in (0, None) and _ends_without_teardown:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)
        raise
