"""The ``approxtree`` command line (click). Every command with --json prints one JSON object.

Errors of the ApproxTreeError hierarchy are printed as one line on stderr (exit code 2), never
as a traceback; so are click's usage errors (an unknown option, a bad value: ``_LazyGroup``).
GDAL's own stderr messages (printed where rasterio has no handler installed) go to
``CPL_LOG`` = the null device unless the user set it: every error reaches the user as one
``Error:`` line of ours.

One module per command, imported only when its command is run or listed; option groups shared
by several commands in options.py, helpers in common.py.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import MutableMapping

import click

from approxtree.cli import compile_notice
from approxtree.cli.common import _is_tree

__all__ = ["_is_tree", "main", "run"]

#: The commands: name → (module of approxtree.cli, the command's name there). A module is
#: imported when its command is looked up (run, help), so starting one command imports its
#: own module only, not every command's imports and options.
_COMMANDS = {
    "info": ("info", "info"),
    "build": ("build", "build"),
    "demo": ("demo", "demo"),
    "fractal": ("fractal", "fractal"),
    "render": ("render", "render"),
    "mesh": ("mesh", "mesh"),
    "tiles": ("tiles", "tiles"),
    "bake": ("bake", "bake_command"),
    "view": ("view", "view"),
    "convert": ("convert", "convert"),
    "rd": ("rd", "rd"),
    "verify": ("verify", "verify"),
    "serve": ("serve", "serve"),
    "update": ("update", "update"),
}


class _UsageError(click.ClickException):
    """A click usage error shown as one ``Error:`` line (click's own adds the usage and a
    hint line before it); exit code 2 as click's."""

    exit_code = 2


#: click's "no arguments: show the help" is a UsageError that shows the help: kept as it is.
_SHOWS_HELP = getattr(click.exceptions, "NoArgsIsHelpError", ())


def _one_line(exc: click.UsageError) -> click.ClickException:
    if isinstance(exc, _SHOWS_HELP):
        return exc
    where = exc.ctx.command_path if exc.ctx is not None else "approxtree"
    return _UsageError(f"{exc.format_message().rstrip('.')} (see '{where} --help').")


class _LazyGroup(click.Group):
    """A click group whose commands (``_COMMANDS``) are imported on first look-up;
    ``commands`` imports them all (help lists every one). Usage errors of the group and its
    commands are one ``Error:`` line."""

    def __init__(self, *args, **kwargs) -> None:
        self._loaded: dict[str, click.Command] = {}
        super().__init__(*args, **kwargs)

    @property
    def commands(self) -> MutableMapping[str, click.Command]:
        for name in _COMMANDS:
            self._command(name)
        return self._loaded

    @commands.setter
    def commands(self, value: MutableMapping[str, click.Command]) -> None:
        self._loaded = dict(value)

    def _command(self, name: str) -> click.Command | None:
        if name not in self._loaded and name in _COMMANDS:
            module, attr = _COMMANDS[name]
            command = getattr(importlib.import_module(f"approxtree.cli.{module}"), attr)
            self._loaded[name] = command
        return self._loaded.get(name)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        return self._command(cmd_name)

    def make_context(self, *args, **kwargs) -> click.Context:
        try:
            return super().make_context(*args, **kwargs)
        except click.UsageError as exc:
            raise _one_line(exc) from exc

    def invoke(self, ctx: click.Context) -> object:
        # The command's own arguments are parsed here (an unknown option, a bad value).
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:
            raise _one_line(exc) from exc

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*_COMMANDS, *self._loaded})


@click.group(cls=_LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="approxtree")
def main() -> None:
    """approxtree: approximation trees for real-time terrain visualization."""
    # GDAL reads CPL_LOG when it prints its first message: set before any command's work.
    os.environ.setdefault("CPL_LOG", os.devnull)
    # A first run after an editable install or an upgrade compiles kernels: say so.
    compile_notice.install()
    click.get_current_context().call_on_close(compile_notice.close)


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
