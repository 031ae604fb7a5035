"""Helpers shared by the benchmark scripts (the folder is not a package: a script run as
``python benchmarks/<name>.py`` has this folder on its path and imports ``from _common import ...``)."""

from __future__ import annotations

import time

import numpy as np


def best_of(fn, repeat=3, *, warmup=False):
    """``(seconds, result)``: the best wall time of ``repeat`` calls of ``fn()`` and the last call's result,
    after one untimed call first when ``warmup`` (with ``repeat=0``: its result)."""
    out = fn() if warmup else None
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out
