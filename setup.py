"""Build hook: compile the numba kernels into the built package, so that the first command
after ``pip install .`` loads machine code instead of compiling it (issue 15, item 5).

Everything else (metadata, packages, data) lives in pyproject.toml. After build_py has copied
the package into build/lib, ``python -m approxtree._warmup`` runs on that copy and fills
build/lib/approxtree/_kernel_cache (see approxtree/kernels/_cache.py), which the wheel then
ships. The build environment holds numba, numpy and the few packages the warm-up imports
([build-system] requires); when their versions differ from the installed ones the cache
simply misses (its stamp holds the versions) and kernels compile on first use, as before.

An editable install (``pip install -e``) runs the same warm-up on the source tree itself: its
git-ignored approxtree/_kernel_cache is the cache the editable package reads, so the first
command after an editable install (or a reinstall after ``git pull``) compiles nothing either.
Entries already there are kept: a warm-up over a full cache only loads them (about half a
minute), and an entry whose kernel sources changed misses and is recompiled.

The hook never fails the build: on any error it prints a warning and the package installs
without the cache. APPROXTREE_NO_AOT=1 skips it (the kernels then compile on first use).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py


def _warn(message: str) -> None:
    print(f"WARNING: approxtree: {message}", file=sys.stderr, flush=True)


def compile_kernels(build_lib: Path, fresh: bool = True) -> None:
    """Run the warm-up on the package below build_lib (raises on failure); ``fresh``: start
    from an empty cache (a built copy), else keep the entries there (the source tree)."""
    cache = build_lib / "approxtree" / "_kernel_cache"
    if fresh:
        shutil.rmtree(cache, ignore_errors=True)
    env = dict(os.environ)
    # The built copy first on the path; numba's and our cache-folder overrides off.
    env["PYTHONPATH"] = os.pathsep.join([str(build_lib), env.get("PYTHONPATH", "")]).rstrip(
        os.pathsep
    )
    for name in ("NUMBA_CACHE_DIR", "APPROXTREE_KERNEL_CACHE", "NUMBA_DISABLE_JIT"):
        env.pop(name, None)
    t0 = time.perf_counter()
    run = subprocess.run(
        [sys.executable, "-m", "approxtree._warmup"],
        env=env,
        cwd=build_lib,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    print(run.stdout, run.stderr, sep="\n", flush=True)
    if run.returncode != 0:
        _warn("some kernels were not compiled at install; they compile on first use.")
    entries = len(list(cache.rglob("*.nbc")))
    print(
        f"approxtree: {entries} compiled kernels cached in {time.perf_counter() - t0:.1f} s",
        flush=True,
    )


class BuildPyWithKernels(build_py):
    """build_py, then the kernels compiled into the built package, or into the source tree for
    an editable install (never fails the build)."""

    def run(self) -> None:
        super().run()
        if os.environ.get("APPROXTREE_NO_AOT") == "1":
            return
        try:
            # Editable: the package is the source tree next to this file, not a copy.
            if getattr(self, "editable_mode", False):
                compile_kernels(Path(__file__).resolve().parent, fresh=False)
            else:
                compile_kernels(Path(self.build_lib).resolve())
        except Exception as error:
            _warn(f"kernels not compiled at install ({error!r}); they compile on first use.")


setup(cmdclass={"build_py": BuildPyWithKernels})
