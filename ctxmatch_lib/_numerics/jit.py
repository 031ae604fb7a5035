"""Where the compiled (numba) kernels of ctxmatch cache their machine code."""

from __future__ import annotations

from contextlib import contextmanager

import numba

from ..cache import cache_dir

__all__ = ["user_cache"]


@contextmanager
def user_cache():
    """Point numba's on-disk cache at ``cache_dir("numba")`` while kernels are decorated (when numba picks
    their cache location), unless ``NUMBA_CACHE_DIR`` is set. Yields whether to cache at all: not when that
    folder cannot be created (numba would fall back to the package's own folder)."""
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
