"""Numba intrinsics for fixed-order float64 sums in SIMD registers, and blob matching's 16-lane work.

numba leaves LLVM's SLP vectoriser off; here running sums are the lanes of one LLVM vector (:class:`Vec8`,
:class:`Vec4`, :class:`Vec16`), each lane-wise operation the scalar IEEE one, so the bits are the scalar
loop's on any x86-64 CPU. Only :func:`fma16` and the fused product that uses it (which only proposes) fuse.

numba's disk cache checks only a kernel's own file: after an edit here, touch the ``*_kernels.py`` files
that use these intrinsics or clear ``$CTXMATCH_CACHE/numba``. Never rename or remove a type below (a
cached index naming a missing type raises ``AttributeError`` instead of recompiling).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core.errors import TypingError
from numba.extending import intrinsic, models, register_model

__all__ = ["Vec8", "zero8", "add_sqdiff8", "lanes8", "Vec4", "load4", "store4", "mul4", "muladd4", "splat4", "zero4",
           "Vec16", "load16",
           "store16", "count16", "below16", "insert16", "lane16", "band16",
           "prefetch", "fill16", "fma16", "row_flags", "row_reflag", "row_codes"]

_V8 = ir.VectorType(ir.DoubleType(), 8)
_V4 = ir.VectorType(ir.DoubleType(), 4)


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


def _check(arr, name, dtypes=(types.float32, types.float64)):
    """Typing-time check of an array operand: contiguous, 1-d, of one of ``dtypes``."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C" and arr.dtype in dtypes):
        names = " or ".join(str(t) for t in dtypes)
        raise TypingError(f"{name} must be a contiguous 1-d {names} array, got {arr}")


def _check2(arr, name, dtypes=None):
    """Typing-time check of a matrix operand: C-contiguous, 2-d, of one of ``dtypes`` (any when ``None``)."""
    if not (isinstance(arr, types.Array) and arr.ndim == 2 and arr.layout == "C"
            and (dtypes is None or arr.dtype in dtypes)):
        names = "" if dtypes is None else " or ".join(str(t) for t in dtypes) + " "
        raise TypingError(f"{name} must be a C-contiguous 2-d {names}array, got {arr}")


def _lanes(context, builder, aryty, ary, k, n):
    """Pointer to the ``n`` elements ``ary[k:k + n]`` as one LLVM vector of the array's type (no bounds
    check)."""
    data = context.make_array(aryty)(context, builder, ary).data
    elem = context.get_value_type(aryty.dtype)
    return builder.bitcast(builder.gep(data, [k]), ir.VectorType(elem, n).as_pointer())


def _load8(context, builder, aryty, ary, k):
    """``ary[k:k + 8]`` as ``<8 x double>`` (float32 lanes widened exactly)."""
    single = aryty.dtype == types.float32
    vec = builder.load(_lanes(context, builder, aryty, ary, k, 8), align=4 if single else 8)
    return builder.fpext(vec, _V8) if single else vec


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


class Vec4(types.Type):
    """Four float64 lanes held as one LLVM ``<4 x double>``; made and used by :func:`load4`, :func:`store4`,
    :func:`mul4`, :func:`muladd4`, :func:`splat4` and :func:`zero4` only."""

    def __init__(self):
        super().__init__(name="Vec4f64")


_vec4 = Vec4()


@register_model(Vec4)
class _Vec4Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, _V4)


@intrinsic
def load4(typingctx, arr, k):
    """``arr[k:k + 4]`` as a :class:`Vec4` (the caller keeps ``k + 4 <= len(arr)``)."""
    _check(arr, "arr", (types.float64,))

    def codegen(context, builder, sig, args):
        return builder.load(_lanes(context, builder, sig.args[0], args[0], args[1], 4), align=8)

    return _vec4(arr, types.intp), codegen


@intrinsic
def store4(typingctx, arr, k, v):
    """``arr[k:k + 4] = v`` for a :class:`Vec4` ``v``."""
    _check(arr, "arr", (types.float64,))

    def codegen(context, builder, sig, args):
        builder.store(args[2], _lanes(context, builder, sig.args[0], args[0], args[1], 4), align=8)
        return context.get_dummy_value()

    return types.none(arr, types.intp, _vec4), codegen


