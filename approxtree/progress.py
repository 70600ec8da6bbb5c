"""Progress reporting: the callback the library layers accept and the tqdm bar the CLI shows.

The library never prints: a long computation takes an optional ``progress`` callback and calls
it with absolute counts, ``progress(done, total)``, whenever a unit of work (a tree level, a
strip of texture rows, a stage) is finished. The CLI (or a script) turns such calls into a
tqdm bar with ``progress_bar``::

    with progress_bar("building tree", unit="point", quiet=quiet) as report:
        ApproximationTree.build(terrain, progress=report)

The bar is shown on stderr only when stderr is a terminal (tqdm's ``disable=None``), never
with ``quiet``; it has no ETA (the work per unit is uneven, an ETA from it is bogus) and its
total is the one last reported, so it always ends at ``total/total``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from tqdm import tqdm


class ProgressCallback(Protocol):
    """Called with the work done so far and the total work (same unit, absolute counts)."""

    def __call__(self, done: int, total: int) -> None: ...


def no_progress(done: int, total: int) -> None:
    """The callback of a computation nobody watches."""


#: Counts and elapsed time only: no ETA, no rate (a rate over uneven units misleads).
BAR_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {unit} [{elapsed}]"


@contextmanager
def progress_bar(
    desc: str,
    unit: str = "it",
    quiet: bool = False,
    force: bool = False,
    file=None,
) -> Iterator[ProgressCallback]:
    """A tqdm bar on stderr fed by the ``ProgressCallback`` it yields; closed on exit.

    quiet: no bar at all; force: a bar even when stderr is not a terminal (tests); otherwise
    a bar only on a terminal. The bar ends at its total: the last call's ``done`` should be
    its ``total`` (the library functions guarantee it on success).
    """
    out = sys.stderr if file is None else file
    disable: bool | None = True if quiet else (False if force else None)
    # tqdm's own rule for disable=None (no bar off a terminal), decided here so that a
    # command whose stderr is a file or a pipe never imports tqdm (~20 ms of its start-up).
    if disable is None and hasattr(out, "isatty") and not out.isatty():
        disable = True
    # The bar opens at the first report, when its total is known (never a bogus 0/0).
    bars: list[tqdm] = []

    def report(done: int, total: int) -> None:
        if disable:
            return
        total, done = int(total), int(done)
        if not bars:
            from tqdm.auto import tqdm

            bars.append(
                tqdm(
                    total=total,
                    desc=desc,
                    unit=unit,
                    file=out,
                    disable=disable,
                    bar_format=BAR_FORMAT,
                    leave=True,
                )
            )
        bar = bars[0]
        if bar.disable:
            return
        if bar.total != total:
            bar.total = total
        bar.update(done - bar.n)
        if done >= total:
            bar.refresh()

    try:
        yield report
    finally:
        for bar in bars:
            bar.close()


def as_callback(
    progress: bool | ProgressCallback | None, desc: str, unit: str = "it"
) -> tuple[ProgressCallback, Callable[[], None]]:
    """(callback, close) for a library function's ``progress`` argument: a callable is used
    as it is, True opens a ``progress_bar`` (shown on a terminal), False/None report nothing."""
    if callable(progress):
        return progress, lambda: None
    if not progress:
        return no_progress, lambda: None
    ctx = progress_bar(desc, unit)

    def close() -> None:
        ctx.__exit__(None, None, None)

    return ctx.__enter__(), close


class Stages:
    """Progress over named stages of uneven length: ``stages.done()`` after each one."""

    def __init__(self, progress: ProgressCallback | None, total: int) -> None:
        self.progress = progress or no_progress
        self.total = int(total)
        self.count = 0
        self.progress(0, self.total)

    def done(self, n: int = 1) -> None:
        self.count = min(self.total, self.count + n)
        self.progress(self.count, self.total)
