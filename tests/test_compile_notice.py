"""The compile notice: while a first run compiles approxtree's kernels (an editable install, an
upgrade: an empty or stale cache), stderr says so in one line; a run that compiles nothing
says nothing."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from approxtree.cli import compile_notice


def _env(cache: Path) -> dict[str, str]:
    env = dict(os.environ, APPROXTREE_KERNEL_CACHE=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    return env


def _dem(path: Path) -> Path:
    """A 33² float32 GeoTIFF (a few kilobytes: its bake compiles two small kernels)."""
    import rasterio
    from affine import Affine

    from approxtree.datasets import fractal_heights

    z = fractal_heights(33, 33, seed=3, relief=100.0).astype(np.float32)
    profile = {"driver": "GTiff", "width": 33, "height": 33, "count": 1, "dtype": "float32"}
    with rasterio.open(
        path, "w", **profile, crs="EPSG:32617", transform=Affine(30, 0, 0, 0, -30, 0)
    ) as f:
        f.write(z, 1)
    return path


def _bake(tmp_path: Path, cache: Path) -> subprocess.CompletedProcess:
    argv = ["bake", str(tmp_path / "dem.tif"), "--out", str(tmp_path / "p"), "--no-gl"]
    return subprocess.run(
        [sys.executable, "-m", "approxtree", *argv, "-q", "--overwrite"],
        env=_env(cache),
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )


def test_notice_once_while_compiling_never_when_cached(tmp_path):
    """An empty kernel cache: the bake prints the notice once on stderr (no bar off a
    terminal) and nothing on stdout; the same bake again, every kernel cached: no notice."""
    _dem(tmp_path / "dem.tif")
    cache = tmp_path / "cache"
    cold = _bake(tmp_path, cache)
    assert cold.returncode == 0, cold.stderr
    assert cold.stderr.count(compile_notice.NOTICE) == 1, cold.stderr
    assert "compiling:" not in cold.stderr
    assert compile_notice.NOTICE not in cold.stdout
    warm = _bake(tmp_path, cache)
    assert warm.returncode == 0, warm.stderr
    assert compile_notice.NOTICE not in warm.stderr, warm.stderr


def _event(module: str, start: bool) -> SimpleNamespace:
    """A stand-in for numba's compile event of a function defined in ``module``."""
    func = SimpleNamespace(__module__=module)
    return SimpleNamespace(data={"dispatcher": SimpleNamespace(py_func=func)}, is_start=start)


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_notice_counts_our_kernels_only_and_bars_on_terminals():
    """Compiles of other packages' functions say nothing; the first of approxtree's prints
    the line once; on a terminal a bar counts approxtree's kernels and is removed at close."""
    for out in (io.StringIO(), _Terminal()):
        notice = compile_notice.CompileNotice(out, bar=out.isatty())
        notice.on_start(_event("somepackage.module", True))
        notice.on_end(_event("somepackage.module", False))
        assert out.getvalue() == "" and notice.compiled == 0
        for _ in range(3):
            notice.on_start(_event("approxtree.kernels.rtin", True))
            notice.on_end(_event("approxtree.kernels.rtin", False))
        assert out.getvalue().count(compile_notice.NOTICE) == 1
        assert notice.compiled == 3
        assert ("compiling: 3 kernels" in out.getvalue()) == out.isatty()
        notice.close()
