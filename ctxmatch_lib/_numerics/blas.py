"""One BLAS thread (float32 products whose rounding must not follow the thread count, the filters' skinny
products), and the in-place product blob matching's scan accumulates into its tile."""

from __future__ import annotations

import sys

import numpy as np
from scipy.linalg import blas as _blas
from threadpoolctl import ThreadpoolController

_controller: ThreadpoolController | None = None
_modules = -1  # len(sys.modules) when the controller was made


def one_blas_thread():
    """``threadpoolctl.threadpool_limits(1)`` through a cached controller, remade when modules were imported
    since (torch brings its own thread pools)."""
    global _controller, _modules
    if _controller is None or len(sys.modules) != _modules:
        _controller = ThreadpoolController()
        _modules = len(sys.modules)
    return _controller.limit(limits=1)


def accumulate_product(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out += a @ b.T`` in place, for C-contiguous float32 ``a`` (R, d), ``b`` (C, d) and ``out`` (R, C).

    ``sgemm`` with ``beta = 1``: the scan zeroes each row of ``out`` while it is in cache, which OpenBLAS's
    ``beta = 0`` would do in a pass of its own.
    """
    for name, arr in (("a", a), ("b", b), ("out", out)):
        if arr.dtype != np.float32 or arr.ndim != 2 or not arr.flags.c_contiguous:
            raise ValueError(f"{name} must be a C-contiguous 2-d float32 array, got {arr.dtype} {arr.shape}")
    if out.shape != (len(a), len(b)) or a.shape[1] != b.shape[1]:
        raise ValueError(f"shapes {a.shape} @ {b.shape}.T do not give out's {out.shape}")
    # Column-major view: out.T (C, R) = b (C, d) @ a.T (d, R); b.T and a.T are Fortran-ordered views.
    c = out.T
    res = _blas.sgemm(1.0, b.T, a.T, beta=1.0, c=c, trans_a=1, overwrite_c=1)
    if res is not c:  # f2py worked on a copy (not for these layouts): write it back
        out[...] = res.T
