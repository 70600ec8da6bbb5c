"""Kernels compiled at install: the package's numba cache and the warm-up that fills it.

``pip install .`` runs ``approxtree._warmup`` into ``approxtree/_kernel_cache`` (setup.py), and
``approxtree.kernels._cache`` makes numba look there first. The guarantees: after a warm-up,
the first ``demo``, ``render`` and ``mesh`` compile nothing (any kernel the warm-up misses is
named); an entry is reused only for the same source and the same numba, llvmlite, numpy and
Python; an unusable cache folder never breaks ``import approxtree``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import DATA_DIR

from approxtree._warmup import NOT_WARMED
from approxtree.kernels import _cache

# Runs approxtree commands in one process and prints, per command, the kernels numba compiled
# (the "numba:compile" event fires on cache misses only; benchmarks/compile_probe.py does the
# same with timings).
_PROBE = """
import json, sys
from numba.core import event

compiled = []

class Recorder(event.Listener):
    def on_start(self, ev):
        pass

    def on_end(self, ev):
        f = ev.data["dispatcher"].py_func
        compiled.append(f"{f.__module__}.{f.__qualname__}{tuple(ev.data['args'])}")

event.register("numba:compile", Recorder())
from approxtree.cli import main

report = {}
for command in json.loads(sys.argv[1]):
    compiled.clear()
    try:
        main(command, standalone_mode=False)
    except SystemExit as stop:  # verify exits with its verdict
        if stop.code:
            raise
    report[" ".join(command)] = list(compiled)
print("REPORT" + json.dumps(report))
"""


def _env(cache: Path) -> dict[str, str]:
    env = dict(os.environ, APPROXTREE_KERNEL_CACHE=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    return env


def _mesh_dem(tmp_path: Path) -> Path:
    """The issue's DEM (nc/elev_ned_30m.tif, float32) when present, else a float32 GeoTIFF."""
    dem = DATA_DIR / "nc" / "elev_ned_30m.tif"
    if dem.is_file():
        return dem
    import rasterio
    from affine import Affine

    from approxtree.datasets import fractal_heights

    dem = tmp_path / "dem.tif"
    z = fractal_heights(129, 129, seed=4, relief=300.0)
    profile = {"driver": "GTiff", "width": 129, "height": 129, "count": 1, "dtype": "float32"}
    with rasterio.open(
        dem, "w", **profile, crs="EPSG:32617", transform=Affine(30, 0, 0, 0, -30, 0)
    ) as f:
        f.write(z, 1)
    return dem


@pytest.fixture(scope="module")
def warm_cache(tmp_path_factory) -> Path:
    """A kernel cache filled by ``python -m approxtree._warmup`` (what ``pip install .`` ships)."""
    cache = tmp_path_factory.mktemp("warm") / "cache"
    warm = subprocess.run(
        [sys.executable, "-m", "approxtree._warmup"],
        env=_env(cache),
        cwd=cache.parent,
        capture_output=True,
        text=True,
    )
    assert warm.returncode == 0, warm.stdout + warm.stderr
    assert any(cache.rglob("*.nbi")), "the warm-up wrote no cache entry"
    return cache


