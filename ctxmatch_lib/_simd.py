"""Numba intrinsics for the fixed-order float64 sums of the exact distances (blob matching).

numba leaves LLVM's SLP vectoriser off, so eight running sums written as eight scalar variables stay eight
scalar chains. Here they are the eight lanes of one LLVM ``<8 x double>`` value (:class:`Vec8`): a lane-wise
subtract, multiply and add is the same IEEE operation as the scalar one (no fast-math flags, so no fused
multiply-add), hence the same bits as the scalar loop on any x86-64 CPU; where the CPU has no 512-bit
registers, LLVM splits the value into narrower ones, lane by lane.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core.errors import TypingError
from numba.extending import intrinsic, models, register_model

__all__ = ["Vec8", "zero8", "add_sqdiff8", "lanes8"]

_V8 = ir.VectorType(ir.DoubleType(), 8)


class Vec8(types.Type):
    """Eight float64 lanes held as one LLVM ``<8 x double>``; made and used by :func:`zero8`,
    :func:`add_sqdiff8` and :func:`lanes8` only."""

    def __init__(self):
        super().__init__(name="Vec8f64")


_vec8 = Vec8()


@register_model(Vec8)
class _Vec8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, _V8)


def _check(arr, name):
    ok = isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C"
    if not (ok and arr.dtype in (types.float32, types.float64)):
        raise TypingError(f"{name} must be a contiguous 1-d float32 or float64 array, got {arr}")


def _load8(context, builder, aryty, ary, k):
    """``ary[k:k + 8]`` as ``<8 x double>`` (float32 lanes widened exactly)."""
    data = context.make_array(aryty)(context, builder, ary).data
    elem = ir.FloatType() if aryty.dtype == types.float32 else ir.DoubleType()
    ptr = builder.bitcast(builder.gep(data, [k]), ir.VectorType(elem, 8).as_pointer())
    vec = builder.load(ptr, align=4 if aryty.dtype == types.float32 else 8)
    return builder.fpext(vec, _V8) if aryty.dtype == types.float32 else vec


@intrinsic
def zero8(typingctx):
    """A :class:`Vec8` of zeros."""

    def codegen(context, builder, sig, args):
        return ir.Constant(_V8, [0.0] * 8)

    return _vec8(), codegen


@intrinsic
def add_sqdiff8(typingctx, acc, a, b, k):
    """``acc + (a[k:k+8] - b[k:k+8])**2`` lane by lane, in float64 (the caller keeps ``k + 8 <= len``)."""
    _check(a, "a")
    _check(b, "b")

    def codegen(context, builder, sig, args):
        t = builder.fsub(_load8(context, builder, sig.args[1], args[1], args[3]),
                         _load8(context, builder, sig.args[2], args[2], args[3]))
        return builder.fadd(args[0], builder.fmul(t, t))

    return _vec8(_vec8, a, b, types.intp), codegen


@intrinsic
def lanes8(typingctx, acc):
    """The eight lanes of a :class:`Vec8` as a tuple of floats."""
    tup = types.UniTuple(types.float64, 8)

    def codegen(context, builder, sig, args):
        out = context.get_constant_undef(tup)
        for q in range(8):
            out = builder.insert_value(out, builder.extract_element(args[0], ir.Constant(ir.IntType(32), q)), q)
        return out

    return tup(_vec8), codegen