@intrinsic
def mul4(typingctx, a, b):
    """``a * b`` lane by lane."""

    def codegen(context, builder, sig, args):
        return builder.fmul(args[0], args[1])

    return _vec4(_vec4, _vec4), codegen


@intrinsic
def splat4(typingctx, arr, k):
    """A :class:`Vec4` with ``arr[k]`` in every lane (float32 widened exactly; no bounds check)."""
    _check(arr, "arr")

    def codegen(context, builder, sig, args):
        aryty = sig.args[0]
        data = context.make_array(aryty)(context, builder, args[0]).data
        x = builder.load(builder.gep(data, [args[1]]))
        if aryty.dtype == types.float32:
            x = builder.fpext(x, ir.DoubleType())
        return _splat(builder, x, _V4)

    return _vec4(arr, types.intp), codegen


@intrinsic
def zero4(typingctx):
    """A :class:`Vec4` of four +0.0."""

    def codegen(context, builder, sig, args):
        return ir.Constant(_V4, [0.0] * 4)

    return _vec4(), codegen


@intrinsic
def muladd4(typingctx, acc, a, b):
    """``acc + a * b`` lane by lane: a multiply, then an add (no fused multiply-add, no flags)."""

    def codegen(context, builder, sig, args):
        return builder.fadd(args[0], builder.fmul(args[1], args[2]))

    return _vec4(_vec4, _vec4, _vec4), codegen


# -- Sixteen lanes: blob matching's scan (``blob/_kernels.py``) and look-ups (``blob/_walk_kernels.py``) ------
_F16 = ir.VectorType(ir.FloatType(), 16)
_I16 = ir.VectorType(ir.IntType(64), 16)
_U16 = ir.VectorType(ir.IntType(16), 16)
_LANE = ir.Constant(ir.VectorType(ir.IntType(64), 16), list(range(16)))
_I64 = ir.IntType(64)


def _splat(builder, value, vty):
    """``value`` in every lane of a vector of type ``vty``."""
    one = builder.insert_element(ir.Constant(vty, ir.Undefined), value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(one, ir.Constant(vty, ir.Undefined), ir.Constant(
        ir.VectorType(ir.IntType(32), vty.count), [0] * vty.count))


def _mask16(builder, bits):
    """A ``<16 x i1>`` as the low 16 bits of an int64 (bit q = lane q)."""
    return builder.zext(builder.bitcast(bits, ir.IntType(16)), _I64)


def _row_lanes(context, builder, aryty, ary, line, k, n):
    """Pointer to ``ary[line, k:k + n]`` of a C-contiguous 2-d array as one LLVM vector (no bounds check)."""
    arr = context.make_array(aryty)(context, builder, ary)
    row = builder.mul(line, builder.extract_value(arr.shape, 1))
    elem = context.get_value_type(aryty.dtype)
    return builder.bitcast(builder.gep(arr.data, [builder.add(row, k)]), ir.VectorType(elem, n).as_pointer())


class Vec16(types.Type):
    """Sixteen float32, int64 or uint16 lanes held as one LLVM vector (a sorted line's values and indices).
    Made and used by :func:`load16`, :func:`store16`, :func:`count16`, :func:`below16`, :func:`insert16`,
    :func:`lane16` and :func:`fill16` only (uint16 stays for numba's on-disk cache, see the module)."""

    def __init__(self, dtype):
        self.dtype = dtype
        super().__init__(name=f"Vec16{dtype}")


_vec16 = {t: Vec16(t) for t in (types.float32, types.int64, types.uint16)}


@register_model(Vec16)
class _Vec16Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, {types.float32: _F16, types.int64: _I16, types.uint16: _U16}[fe_type.dtype])


def _vec16_of(arr, name):
    _check2(arr, name, tuple(_vec16))
    return _vec16[arr.dtype]


@intrinsic
def load16(typingctx, arr, line, k):
    """``arr[line, k:k + 16]`` as a :class:`Vec16` (``k + 16 <= arr.shape[1]``)."""
    vty = _vec16_of(arr, "arr")

    def codegen(context, builder, sig, args):
        return builder.load(_row_lanes(context, builder, sig.args[0], args[0], args[1], args[2], 16), align=4)

    return vty(arr, types.intp, types.intp), codegen