def _small_las(path: Path) -> Path:
    """autzen_trim.laz when present (the issue's file), else 400 scattered points."""
    laz = DATA_DIR / "lidar" / "autzen_trim.laz"
    if laz.is_file():
        return laz
    import laspy
    import numpy as np

    rng = np.random.default_rng(0)
    x, y = rng.uniform(1000, 1100, 400), rng.uniform(2000, 2080, 400)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01, 0.01, 0.01], [1000, 2000, 0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, 50 + 0.1 * (x - 1000) + 3 * np.sin(x / 10)
    las.classification = np.full(400, 2, dtype=np.uint8)
    las.write(path)
    return path


def _int32_dem(path: Path) -> Path:
    """A 129² GeoTIFF of 32-bit integers: its heights read as float64 (as ASCII grids')."""
    import rasterio
    from affine import Affine

    from approxtree.datasets import fractal_heights

    z = (fractal_heights(129, 129, seed=6, relief=300.0) + 100).astype("int32")
    profile = {"driver": "GTiff", "width": 129, "height": 129, "count": 1, "dtype": "int32"}
    with rasterio.open(
        path, "w", **profile, crs="EPSG:32617", transform=Affine(30, 0, 5e5, 0, -30, 4e6)
    ) as f:
        f.write(z, 1)
    return path


def test_warmed_cache_commands_compile_nothing(tmp_path, warm_cache):
    """After ``python -m approxtree._warmup`` into an empty cache folder, the first demo,
    render (of the demo's tree), mesh (TIN, the issue's DEM) and bake (a pyramid of several
    levels) load every kernel from it; so do the issue's other first runs: info, build,
    point-quadtree build and render of a LAZ, quantized-mesh tiles, rd, verify, fractal, and
    the float64 heights of a 32-bit integer DEM."""
    cache = warm_cache
    tree = str(tmp_path / "demo.zarr")
    pyramid, small_limit = tmp_path / "pyramid", ["--max-texture-size", "64"]
    laz, pq = str(_small_las(tmp_path / "points.las")), str(tmp_path / "pq.zarr")
    dem, i32 = str(_mesh_dem(tmp_path)), str(_int32_dem(tmp_path / "i32.tif"))
    commands = [
        ["demo", "--out", tree],
        ["render", tree, "--out", str(tmp_path / "render.png")],
        ["mesh", dem, "--strategy", "tin", "--max-error", "1"],
        # A pyramid of several levels (halved), as any DEM over 4096² bakes into.
        ["bake", dem, "--out", str(pyramid), "--no-gl", *small_limit],
        ["info", laz],
        ["build", laz, "--kind", "point-quadtree", "--out", pq, "-q"],
        ["render", pq, "--out", str(tmp_path / "pq.png"), "--size", "320x180"],
        ["tiles", tree, "--format", "quantized-mesh", "--out", str(tmp_path / "qm")],
        ["rd", dem, "--size", "65", "-q"],
        ["mesh", i32, "--strategy", "tin", "--max-error", "1", "--out", str(tmp_path / "m.ply")],
        ["verify", str(tmp_path / "m.ply"), "--source", i32],
        ["fractal", str(tmp_path / "fractal.tif"), "--size", "65"],
    ]
    run = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(commands)],
        env=_env(cache),
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    report = json.loads(run.stdout.split("REPORT", 1)[1])
    assert len(report) == len(commands)
    compiled = {name: kernels for name, kernels in report.items() if kernels}
    assert compiled == {}, f"compiled on first use: {compiled}"


def _kernels() -> dict[str, tuple[str, str, bool]]:
    """Every numba kernel defined in approxtree (all its modules imported): name → (cache
    subfolder, index file name, whether it is inlined into its callers)."""
    import importlib
    import pkgutil

    from numba.core.dispatcher import Dispatcher

    import approxtree

    for module in pkgutil.walk_packages(approxtree.__path__, "approxtree."):
        if module.name != "approxtree.__main__":
            importlib.import_module(module.name)
    found = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("approxtree") or module is None:
            continue
        for obj in vars(module).values():
            if isinstance(obj, Dispatcher) and obj.py_func.__module__ == name:
                cache_file = obj._cache._cache_file
                found[f"{name}.{obj.py_func.__qualname__}"] = (
                    Path(cache_file._cache_path).name,
                    cache_file._index_name,
                    obj.targetoptions.get("inline", "never") == "always",
                )
    return found


