"""Where numba caches approxtree's kernels: a folder inside the installed package.

``pip install .`` compiles every kernel once into ``approxtree/_kernel_cache/`` (setup.py runs
``approxtree._warmup``), so the first ``approxtree demo`` loads machine code instead of
compiling it. numba's own locators would not find such a cache: they look in ``__pycache__``
next to the source and key entries by the interpreter's idea of the file, so this module puts
:class:`PackageCacheLocator` at the front of numba's locator list. It applies only to
approxtree's own source files; everything else goes to numba's locators unchanged.

The entry stamp is a content hash of the source file, of every other kernel source of the package
(each ``.py`` file below it that names numba) and of the numba, llvmlite, numpy and Python
versions: a wheel install does not preserve file times, a kernel carries compiled copies of the
kernels it calls from other modules (an edit there must reach it), and a cache built against
other versions must simply miss. (numba also keys each entry by the CPU name and features, so
a cache built on another machine misses too, and is refilled on first use.)

Fallbacks, all silent (importing approxtree never fails because of the cache):
- ``NUMBA_CACHE_DIR`` set: numba's ``UserProvidedCacheLocator`` wins (the locator steps aside);
- the package folder not writable (e.g. a root-owned site-packages): numba's default locators
  (``__pycache__``, then the user-wide cache);
- numba's caching internals not shaped as expected: nothing is registered.

``APPROXTREE_KERNEL_CACHE`` names another folder (tests and benchmarks use an empty one).

Loading an entry skips numba's full target refresh (``install_light_load``): before loading any
cached entry numba imports all its lowering registries and scipy.linalg (its BLAS check), ~0.3 s
holding the GIL in a fresh process, which machine code does not need. Entries of this cache get
the runtime initialized instead; a miss compiles (and refreshes) as usual, and an entry naming
a symbol only the refresh registers takes numba's own path. ``APPROXTREE_FULL_REFRESH=1`` turns
it off.
"""

from __future__ import annotations

import functools
import hashlib
import os
import sys
from pathlib import Path

# The approxtree package folder: only kernels defined below it are located here.
PACKAGE_ROOT = Path(__file__).resolve().parent.parent
ENV_FOLDER = "APPROXTREE_KERNEL_CACHE"
FULL_REFRESH_ENV = "APPROXTREE_FULL_REFRESH"


def cache_folder() -> Path:
    """The folder holding approxtree's kernel cache (one subfolder per package module folder)."""
    override = os.environ.get(ENV_FOLDER)
    return Path(override) if override else PACKAGE_ROOT / "_kernel_cache"


def _versions() -> tuple[str, str, str, str]:
    import llvmlite
    import numba
    import numpy

    return (numba.__version__, llvmlite.__version__, numpy.__version__, sys.version)


@functools.cache
def _stamp(path: str, mtime: float, size: int, versions: tuple[str, ...]) -> str:
    # mtime and size are only the memo key (a file edited while running is re-hashed).
    digest = hashlib.sha256(Path(path).read_bytes())
    digest.update("\0".join(versions).encode())
    return digest.hexdigest()


@functools.cache
def _kernel_files(root: Path) -> tuple[Path, ...]:
    """The ``.py`` files below ``root`` that name numba (where kernels live), sorted; listed
    once per process (a file added while running is not seen until the next one)."""
    files = [p for p in root.rglob("*.py") if b"numba" in p.read_bytes()]
    return tuple(sorted(files, key=lambda p: p.relative_to(root).as_posix()))


@functools.cache
def _named_kernel_files(root: Path) -> tuple[tuple[str, str], ...]:
    """(relative name, path) of each of ``_kernel_files(root)``, in its order."""
    return tuple((p.relative_to(root).as_posix(), str(p)) for p in _kernel_files(root))


@functools.cache
def _sources_digest(
    files: tuple[tuple[str, str], ...], stats: tuple[tuple[float, int], ...]
) -> str:
    """``kernel_sources_digest`` of ``files`` whose (mtime, size) are ``stats`` (the memo key:
    numba asks once per kernel, ~70 times in a process, for the same files)."""
    digest = hashlib.sha256()
    for (name, path), (mtime, size) in zip(files, stats, strict=True):
        digest.update(name.encode() + b"\0")
        digest.update(_stamp(path, mtime, size, ()).encode())
    return digest.hexdigest()


def kernel_sources_digest(root: str | os.PathLike = PACKAGE_ROOT) -> str:
    """Content hash of every kernel source below ``root`` (relative names and contents).

    numba compiles a kernel together with the kernels it calls, including other modules'; a
    stamp of the kernel's own file alone would keep serving the old code after an edit there.
    """
    files = _named_kernel_files(Path(root))
    stats = []
    for _, path in files:
        st = os.stat(path)
        stats.append((st.st_mtime, st.st_size))
    return _sources_digest(files, tuple(stats))


def source_stamp(
    path: str | os.PathLike,
    versions: tuple[str, ...] | None = None,
    root: str | os.PathLike = PACKAGE_ROOT,
) -> str:
    """Content hash of ``path``, of every kernel source below ``root``
    (:func:`kernel_sources_digest`) and of the numba, llvmlite, numpy and Python versions."""
    st = os.stat(path)
    own = _stamp(str(path), st.st_mtime, st.st_size, versions or _versions())
    return hashlib.sha256((own + kernel_sources_digest(root)).encode()).hexdigest()