@intrinsic
def store16(typingctx, arr, line, k, vec):
    """``arr[line, k:k + 16] = vec``."""
    if _vec16_of(arr, "arr") != vec:
        raise TypingError(f"vec must be a {_vec16_of(arr, 'arr')}, got {vec}")

    def codegen(context, builder, sig, args):
        builder.store(args[3], _row_lanes(context, builder, sig.args[0], args[0], args[1], args[2], 16), align=4)
        return context.get_dummy_value()

    return types.none(arr, types.intp, types.intp, vec), codegen


def _count16(vec, v, lim, op):
    if vec != _vec16[types.float32]:
        raise TypingError(f"vec must be a float32 Vec16, got {vec}")

    def codegen(context, builder, sig, args):
        hit = builder.fcmp_ordered(op, args[0], _splat(builder, args[1], _F16))
        inside = builder.icmp_signed("<", _LANE, _splat(builder, args[2], _LANE.type))
        return builder.ctpop(_mask16(builder, builder.and_(hit, inside)))

    return types.int64(vec, types.float32, types.intp), codegen


@intrinsic
def count16(typingctx, vec, v, lim):
    """How many lanes ``q < lim`` of a float32 :class:`Vec16` are ``<= v``."""
    return _count16(vec, v, lim, "<=")


@intrinsic
def below16(typingctx, vec, v, lim):
    """How many lanes ``q < lim`` of a float32 :class:`Vec16` are ``< v``."""
    return _count16(vec, v, lim, "<")


@intrinsic
def insert16(typingctx, vals, idxs, v, x):
    """Insert ``(v, x)`` into a line sorted by value (float32 :class:`Vec16` values, int64 indices), after
    equal values; the last lane drops out. Lane q keeps its entry when it is ``<= v``, takes ``(v, x)`` when
    its left neighbour is ``<= v`` (or q = 0), else its left neighbour's. Returns the two vectors."""
    if vals != _vec16[types.float32] or idxs != _vec16[types.int64]:
        raise TypingError(f"vals / idxs must be float32 / int64 Vec16, got {vals} / {idxs}")

    def codegen(context, builder, sig, args):
        left = ir.Constant(ir.VectorType(ir.IntType(32), 16), [16] + list(range(15)))
        lv, lx = args[0], args[1]
        sv, sx = _splat(builder, args[2], _F16), _splat(builder, args[3], _I16)
        prev_v = builder.shuffle_vector(lv, ir.Constant(_F16, [float("-inf")] * 16), left)
        prev_x = builder.shuffle_vector(lx, sx, left)
        keep = builder.fcmp_ordered("<=", lv, sv)
        here = builder.fcmp_ordered("<=", prev_v, sv)
        out_v = builder.select(keep, lv, builder.select(here, sv, prev_v))
        out_x = builder.select(keep, lx, builder.select(here, sx, prev_x))
        return context.make_tuple(builder, sig.return_type, [out_v, out_x])

    return types.Tuple((vals, idxs))(vals, idxs, types.float32, types.int64), codegen


@intrinsic
def lane16(typingctx, vec, q):
    """Lane ``q`` of a :class:`Vec16`."""
    if not isinstance(vec, Vec16):
        raise TypingError(f"vec must be a Vec16, got {vec}")

    def codegen(context, builder, sig, args):
        return builder.extract_element(args[0], args[1])

    return vec.dtype(vec, types.intp), codegen


def _coded_row(context, builder, aryty, ary, line, k, penty, pen):
    """``ary[line, k:k + 16] | pen[k:k + 16]`` as a ``<16 x i16>`` (no bounds check): a code, or 0xFFFF
    where ``pen`` takes the entry out."""
    row = builder.load(_row_lanes(context, builder, aryty, ary, line, k, 16), align=2)
    return builder.or_(row, builder.load(_lanes(context, builder, penty, pen, k, 16), align=2))


def _check_row_pen(arr, pen):
    _check2(arr, "arr", (types.uint16,))
    _check(pen, "pen", (types.uint16,))