def test_warmup_compiles_every_kernel(warm_cache):
    """Every numba kernel of approxtree (each module imported) has an entry in the warmed
    cache: a kernel added without a warm-up path fails here. Only kernels inlined into their
    callers (inline="always") have none of their own, and those the warm-up names with the
    reason it cannot reach them (``NOT_WARMED``)."""
    kernels = _kernels()
    assert set(NOT_WARMED) <= set(kernels), "NOT_WARMED names a kernel that does not exist"
    missing = [
        name
        for name, (folder, index, inline) in kernels.items()
        if not inline and not (warm_cache / folder / index).is_file() and name not in NOT_WARMED
    ]
    assert missing == [], f"kernels the warm-up does not compile: {missing}"


def test_stamp_follows_source_and_versions(tmp_path):
    """An entry's stamp is the source's content plus the numba/llvmlite/numpy/Python versions:
    not the file time (a wheel install does not keep it)."""
    src = tmp_path / "k.py"
    src.write_text("x = 1\n")
    versions = ("0.68.1", "0.50.0", "2.4.6", "3.11.7")
    stamp = _cache.source_stamp(src, versions)
    os.utime(src, (1e9, 1e9))
    assert _cache.source_stamp(src, versions) == stamp
    src.write_text("x = 2\n")
    assert _cache.source_stamp(src, versions) != stamp
    src.write_text("x = 1\n")
    assert _cache.source_stamp(src, versions) == stamp
    for i in range(4):
        other = tuple(v + ".1" if j == i else v for j, v in enumerate(versions))
        assert _cache.source_stamp(src, other) != stamp
    # The default versions are the running ones.
    assert _cache.source_stamp(src) == _cache.source_stamp(src, _cache._versions())


def test_stamp_follows_the_kernels_a_kernel_calls(tmp_path):
    """A kernel compiles in the kernels it calls from other modules: editing one of those must
    change every entry's stamp, or the cache would keep serving the old code; editing a module
    without kernels must not (a CLI edit does not recompile everything)."""
    root = tmp_path / "pkg"
    (root / "kernels").mkdir(parents=True)
    caller = root / "kernels" / "caller.py"
    callee = root / "kernels" / "callee.py"
    plain = root / "cli.py"
    caller.write_text("from numba import njit\nfrom .callee import f\n")
    callee.write_text("from numba import njit\n\n@njit\ndef f(x):\n    return x + 1\n")
    plain.write_text("x = 1\n")
    versions = ("0.68.1", "0.50.0", "2.4.6", "3.11.7")
    stamp = _cache.source_stamp(caller, versions, root)
    plain.write_text("x = 2\n")
    assert _cache.source_stamp(caller, versions, root) == stamp
    callee.write_text("from numba import njit\n\n@njit\ndef f(x):\n    return x + 2\n")
    assert _cache.source_stamp(caller, versions, root) != stamp
    # The installed package's stamp covers its kernel modules, this one among them.
    names = [p.name for p in _cache._kernel_files(_cache.PACKAGE_ROOT)]
    assert "greedy_tin.py" in names and "tin_scan.py" in names and "errors.py" not in names


def _locator(dispatcher) -> object:
    return dispatcher._cache._impl.locator


def test_locator_serves_approxtree_kernels_only(tmp_path, monkeypatch):
    """approxtree's kernels (kernels/ and render/) are cached in the package folder; other
    code, and everything when NUMBA_CACHE_DIR is set, goes to numba's locators."""
    from numba import njit
    from numba.core import config

    from approxtree.kernels.grid_patch import grid_patch_mesh
    from approxtree.render.selector import _traverse

    assert _cache.REGISTERED
    for kernel, folder in ((grid_patch_mesh, "kernels"), (_traverse, "render")):
        locator = _locator(kernel)
        assert type(locator).__name__ == "PackageCacheLocator"
        assert Path(locator.get_cache_path()) == _cache.cache_folder() / folder
    src = tmp_path / "elsewhere.py"
    src.write_text("def f(x):\n    return x + 1\n")
    namespace: dict = {}
    exec(compile(src.read_text(), str(src), "exec"), namespace)
    assert type(_locator(njit(cache=True)(namespace["f"]))).__name__ != "PackageCacheLocator"
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path / "user"))
    assert type(_locator(njit(cache=True)(_traverse.py_func))).__name__ == (
        "UserProvidedCacheLocator"
    )


