"""Compiled (numba) loops behind :func:`.fixedmath.exp` and :func:`.fixedmath.tanh` (the patch networks' activations).

The same operations as ``fixedmath._exp_ufuncs`` / ``_tanh_ufuncs``, in one loop; without ``fastmath``
nothing is reassociated or fused, so every x86-64 CPU gives the same bits. ``tanh``'s loop has no branch or
integer conversion (:func:`_pow2`), so LLVM vectorises it.
"""

from __future__ import annotations

import math
from functools import partial

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .fdlibm import _INVLN2, _LN2HI, _LN2LO, _P
from .jit import user_cache

__all__ = ["exp", "tanh", "tanh_f32"]

_P1, _P2, _P3, _P4, _P5 = _P
_TINY = 2.0 ** -5
# 2 ** m for |m| <= 800 (exact powers of two; _exp1's scalings need |m| <= 794).
_POW2_BIAS = 800
_POW2 = np.ldexp(1.0, np.arange(-_POW2_BIAS, _POW2_BIAS + 1))


@intrinsic
def _pow2(typingctx, k):
    """``2.0 ** k`` for an integer-valued float64 ``k`` in [-1022, 1023], from the bits of ``k + 1.5 * 2**52``
    (no integer conversion, which AVX2 lacks, so a loop using it vectorises)."""
    sig = types.float64(types.float64)

    def codegen(context, builder, sig, args):
        i64 = ir.IntType(64)
        biased = builder.bitcast(builder.fadd(args[0], ir.Constant(ir.DoubleType(), 6755399441055744.0)), i64)
        bits = builder.shl(builder.sub(biased, ir.Constant(i64, 0x4338000000000000 - 1023)), ir.Constant(i64, 52))
        return builder.bitcast(bits, ir.DoubleType())

    return sig, codegen


with user_cache() as _cache:
    # error_model="numpy": a float division by zero is IEEE's (never met here), not a branch to a Python
    # exception that would keep the loops scalar.
    _jit = partial(numba.njit, cache=_cache, nogil=True, error_model="numpy")

    @_jit
    def _exp1(x):
        # fixedmath._exp_ufuncs on one value (NaN gives NaN), without branches or calls. Both scalings by
        # 2 ** m (|m| <= 794: normal numbers) multiply by table entries, as ldexp (the second rounds once).
        xc = min(max(x, -1100.0), 1100.0)
        k = np.rint(xc * _INVLN2)
        hi = x - k * _LN2HI
        lo = k * _LN2LO
        r = hi - lo
        rr = r * r
        # _horner(rr, _P): the innermost coefficient first, one rounding per operation.
        acc = _P5
        acc = acc * rr + _P4
        acc = acc * rr + _P3
        acc = acc * rr + _P2
        acc = acc * rr + _P1
        c = r - rr * acc
        y = 1.0 + ((r * c) / (2.0 - c) - lo + hi)
        half = np.trunc(k / 2)
        out = (y * _POW2[int(half) + _POW2_BIAS]) * _POW2[int(k - half) + _POW2_BIAS]
        out = np.inf if x > 709.782712893384 else out
        out = 0.0 if x < -745.1332191019412 else out
        return x if x != x else out

    @_jit
    def _exp_tanh(x):
        # _exp1 for x in [-80, 0] (NaN unused): k in [-116, 0], so _exp1's two exact scalings are one exact
        # multiplication by _pow2(k): the same bits, no table or integer conversion (_tanh_loop vectorises).
        k = np.rint(x * _INVLN2)
        hi = x - k * _LN2HI
        lo = k * _LN2LO
        r = hi - lo
        rr = r * r
        acc = _P5
        acc = acc * rr + _P4
        acc = acc * rr + _P3
        acc = acc * rr + _P2
        acc = acc * rr + _P1
        c = r - rr * acc
        y = 1.0 + ((r * c) / (2.0 - c) - lo + hi)
        return y * _pow2(k)

    @_jit
    def _tanh1(x):
        # fixedmath._tanh_ufuncs on one value: both branches evaluated, one selected (vectorisable).
        a = abs(x)
        z = a * a
        small = a + a * (z * (-1 / 3 + z * (2 / 15 + z * (-17 / 315 + z * (62 / 2835)))))
        e = _exp_tanh(-2.0 * min(a, 40.0))
        big = (1.0 - e) / (1.0 + e)
        t = small if a < _TINY else big
        return x if x != x else math.copysign(t, x)

    @_jit
    def _exp_loop(x, out):
        for i in range(x.size):
            out[i] = _exp1(x[i])

    @_jit
    def _tanh_loop(x, out):
        for i in range(x.size):
            out[i] = _tanh1(np.float64(x[i]))


def exp(x) -> np.ndarray:
    """``fixedmath._exp_ufuncs(x)``, compiled: the same bits, a float64 array of ``x``'s shape."""
    x = np.asarray(x, np.float64)
    out = np.empty(x.shape)
    _exp_loop(np.ascontiguousarray(x).reshape(-1), out.reshape(-1))
    return out


def tanh(x) -> np.ndarray:
    """``fixedmath._tanh_ufuncs(x)``, compiled: the same bits, a float64 array of ``x``'s shape."""
    x = np.asarray(x, np.float64)
    out = np.empty(x.shape)
    _tanh_loop(np.ascontiguousarray(x).reshape(-1), out.reshape(-1))
    return out


def tanh_f32(x: np.ndarray) -> np.ndarray:
    """``tanh(x).astype(np.float32)`` of a float32 array, without the float64 array in between."""
    x = np.ascontiguousarray(x, np.float32)
    out = np.empty_like(x)
    _tanh_loop(x.reshape(-1), out.reshape(-1))
    return out
