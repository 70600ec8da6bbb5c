"""Where numba caches approxtree's kernels: a folder inside the installed package.

``pip install .`` compiles every kernel once into ``approxtree/_kernel_cache/`` (setup.py runs
``approxtree._warmup``), so the first ``approxtree demo`` loads machine code instead of
compiling it. numba's own locators would not find such a cache: they look in ``__pycache__``
next to the source and key entries by the interpreter's idea of the file, so this module puts
:class:`PackageCacheLocator` at the front of numba's locator list. It applies only to
approxtree's own source files; everything else goes to numba's locators unchanged.

The entry stamp is a content hash of the source file plus the numba, llvmlite, numpy and Python
versions: a wheel install does not preserve file times, and a cache built against other
versions must simply miss. (numba also keys each entry by the CPU name and features, so a cache
built on another machine misses too, and is refilled on first use.)

Fallbacks, all silent (importing approxtree never fails because of the cache):
- ``NUMBA_CACHE_DIR`` set: numba's ``UserProvidedCacheLocator`` wins (the locator steps aside);
- the package folder not writable (e.g. a root-owned site-packages): numba's default locators
  (``__pycache__``, then the user-wide cache);
- numba's caching internals not shaped as expected: nothing is registered.

``APPROXTREE_KERNEL_CACHE`` names another folder (tests and benchmarks use an empty one).
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


def source_stamp(path: str | os.PathLike, versions: tuple[str, ...] | None = None) -> str:
    """Content hash of ``path`` plus the numba, llvmlite, numpy and Python versions."""
    st = os.stat(path)
    return _stamp(str(path), st.st_mtime, st.st_size, versions or _versions())


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
            # An explicit NUMBA_CACHE_DIR is the user's choice: step aside.
            if config.CACHE_DIR:
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
        impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
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


REGISTERED = install()