@pytest.mark.parametrize("how", ["under_a_file", "read_only"])
def test_unusable_cache_folder_never_breaks_import(tmp_path, how):
    """A cache folder that cannot be created or written: approxtree imports, and its kernels
    fall back to numba's default locators (``__pycache__`` or the user-wide cache)."""
    if how == "under_a_file":
        (tmp_path / "file").write_text("")
        cache = tmp_path / "file" / "cache"
    else:
        if os.geteuid() == 0:
            pytest.skip("root writes into read-only folders")
        cache = tmp_path / "ro"
        cache.mkdir()
        cache.chmod(0o555)
    code = (
        "from approxtree.kernels.rgba import bands_into_rgba\n"
        "print(type(bands_into_rgba._cache._impl.locator).__name__)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], env=_env(cache), capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[0] in ("InTreeCacheLocator", "UserWideCacheLocator")
    assert not any(tmp_path.rglob("*.nbi"))


def _setup_module(monkeypatch) -> dict:
    """setup.py's definitions, without running setup()."""
    import setuptools

    monkeypatch.setattr(setuptools, "setup", lambda **kw: None)
    path = Path(__file__).resolve().parents[1] / "setup.py"
    namespace: dict = {"__name__": "approxtree_setup", "__file__": str(path)}
    exec(compile(path.read_text(), str(path), "exec"), namespace)
    return namespace


@pytest.mark.parametrize("failure", ["warmup_exits_1", "hook_raises"])
def test_build_hook_never_fails_the_build(tmp_path, monkeypatch, capsys, failure):
    """setup.py's build_py hook: a failing warm-up, or an error in the hook itself, prints a
    warning and the build goes on (the package then compiles its kernels on first use)."""
    from setuptools import Distribution
    from setuptools.command.build_py import build_py

    setup = _setup_module(monkeypatch)
    monkeypatch.setattr(build_py, "run", lambda self: None)
    build_lib = tmp_path / "lib"
    (build_lib / "approxtree").mkdir(parents=True)
    (build_lib / "approxtree" / "__init__.py").write_text("")
    (build_lib / "approxtree" / "_warmup.py").write_text("raise SystemExit(1)\n")
    if failure == "hook_raises":
        build_lib = tmp_path / "missing"
    command = setup["BuildPyWithKernels"](Distribution())
    command.build_lib = str(build_lib)
    command.editable_mode = False
    command.run()
    assert "WARNING: approxtree:" in capsys.readouterr().err


def test_editable_install_compiles_into_the_source_tree(tmp_path, monkeypatch):
    """An editable install runs the warm-up on the source tree itself (the cache the editable
    package reads), keeping the entries already there; APPROXTREE_NO_AOT=1 skips it."""
    from setuptools import Distribution
    from setuptools.command.build_py import build_py

    setup = _setup_module(monkeypatch)
    monkeypatch.setattr(build_py, "run", lambda self: None)
    calls: list[tuple[Path, bool]] = []
    setup["compile_kernels"] = lambda root, fresh=True: calls.append((root, fresh))
    command = setup["BuildPyWithKernels"](Distribution())
    command.build_lib = str(tmp_path / "lib")
    command.editable_mode = True
    command.run()
    assert calls == [(Path(__file__).resolve().parents[1], False)]
    # A wheel build compiles into its own fresh copy.
    command.editable_mode = False
    command.run()
    assert calls[1] == ((tmp_path / "lib").resolve(), True)
    monkeypatch.setenv("APPROXTREE_NO_AOT", "1")
    command.editable_mode = True
    command.run()
    assert len(calls) == 2


# Runs the bake's kernels (shading a strip, halving it) in one process and prints whether
# numba's full target refresh ran (it imports every lowering registry, numba.np.arraymath
# among them, and scipy.linalg for its BLAS check), the cache hits and misses, and the texels.
_LOAD_PROBE = """
import json, sys
import numpy as np
from approxtree.kernels import hillshade as hs
from approxtree.kernels.rgba import halve_bands

z = (np.arange(40 * 48, dtype=np.float32).reshape(40, 48) ** 1.5) % 97
z[5, 7] = np.nan
texels = np.empty((38, 48, 2), np.uint8)
hs.hillshade_grey_alpha_rows(
    z, 1, texels.view(np.uint16)[:, :, 0], 30.0, -30.0, 1.0, 45.0, 315.0, hs.HORN, hs.STANDARD
)
strip = np.ascontiguousarray(texels.transpose(2, 0, 1))
half = np.empty((2, 19, 24), np.uint8)
halve_bands(strip, half)
kernels = (hs.hillshade_grey_alpha_rows, halve_bands)
print("PROBE" + json.dumps({
    "refreshed": "numba.np.arraymath" in sys.modules,
    "scipy_linalg": "scipy.linalg" in sys.modules,
    "hits": sum(sum(k.stats.cache_hits.values()) for k in kernels),
    "misses": sum(sum(k.stats.cache_misses.values()) for k in kernels),
    "texels": [strip.tolist(), half.tolist()],
}))
"""


def _load_probe(cache: Path, **env: str) -> dict:
    run = subprocess.run(
        [sys.executable, "-c", _LOAD_PROBE],
        env=dict(_env(cache), **env),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.split("PROBE", 1)[1])


def test_cached_kernels_load_without_numbas_full_refresh(tmp_path):
    """A fresh process loads the bake's cached kernels without numba's target refresh (the
    ~0.3 s of importing every lowering registry and scipy.linalg), and they give the texels
    of numba's own loading (APPROXTREE_FULL_REFRESH=1) and of the compiling run."""
    cache = tmp_path / "cache"
    compiled = _load_probe(cache)
    assert compiled["misses"] == 2 and compiled["refreshed"]
    light = _load_probe(cache)
    assert light["hits"] == 2 and light["misses"] == 0
    assert not light["refreshed"] and not light["scipy_linalg"]
    full = _load_probe(cache, APPROXTREE_FULL_REFRESH="1")
    assert full["hits"] == 2 and full["misses"] == 0 and full["refreshed"]
    assert light["texels"] == full["texels"] == compiled["texels"]


def test_entries_naming_refresh_only_symbols_take_numbas_path():
    """An entry whose machine code names the string-hashing secrets (registered only by the
    full refresh), or that is not object code, is loaded after numba's full refresh."""
    plain = (("lib", "object", (b"\x7fELF...NRT_decref...", b"BC")), "fndesc")
    hashing = (("lib", "object", (b"\x7fELF..._numba_hashsecret_siphash_k0...", b"BC")), "f")
    assert not _cache._needs_full_refresh(plain)
    assert _cache._needs_full_refresh(hashing)
    assert _cache._needs_full_refresh((("lib", "bitcode", b"BC"), "fndesc"))
    assert _cache._needs_full_refresh(None)
    assert _cache.LIGHT_LOAD


def test_a_source_checkout_on_the_path_finds_its_shaders(monkeypatch):
    """Without an install mapping shaders/ to approxtree.shaders (the editable install's own
    warm-up imports the source tree through PYTHONPATH), the shaders come from the checkout."""
    from importlib import resources

    from approxtree import glsl

    def missing(package):
        raise ModuleNotFoundError(f"No module named {package!r}")

    monkeypatch.setattr(resources, "files", missing)
    folder = glsl.shader_dir()
    assert folder == Path(glsl.__file__).resolve().parent.parent / "shaders"
    assert glsl.load_source("terrain").stages