@intrinsic
def band16(typingctx, arr, line, k, pen, lo, hi):
    """Bit mask (bit q) of the uint16 codes ``x = arr[line, k + q] | pen[k + q]`` with ``lo <= x <= hi``."""
    _check_row_pen(arr, pen)

    def codegen(context, builder, sig, args):
        x = _coded_row(context, builder, sig.args[0], args[0], args[1], args[2], sig.args[3], args[3])
        ok = builder.and_(builder.icmp_unsigned(">=", x, _splat(builder, args[4], _U16)),
                          builder.icmp_unsigned("<=", x, _splat(builder, args[5], _U16)))
        return _mask16(builder, ok)

    return types.int64(arr, types.intp, types.intp, pen, types.uint16, types.uint16), codegen


@intrinsic
def prefetch(typingctx, arr, line, k):
    """Prefetch the cache line of ``arr[line, k]`` (``llvm.prefetch``, a read); no effect on any result."""
    _check2(arr, "arr")

    def codegen(context, builder, sig, args):
        ptr = _row_lanes(context, builder, sig.args[0], args[0], args[1], args[2], 1)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        name = "llvm.prefetch.p0"
        fn = builder.module.globals.get(name) or ir.Function(
            builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), name=name)
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return types.none(arr, types.intp, types.intp), codegen


# -- the fused product and scan of blob matching (blob/_fused_kernels.py): the float32 product only proposes
# (within the certified bound of blob/_kernels.py), so fma16 fuses; the scan is scan_tile's, lane by lane.


@intrinsic
def fill16(typingctx, v):
    """A float32 :class:`Vec16` with ``v`` in every lane."""
    if v != types.float32:
        raise TypingError(f"v must be a float32, got {v}")

    def codegen(context, builder, sig, args):
        return _splat(builder, args[0], _F16)

    return _vec16[types.float32](types.float32), codegen


@intrinsic
def fma16(typingctx, acc, b, s):
    """``acc + b * s`` lane by lane with one rounding (``llvm.fma``) for float32 :class:`Vec16` ``acc``,
    ``b`` and a float32 ``s``."""
    if acc != _vec16[types.float32] or b != acc or s != types.float32:
        raise TypingError(f"acc / b / s must be float32 Vec16 / Vec16 / scalar, got {acc} / {b} / {s}")

    def codegen(context, builder, sig, args):
        name = "llvm.fma.v16f32"
        fn = builder.module.globals.get(name) or ir.Function(
            builder.module, ir.FunctionType(_F16, [_F16, _F16, _F16]), name=name)
        return builder.call(fn, [args[1], _splat(builder, args[2], _F16), args[0]])

    return acc(acc, b, s), codegen


@intrinsic
def row_flags(typingctx, V, r, k, g0, g1, g2, g3, a, t, n2, cthr, j0):
    """One row of a register block: ``V[r, k + 16 p + q] = v = (a + n2[j0 + 16 p + q]) - (g_p[q] + g_p[q])``
    in float32 (as ``scan_tile``); returns the bit masks (bit 16 p + q) of ``v < t`` (below the row's
    threshold) and of ``v < cthr[j0 + 16 p + q]`` (below the column's). No bounds check."""
    vec = _vec16[types.float32]
    if (g0, g1, g2, g3) != (vec,) * 4 or a != types.float32 or t != types.float32:
        raise TypingError(f"g0..g3 / a / t must be float32 Vec16 / float32 / float32, got {g0} / {a} / {t}")
    _check2(V, "V", (types.float32,))
    _check(n2, "n2", (types.float32,))
    _check(cthr, "cthr", (types.float32,))

    def codegen(context, builder, sig, args):
        V, r, k0, g, (a, t, n2, cthr, j0) = args[0], args[1], args[2], args[3:7], args[7:]
        sa, st = _splat(builder, a, _F16), _splat(builder, t, _F16)
        rows, cols = ir.Constant(_I64, 0), ir.Constant(_I64, 0)
        for p in range(4):
            k = builder.add(j0, ir.Constant(_I64, 16 * p))
            col = builder.load(_lanes(context, builder, sig.args[9], n2, k, 16), align=4)
            v = builder.fsub(builder.fadd(sa, col), builder.fadd(g[p], g[p]))
            kv = builder.add(k0, ir.Constant(_I64, 16 * p))
            builder.store(v, _row_lanes(context, builder, sig.args[0], V, r, kv, 16), align=4)
            ct = builder.load(_lanes(context, builder, sig.args[10], cthr, k, 16), align=4)
            shift = ir.Constant(_I64, 16 * p)
            rows = builder.or_(rows, builder.shl(_mask16(builder, builder.fcmp_ordered("<", v, st)), shift))
            cols = builder.or_(cols, builder.shl(_mask16(builder, builder.fcmp_ordered("<", v, ct)), shift))
        return context.make_tuple(builder, sig.return_type, [rows, cols])

    sig = types.UniTuple(types.int64, 2)(V, types.intp, types.intp, g0, g1, g2, g3, a, t, n2, cthr, types.intp)
    return sig, codegen


