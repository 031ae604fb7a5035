"""Compiled (numba) kernel of PGM: the pairwise affinity of many candidate pairs (see :mod:`.pgm`).

The kernel evaluates, pair by pair, the very expressions of the array formulation (same operations in the
same order, no fast-math), so its results are bit-identical to it; it only saves the temporaries of the
gathers, which made the affinity the dominant cost of PGM on 30 000 candidates.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .._numba import user_cache

__all__ = ["pair_affinity"]


with user_cache() as _cache:

    @numba.njit(cache=_cache, nogil=True, error_model="numpy")
    def _pair_affinity_kernel(x, y, t, a, b, cut, with_t):  # pragma: no cover - compiled
        w = np.empty(len(a))
        for i in range(len(a)):
            p, q = a[i], b[i]
            dx0, dx1 = x[q, 0] - x[p, 0], x[q, 1] - x[p, 1]
            dy0, dy1 = y[q, 0] - y[p, 0], y[q, 1] - y[p, 1]
            if with_t:
                e_a = math.hypot(dy0 - t[p, 0] * dx0 - t[p, 1] * dx1, dy1 - t[p, 2] * dx0 - t[p, 3] * dx1)
                e_b = math.hypot(dy0 - t[q, 0] * dx0 - t[q, 1] * dx1, dy1 - t[q, 2] * dx0 - t[q, 3] * dx1)
                d = 0.5 * (e_a + e_b)
                if not math.isfinite(d):
                    d = np.inf
            else:
                l1, l2 = math.hypot(dx0, dx1), math.hypot(dy0, dy1)
                d = 2.0 * abs(l1 - l2) / (l1 + l2) if l1 + l2 > 0 else 0.0
            w[i] = max(1.0 - d / cut, 0.0)
        return w


def pair_affinity(x: np.ndarray, y: np.ndarray, T: np.ndarray | None, a: np.ndarray, b: np.ndarray,
                  tau: float, rho: float) -> np.ndarray:
    """Pairwise affinity in [0, 1] of the candidates ``a[i]`` and ``b[i]`` (arrays of indices).

    ``x``, ``y``: (n, 2) candidate keypoints in image 1 and 2, (x, y) pixels. With the local affine
    transformations ``T`` (n, 2, 2): ``max(1 - d / tau, 0)``, ``d`` the mutual projection error in pixels
    (infinite when not finite). Without (``T=None``): ``max(1 - d / rho, 0)``,
    ``d = |l1 - l2| / ((l1 + l2) / 2)`` the relative length distortion of the edge (0 for two coincident
    keypoints in both images).
    """
    x = np.ascontiguousarray(x, np.float64)
    y = np.ascontiguousarray(y, np.float64)
    a = np.ascontiguousarray(a, np.int64)
    b = np.ascontiguousarray(b, np.int64)
    if T is None:
        return _pair_affinity_kernel(x, y, np.zeros((0, 4)), a, b, float(rho), False)
    t = np.ascontiguousarray(np.asarray(T, np.float64).reshape(-1, 4))
    return _pair_affinity_kernel(x, y, t, a, b, float(tau), True)
