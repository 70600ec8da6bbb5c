"""One line on stderr while approxtree's kernels compile, so a first run never looks hung.

After ``pip install .`` every kernel is already compiled (setup.py runs ``approxtree._warmup``
into the package's cache) and nothing here ever shows. After an editable install or an
upgrade the cache is empty or stale: the first command compiles the kernels it needs, which
takes seconds to a minute with nothing else on screen. :func:`install` registers a listener
for numba's ``numba:compile`` event, which numba fires only when it compiles (a cache hit
fires nothing, so a warm run prints nothing); at the first compile of an approxtree kernel it
prints :data:`NOTICE` once, and on a terminal a bar counts the kernels compiled.

(numba is imported with ``approxtree`` itself, its geometry needs kernels: listening costs
nothing more.)
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any, TextIO

from numba.core import event

if TYPE_CHECKING:
    from tqdm import tqdm

#: The line shown once per process, at the first compile of one of approxtree's kernels.
NOTICE = (
    "Compiling approxtree's kernels for this machine (once: later runs load them from the cache)…"
)


class CompileNotice(event.Listener):
    """numba compile listener: :data:`NOTICE` at the first approxtree kernel compiled, then
    a bar of the kernels compiled (``bar``: on terminals)."""

    def __init__(self, out: TextIO, bar: bool) -> None:
        self.out = out
        self.bar = bar
        self.said = False
        self.compiled = 0
        self._tqdm: tqdm | None = None

    def on_start(self, ev: event.Event) -> None:
        if self.said or not _is_ours(ev):
            return
        self.said = True
        print(NOTICE, file=self.out, flush=True)
        if self.bar:
            from tqdm.auto import tqdm

            # No total: how many kernels a command needs is known only once it has run.
            self._tqdm = tqdm(
                desc="compiling",
                unit="kernel",
                file=self.out,
                leave=False,
                # A compile takes 0.1 s or more: each one redraws the count.
                mininterval=0,
                bar_format="{desc}: {n_fmt} {unit}s [{elapsed}]",
            )

    def on_end(self, ev: event.Event) -> None:
        if _is_ours(ev):
            self.compiled += 1
            if self._tqdm is not None:
                self._tqdm.update(1)

    def close(self) -> None:
        """Remove the bar (the line stays)."""
        if self._tqdm is not None:
            self._tqdm.close()
            self._tqdm = None


def _is_ours(ev: event.Event) -> bool:
    """Whether the event is the compile of a kernel defined in approxtree."""
    data: Any = ev.data
    dispatcher = data.get("dispatcher") if isinstance(data, dict) else None
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", None) or ""
    return module.split(".", 1)[0] == "approxtree"


_installed: CompileNotice | None = None


def install(out: TextIO | None = None) -> CompileNotice:
    """Register the notice for this process (once; later calls return the same listener).
    The bar shows only when ``out`` (stderr by default) is a terminal."""
    global _installed
    if _installed is None:
        stream = sys.stderr if out is None else out
        tty = bool(getattr(stream, "isatty", lambda: False)())
        _installed = CompileNotice(stream, bar=tty)
        event.register("numba:compile", _installed)
    return _installed


def close() -> None:
    """The end of a command: remove the bar, if any (the listener stays, and the line is
    never shown twice in a process)."""
    if _installed is not None:
        _installed.close()
