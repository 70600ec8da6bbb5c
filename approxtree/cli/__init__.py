"""The ``approxtree`` command line (click). Every command with --json prints one JSON object.

Errors of the ApproxTreeError hierarchy are printed as one line on stderr (exit code 2), never
as a traceback.

One module per command; option groups shared by several commands in options.py, helpers in
common.py.
"""

from __future__ import annotations

import click

from approxtree.cli import bake, build, convert, demo, fractal, info, mesh, rd, render, tiles, view
from approxtree.cli.common import _is_tree

__all__ = ["_is_tree", "main"]


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
