"""Where the compiled (numba) kernels of ctxmatch cache their machine code, and when it is stale.

numba's own locators file a kernel under the absolute path of its folder, so a fresh clone, a second
checkout or a new virtual environment compiles every kernel again (a minute or two on 2 cores), and they
stamp it with its own file only, so a kernel whose callee in another file changed loads stale code.
:class:`PackageLocator` files a kernel of this package under ``<numba cache>/ctxmatch_lib-<digest>/<its folder in
the package>``, the digest (:func:`kernel_sources_digest`) being the content of every module that holds or feeds
kernels: the same code compiles once per machine (per CPU name, which numba's index keys hold), wherever it
is checked out; any edit of kernel code compiles every kernel again, into a new folder, so that two versions
side by side (two branches) do not evict each other (``ctxmatch cache`` shows and clears the old ones).
"""

from __future__ import annotations

import functools
import hashlib
import os
from contextlib import contextmanager
from pathlib import Path

import numba
from numba.core import caching

from ..cache import cache_dir

__all__ = ["PackageLocator", "kernel_sources_digest", "user_cache"]

_PACKAGE = Path(__file__).resolve().parent.parent


@functools.lru_cache(maxsize=4)
def kernel_sources_digest(package: Path = _PACKAGE) -> str:
    """SHA-256 of the modules of ``package`` that hold or feed compiled kernels: every ``.py`` file that
    names numba, and the fixed-order numerics (``_numerics/``) whose constants and helpers kernels inline.
    Paths enter relative to ``package``, so two checkouts of the same code give the same digest."""
    h = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        data = path.read_bytes()
        rel = path.relative_to(package)
        if b"numba" in data or rel.parts[0] == "_numerics":
            h.update(rel.as_posix().encode() + b"\0" + data + b"\0")
    return h.hexdigest()


class PackageLocator(caching._CacheLocator):
    """numba cache locator for the kernels of this package: the folder follows the kernel code's digest and the
    module's place in the package (not the checkout's absolute path); the stamp is the same digest."""

    def __init__(self, py_func, py_file: str, package: Path):
        rel = Path(py_file).resolve().relative_to(package)
        self._cache_path = os.path.join(numba.config.CACHE_DIR, f"{package.name}-{kernel_sources_digest(package)[:16]}",
                                        *rel.parent.parts)
        self._lineno = py_func.__code__.co_firstlineno
        self._package = package

    def get_cache_path(self) -> str:
        return self._cache_path

    def get_source_stamp(self) -> str:
        return kernel_sources_digest(self._package)

    def get_disambiguator(self) -> str:
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file: str):
        """The locator of a kernel defined in a module of this package, ``None`` for any other function (numba
        then tries its own locators) or when the cache folder cannot be written."""
        if not numba.config.CACHE_DIR or not py_file.endswith(".py"):
            return None
        path = Path(py_file).resolve()
        package = next((p for p in path.parents if p.name == _PACKAGE.name and (p / "__init__.py").is_file()),
                       None)
        if package is None:
            return None
        self = cls(py_func, py_file, package)
        try:
            self.ensure_cache_path()
        except OSError:
            return None
        return self


def _install_locator() -> None:
    """Put :class:`PackageLocator` first in numba's locators (once per process)."""
    classes = caching.CacheImpl._locator_classes
    if PackageLocator not in classes:
        classes.insert(0, PackageLocator)


@contextmanager
def user_cache():
    """Point numba's cache at ``cache_dir("numba")`` while kernels are decorated, unless ``NUMBA_CACHE_DIR``
    is set, with :class:`PackageLocator` in place; yield whether to cache (not when the folder cannot be
    created)."""
    _install_locator()
    previous = numba.config.CACHE_DIR
    if previous:
        yield True
        return
    try:
        numba.config.CACHE_DIR = str(cache_dir("numba"))
    except OSError:
        yield False
        return
    try:
        yield True
    finally:
        numba.config.CACHE_DIR = previous