@intrinsic
def row_reflag(typingctx, V, r, k, t, cthr, j0):
    """Bit mask (bit q < 64) of ``V[r, k + q] < max(t, cthr[j0 + q])`` on the distances :func:`row_flags`
    stored: against a row's new threshold (``cthr`` of -inf), or the columns' (``t`` of -inf)."""
    if t != types.float32:
        raise TypingError(f"t must be a float32, got {t}")
    _check2(V, "V", (types.float32,))
    _check(cthr, "cthr", (types.float32,))

    def codegen(context, builder, sig, args):
        V, r, k0, t, cthr, j0 = args
        st = _splat(builder, t, _F16)
        mask = ir.Constant(_I64, 0)
        for p in range(4):
            v = builder.load(_row_lanes(context, builder, sig.args[0], V, r, builder.add(k0, ir.Constant(_I64, 16 * p)),
                                        16), align=4)
            ct = builder.load(_lanes(context, builder, sig.args[4], cthr, builder.add(j0, ir.Constant(_I64, 16 * p)),
                                     16), align=4)
            lim = builder.select(builder.fcmp_ordered(">", st, ct), st, ct)
            bits = _mask16(builder, builder.fcmp_ordered("<", v, lim))
            mask = builder.or_(mask, builder.shl(bits, ir.Constant(_I64, 16 * p)))
        return mask

    return types.int64(V, types.intp, types.intp, t, cthr, types.intp), codegen


@intrinsic
def row_codes(typingctx, dense, i, j0, V, r, k, qoff, qinv, top):
    """``dense[i, j0:j0 + 64]`` = the 16-bit codes of ``V[r, k:k + 64]``, as ``blob._kernels.code`` lane by lane:
    ``(v - qoff) * qinv + 0.5`` clamped to ``[0, top]`` and truncated."""
    _check2(dense, "dense", (types.uint16,))
    _check2(V, "V", (types.float32,))
    if (qoff, qinv, top) != (types.float32,) * 3:
        raise TypingError(f"qoff / qinv / top must be float32, got {qoff}, {qinv}, {top}")

    def codegen(context, builder, sig, args):
        dense, i, j0, V, r, k0, qoff, qinv, top = args
        soff, sinv, shi = _splat(builder, qoff, _F16), _splat(builder, qinv, _F16), _splat(builder, top, _F16)
        zero, half = ir.Constant(_F16, [0.0] * 16), ir.Constant(_F16, [0.5] * 16)
        for p in range(4):
            kv = builder.add(k0, ir.Constant(_I64, 16 * p))
            v = builder.load(_row_lanes(context, builder, sig.args[3], V, r, kv, 16), align=4)
            x = builder.fadd(builder.fmul(builder.fsub(v, soff), sinv), half)
            x = builder.select(builder.fcmp_ordered(">", x, zero), x, zero)
            x = builder.select(builder.fcmp_ordered("<", x, shi), x, shi)
            k = builder.add(j0, ir.Constant(_I64, 16 * p))
            builder.store(builder.fptoui(x, _U16), _row_lanes(context, builder, sig.args[0], dense, i, k, 16), align=2)
        return context.get_dummy_value()

    return types.none(dense, types.intp, types.intp, V, types.intp, types.intp, qoff, qinv, top), codegen
