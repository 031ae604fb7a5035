"""Compiled (numba) direct convolution for the patch networks' shallow layers (:func:`._nn.conv2d`).

Where the ``im2col`` matrix costs more than its product (OriNet's 16-channel 3×3 layers), each output
``Σ_(i, j, c) x[y + i, x + j, c] · w[i, j, c, o]`` is summed in registers in float64, in that fixed order, so
the same on any CPU; tiles of 4 pixels × 8 channels keep one input channel's weights in two registers.
"""

from __future__ import annotations

from functools import partial

import numba
import numpy as np

from .._numerics.jit import user_cache
from .._numerics.simd import load4 as _load4, muladd4 as _muladd4, splat4 as _splat4, store4 as _store4, zero4 as _zero4

__all__ = ["direct_conv2d"]

with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _conv_rows(x, w, dims, out):
        # x: the padded input (N, Hp, Wp, C) flattened, float32; w: (kh, kw, C, O) flattened, float64;
        # out: (N, Ho, Wo, O) flattened, float64. dims = (N, Hp, Wp, C, kh, kw, O, stride, Ho, Wo).
        N, Hp, Wp, C, kh, kw, O, s, Ho, Wo = dims
        ps = s * C  # from one output pixel's window to the next one's
        for n in range(N):
            for yo in range(Ho):
                orow = (n * Ho + yo) * Wo * O
                for ob in range(0, O, 8):
                    xo = 0
                    while xo + 4 <= Wo:
                        a0 = _zero4()
                        b0 = _zero4()
                        a1 = _zero4()
                        b1 = _zero4()
                        a2 = _zero4()
                        b2 = _zero4()
                        a3 = _zero4()
                        b3 = _zero4()
                        for i in range(kh):
                            for j in range(kw):
                                p = ((n * Hp + yo * s + i) * Wp + xo * s + j) * C
                                q = ((ob * kh + i * 8) * kw + j * 8) * C
                                for c in range(C):
                                    w0 = _load4(w, q)
                                    w1 = _load4(w, q + 4)
                                    v = _splat4(x, p + c)
                                    a0 = _muladd4(a0, v, w0)
                                    b0 = _muladd4(b0, v, w1)
                                    v = _splat4(x, p + ps + c)
                                    a1 = _muladd4(a1, v, w0)
                                    b1 = _muladd4(b1, v, w1)
                                    v = _splat4(x, p + 2 * ps + c)
                                    a2 = _muladd4(a2, v, w0)
                                    b2 = _muladd4(b2, v, w1)
                                    v = _splat4(x, p + 3 * ps + c)
                                    a3 = _muladd4(a3, v, w0)
                                    b3 = _muladd4(b3, v, w1)
                                    q += 8
                        t = orow + xo * O + ob
                        _store4(out, t, a0)
                        _store4(out, t + 4, b0)
                        _store4(out, t + O, a1)
                        _store4(out, t + O + 4, b1)
                        _store4(out, t + 2 * O, a2)
                        _store4(out, t + 2 * O + 4, b2)
                        _store4(out, t + 3 * O, a3)
                        _store4(out, t + 3 * O + 4, b3)
                        xo += 4
                    while xo < Wo:  # the last Wo mod 4 pixels of the row, one at a time
                        a0 = _zero4()
                        b0 = _zero4()
                        for i in range(kh):
                            for j in range(kw):
                                p = ((n * Hp + yo * s + i) * Wp + xo * s + j) * C
                                q = ((ob * kh + i * 8) * kw + j * 8) * C
                                for c in range(C):
                                    v = _splat4(x, p + c)
                                    a0 = _muladd4(a0, v, _load4(w, q))
                                    b0 = _muladd4(b0, v, _load4(w, q + 4))
                                    q += 8
                        t = orow + xo * O + ob
                        _store4(out, t, a0)
                        _store4(out, t + 4, b0)
                        xo += 1


def direct_conv2d(x: np.ndarray, w: np.ndarray, *, stride: int = 1) -> np.ndarray:
    """Cross-correlation of the padded float32 ``x`` (N, H, W, C) with torch-layout ``w`` (O, C, kh, kw), ``O``
    a multiple of 8 -> float32 (N, H', W', O), each sum rounded once; the caller adds the bias."""
    o, c, kh, kw = w.shape
    if o % 8 or x.ndim != 4 or x.shape[3] != c:
        raise ValueError(f"direct_conv2d needs (N, H, W, {c}) input and a multiple of 8 output channels, got "
                         f"{x.shape} and {w.shape}")
    n, h, wd = x.shape[:3]
    ho, wo = (h - kh) // stride + 1, (wd - kw) // stride + 1
    out = np.empty(n * ho * wo * o)
    dims = tuple(int(v) for v in (n, h, wd, c, kh, kw, o, stride, ho, wo))
    _conv_rows(np.ascontiguousarray(x, np.float32).reshape(-1),
               np.ascontiguousarray(w.reshape(o // 8, 8, c, kh, kw).transpose(0, 3, 4, 2, 1), np.float64).reshape(-1), dims, out)
    return out.astype(np.float32).reshape(n, ho, wo, o)