def _make_locator_class() -> type:
    from numba.core import caching, config

    class PackageCacheLocator(caching._CacheLocator):
        """numba cache locator for approxtree's own kernels: the package's cache folder."""

        def __init__(self, py_func, py_file: str, relative: Path) -> None:
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            # One subfolder per source folder (kernels/, render/): names stay short and the
            # cache is relocatable (no absolute path in it).
            self._cache_path = str(cache_folder() / "_".join(relative.parent.parts or ("root",)))

        def get_cache_path(self) -> str:
            return self._cache_path

        def get_source_stamp(self) -> str:
            return source_stamp(self._py_file)

        def get_disambiguator(self) -> str:
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file: str):
            # An explicit NUMBA_CACHE_DIR is the user's choice: step aside. (numba's config sets
            # its attributes from the environment at run time: mypy cannot see them.)
            if getattr(config, "CACHE_DIR", ""):
                return None
            try:
                relative = Path(py_file).resolve().relative_to(PACKAGE_ROOT)
            except (ValueError, OSError):
                return None
            self = cls(py_func, py_file, relative)
            try:
                self.ensure_cache_path()
            except OSError:
                # Not writable: numba's default locators take over.
                return None
            return self

    return PackageCacheLocator


def install() -> bool:
    """Put the package locator first in numba's locator list (once). True when registered."""
    try:
        from numba.core import caching

        # numba 0.68 names the class CacheImpl, older releases _CacheImpl.
        impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
        if impl is None:
            return False
        classes = impl._locator_classes
        if any(getattr(c, "__name__", "") == "PackageCacheLocator" for c in classes):
            return True
        locator = _make_locator_class()
        for name in ("get_cache_path", "ensure_cache_path", "from_function"):
            if not hasattr(caching._CacheLocator, name):
                return False
        classes.insert(0, locator)
        return True
    except Exception:
        # numba's internals changed: keep numba's default caching.
        return False


#: Names that compiled code can only link against after numba's full target refresh: the
#: string-hashing secrets (``numba.cpython.hashing``, imported by ``load_additional_registries``).
#: Every other symbol a cached library names is registered without it: numba's C helpers and
#: math functions when its CPU context is made, the runtime (NRT) by ``rtsys.initialize``, the
#: threading layer by the entry's own reload hooks (parallel kernels).
_REFRESH_ONLY_SYMBOLS = (b"_numba_hashsecret_",)


def _needs_full_refresh(data: object) -> bool:
    """Whether a cached entry (numba's reduced compile result) may name a symbol that only a
    full refresh registers; True for anything not shaped as an object-code library."""
    if not isinstance(data, tuple):
        return True
    try:
        _name, kind, (object_code, _bitcode) = data[0]
        if kind != "object" or not isinstance(object_code, bytes):
            return True
        return any(symbol in object_code for symbol in _REFRESH_ONLY_SYMBOLS)
    except (TypeError, ValueError, IndexError):
        return True


def _light_load_overload(original):
    """numba's ``Cache.load_overload`` for approxtree's kernels without the target refresh.

    numba refreshes its CPU target before loading any cached entry: it imports every lowering
    registry (and scipy.linalg, for its BLAS check), ~0.3 s of a fresh process holding the
    GIL, though loading machine code needs none of it. For an entry of the package locator
    this initializes only the runtime and loads the entry; a miss returns None as before (the
    compile that follows refreshes the target itself), and an entry that may need more (see
    ``_needs_full_refresh``), or any other cache, takes numba's own path.
    """

    def load_overload(self, sig, target_context):
        impl = getattr(self, "_impl", None)
        locator = getattr(impl, "_locator", None)
        if type(locator).__name__ != "PackageCacheLocator" or not getattr(self, "_enabled", 0):
            return original(self, sig, target_context)
        from numba.core.runtime import rtsys

        with self._guard_against_spurious_io_errors():
            data = self._cache_file.load(self._index_key(sig, target_context.codegen()))
            if data is None:
                return None
            if _needs_full_refresh(data):
                target_context.refresh()
            else:
                rtsys.initialize(target_context)
            return impl.rebuild(target_context, data)
        return None

    load_overload.approxtree_light = True
    return load_overload


def install_light_load() -> bool:
    """Load approxtree's cached kernels without numba's full target refresh (once). True
    when installed; numba's own loading stays when its internals are not as expected."""
    try:
        from numba.core import caching

        cache = caching.Cache
        if getattr(cache.load_overload, "approxtree_light", False):
            return True
        for name in ("_guard_against_spurious_io_errors", "_index_key", "load_overload"):
            if not hasattr(cache, name):
                return False
        from numba.core.runtime import rtsys

        if not hasattr(rtsys, "initialize"):
            return False
        # Replacing numba's method on purpose (a monkeypatch): mypy forbids it by default.
        cache.load_overload = _light_load_overload(cache.load_overload)  # type: ignore[method-assign]
        return True
    except Exception:
        return False


REGISTERED = install()
#: Cached kernels load without numba's full target refresh (``APPROXTREE_FULL_REFRESH=1``:
#: numba's own loading, as for every other package).
LIGHT_LOAD = REGISTERED and os.environ.get(FULL_REFRESH_ENV) != "1" and install_light_load()
