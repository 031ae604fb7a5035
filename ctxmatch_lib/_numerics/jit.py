"""Where the compiled (numba) kernels of ctxmatch cache their machine code."""

from __future__ import annotations

from contextlib import contextmanager

import numba

from ..cache import cache_dir

__all__ = ["user_cache"]


@contextmanager
def user_cache():
    """Point numba's cache at ``cache_dir("numba")`` while kernels are decorated, unless ``NUMBA_CACHE_DIR``
    is set; yield whether to cache (not when the folder cannot be created)."""
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
