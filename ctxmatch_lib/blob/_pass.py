"""The two drivers of ``BlobContext``'s one pass over D (:attr:`~.context.BlobContext.product`), filling the
same lists and codes; the arguments are those of :func:`._kernels.scan_tile`."""

from __future__ import annotations

import numpy as np

from .._numerics.blas import accumulate_product
from . import _fused_kernels, _kernels

__all__ = ["fused_pass", "tile_pass"]


def tile_pass(A32, B32, n1, n2, rv, ri, rthr, cv, ci, cthr, Kr, Kc, dense, keep, qoff, qinv, *, tile) -> None:
    """The pass over BLAS GEMM tiles of ``tile = (rows, columns)``, accumulated into a buffer that
    :func:`._kernels.scan_tile` reads and zeroes."""
    R, C = tile
    buf = np.zeros(R * C, np.float32)  # zero between tiles: the scan clears what it has read
    for r0 in range(0, len(A32), R):
        a = A32[r0 : r0 + R]
        for c0 in range(0, len(B32), C):
            b = B32[c0 : c0 + C]
            G = buf[: len(a) * len(b)].reshape(len(a), len(b))
            accumulate_product(a, b, G)
            _kernels.scan_tile(G, r0, c0, n1, n2, rv, ri, rthr, cv, ci, cthr, Kr, Kc, dense, keep, qoff, qinv)


def fused_pass(A32, B32, n1, n2, rv, ri, rthr, cv, ci, cthr, Kr, Kc, dense, keep, qoff, qinv, *, columns) -> None:
    """The pass with the product in registers (:func:`._fused_kernels.product_scan`), on padded inputs that
    are never flagged. ``columns`` False: no column keeps entries."""
    n, m = len(A32), len(B32)
    if n == 0 or m == 0:
        return
    n4 = -(-n // 4) * 4
    A4, n1p = A32, n1
    if n4 != n:
        A4 = np.zeros((n4, A32.shape[1]), np.float32)
        A4[:n] = A32
        n1p = np.full(n4, np.inf, np.float32)
        n1p[:n] = n1
    Bp, n2p = _fused_kernels.pack_columns(B32, n2)
    cthrp = np.full(len(n2p), -np.inf, np.float32)
    cthrp[:m] = cthr
    _fused_kernels.product_scan(A4, n1p, Bp, n2p, rv, ri, rthr, cv, ci, cthrp, Kr, Kc, columns, dense, keep,
                                qoff, qinv)
    cthr[:] = cthrp[:m]
