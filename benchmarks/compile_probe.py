"""Run one ``approxtree`` command in this process and record what numba compiles.

    python benchmarks/compile_probe.py OUT.json -- demo --out /tmp/x/demo.zarr

Writes OUT.json: the command's wall and CPU time, the time spent compiling, wall and CPU
(outermost compiles only, so a kernel compiled while typing its caller is not counted twice;
the CPU time is the calling thread's, where numba compiles: on a loaded machine it is what a
quiet one would wait), every compile event (kernel, argument types, inclusive seconds,
nesting depth), and every approxtree dispatcher with its signatures and cache hits.

Used by bench_compile.py in a fresh subprocess per run; point NUMBA_CACHE_DIR at an empty
folder for a cold run.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

from numba.core import event


class _CompileRecorder(event.Listener):
    """Times every ``numba:compile`` event (one per cache miss), nested ones included."""

    def __init__(self) -> None:
        self.records: list[dict[str, Any]] = []
        self._open: list[tuple[float, float]] = []

    def on_start(self, ev: event.Event) -> None:
        self._open.append((time.perf_counter(), time.thread_time()))

    def on_end(self, ev: event.Event) -> None:
        t0, c0 = self._open.pop()
        d = ev.data
        disp = d["dispatcher"]
        self.records.append(
            {
                "kernel": f"{disp.py_func.__module__}.{disp.py_func.__qualname__}",
                "args": str(tuple(d["args"])),
                "seconds": time.perf_counter() - t0,
                "cpu_seconds": time.thread_time() - c0,
                "depth": len(self._open),
            }
        )


def _dispatchers() -> list[dict[str, Any]]:
    """Every numba dispatcher defined in an imported approxtree module, with its signatures."""
    from numba.core.dispatcher import Dispatcher

    found = []
    for name, module in sorted(sys.modules.items()):
        if not name.startswith("approxtree") or module is None:
            continue
        for attr, obj in vars(module).items():
            if isinstance(obj, Dispatcher) and obj.py_func.__module__ == name:
                stats = obj.stats
                found.append(
                    {
                        "kernel": f"{name}.{attr}",
                        "signatures": [str(s) for s in obj.signatures],
                        "cache_hits": sum(stats.cache_hits.values()),
                        "cache_misses": sum(stats.cache_misses.values()),
                    }
                )
    return found


def main(argv: list[str]) -> None:
    out, sep, *command = argv
    assert sep == "--", "usage: compile_probe.py OUT.json -- COMMAND ARGS..."
    recorder = _CompileRecorder()
    event.register("numba:compile", recorder)
    t0, c0 = time.perf_counter(), time.process_time()
    from approxtree.cli import main as cli

    try:
        cli.main(command, standalone_mode=False)
    finally:
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        outer = [r for r in recorder.records if r["depth"] == 0]
        with open(out, "w") as f:
            json.dump(
                {
                    "command": command,
                    # Which copy ran (bench_compile.py's fresh install vs the source tree).
                    "approxtree_file": sys.modules["approxtree"].__file__,
                    "wall_s": wall,
                    "cpu_s": cpu,
                    "compile_s": sum(r["seconds"] for r in outer),
                    "compile_cpu_s": sum(r["cpu_seconds"] for r in outer),
                    "compiles": len(recorder.records),
                    "events": recorder.records,
                    "dispatchers": _dispatchers(),
                },
                f,
                indent=1,
            )


if __name__ == "__main__":
    main(sys.argv[1:])
