"""Elementary functions whose bits do not depend on the CPU: ``exp``, ``log``, ``tanh``, ``sin``/``cos``, ``atan2``,
``acos``, ``cbrt``, ``power``.

numpy's transcendental ufuncs dispatch by CPU and differ in the last bit; these use fdlibm's algorithms (as
in musl, error below 1 ulp) with only correctly rounded IEEE operations, one ufunc per operation (``exp`` and
``tanh`` in a compiled loop, :mod:`.fixedmath_kernels`), so no multiply-add is fused. Inputs are float64.
:func:`opencv_baseline` pins OpenCV, which dispatches too.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager

import numpy as np

# fdlibm's exp constants, shared with the compiled loop (fixedmath_kernels) that exp and tanh call.
from .fdlibm import _INVLN2, _LN2HI, _LN2LO, _P

__all__ = ["acos", "atan", "atan2", "cbrt", "cos", "exp", "floor_log2", "hypot", "log", "opencv_baseline", "power",
           "sin", "sincos", "tanh"]

_CV_LOCK = threading.Lock()
_CV_USERS = [0, True, 1]  # blocks inside opencv_baseline; the settings to restore when the last one leaves


@contextmanager
def opencv_baseline():
    """Run the block with OpenCV on its baseline code and one thread (dispatched builds and IPP move SIFT's
    last bits). The global settings are shared by concurrent blocks and restored by the last one to leave; IPP
    is switched per thread (OpenCV keeps that switch in thread-local storage), so every thread inside the block
    runs without it."""
    import cv2

    ipp = cv2.ipp.useIPP()
    with _CV_LOCK:
        if _CV_USERS[0] == 0:
            _CV_USERS[1:] = [cv2.useOptimized(), cv2.getNumThreads()]
            cv2.setUseOptimized(False)
            cv2.setNumThreads(1)
        _CV_USERS[0] += 1
    cv2.ipp.setUseIPP(False)
    try:
        yield
    finally:
        with _CV_LOCK:
            _CV_USERS[0] -= 1
            if _CV_USERS[0] == 0:
                cv2.setUseOptimized(_CV_USERS[1])
                cv2.setNumThreads(_CV_USERS[2])
            cv2.ipp.setUseIPP(ipp)

# fdlibm's __kernel_sin / __kernel_cos minimax coefficients on [-pi/4, pi/4].
_S = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
      2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_C = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
      -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)
# pi/2 in two parts (the first has 33 bits, so n * _PIO2_1 is exact for |n| < 2^20).
_INVPIO2 = 6.36619772367581382433e-01
_PIO2_1 = 1.57079632673412561417e+00
_PIO2_1T = 6.07710050650619224932e-11
# fdlibm's atan: breakpoints atan(0.5), atan(1), atan(1.5), atan(inf) in two parts, and its coefficients.
_ATANHI = np.array([4.63647609000806093515e-01, 7.85398163397448278999e-01, 9.82793723247329054082e-01,
                    1.57079632679489655800e+00])
_ATANLO = np.array([2.26987774529616870924e-17, 3.06161699786838301793e-17, 1.39033110312309984516e-17,
                    6.12323399573676603587e-17])
_AT = (3.33333333333329318027e-01, -1.99999999998764832476e-01, 1.42857142725034663711e-01,
       -1.11111104054623557880e-01, 9.09088713343650656196e-02, -7.69187620504482999495e-02,
       6.66107313738753120669e-02, -5.83357013379057348645e-02, 4.97687799461593236017e-02,
       -3.65315727442169155270e-02, 1.62858201153657823623e-02)
_PI = 3.1415926535897931160e+00
_PI_LO = 1.2246467991473531772e-16
# fdlibm's log: the remez coefficients of (log(1 + s) - log(1 - s) - 2 s) / s on [0, 0.1716], and the
# reduction bound: the double whose high word is 0x3fe6a09e (just below sqrt(2) / 2), as fdlibm tests it.
_LG = (6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01, 2.222219843214978396e-01,
       1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01)
_SQRT_HALF_HI = float(np.array(0x3FE6A09E << 32, np.uint64).view(np.float64))


def _f64(x) -> np.ndarray:
    return np.asarray(x, np.float64)


def _horner(z: np.ndarray, coefs) -> np.ndarray:
    """``c0 + z (c1 + z (c2 + …))`` with one rounding per operation."""
    acc = np.full_like(z, coefs[-1])
    for c in coefs[-2::-1]:
        acc = acc * z + c
    return acc


def _kernel_sin(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """sin(x + y) for |x + y| <= pi/4, y the tail of the reduced argument (fdlibm's ``__kernel_sin``)."""
    z = x * x
    v = z * x
    r = _horner(z, _S[1:])
    return x - ((z * (0.5 * y - v * r) - y) - v * _S[0])


def _kernel_cos(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """cos(x + y) for |x + y| <= pi/4 (fdlibm's ``__kernel_cos``, as in musl)."""
    z = x * x
    r = z * _horner(z, _C)
    hz = 0.5 * z
    w = 1.0 - hz
    return w + (((1.0 - w) - hz) + (z * r - x * y))


def sincos(x) -> tuple[np.ndarray, np.ndarray]:
    """``(sin x, cos x)`` in radians, the same bits on any CPU; Cody-Waite reduction, for ``|x| < 2**20``.

    Examples
    --------
    >>> s, c = sincos([0.0, np.pi / 6, np.pi])
    >>> np.round(s, 12).tolist(), np.round(c, 12).tolist()
    ([0.0, 0.5, 0.0], [1.0, 0.866025403784, -1.0])
    """
    x = _f64(x)
    n = np.rint(x * _INVPIO2)
    r = x - n * _PIO2_1
    w = n * _PIO2_1T
    y0 = r - w
    y1 = (r - y0) - w
    s, c = _kernel_sin(y0, y1), _kernel_cos(y0, y1)
    q = np.mod(n, 4)  # exact: n is an integer
    sin = np.where(q == 0, s, np.where(q == 1, c, np.where(q == 2, -s, -c)))
    cos = np.where(q == 0, c, np.where(q == 1, -s, np.where(q == 2, -c, s)))
    return sin, cos


def sin(x) -> np.ndarray:
    """``sin x`` (float64, radians), the same bits on any CPU: see :func:`sincos`."""
    return sincos(x)[0]


def cos(x) -> np.ndarray:
    """``cos x`` (float64, radians), the same bits on any CPU: see :func:`sincos`."""
    return sincos(x)[1]


def _atan_pos(x: np.ndarray) -> np.ndarray:
    """``atan x`` for ``x >= 0`` (fdlibm's ``atan``: four reduction intervals and one polynomial)."""
    big = x >= 2.0 ** 66
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        idx = np.select([x < 7 / 16, x < 11 / 16, x < 19 / 16, x < 39 / 16], [-1, 0, 1, 2], 3)
        t = np.select([idx == 0, idx == 1, idx == 2, idx == 3],
                      [(2.0 * x - 1.0) / (2.0 + x), (x - 1.0) / (x + 1.0), (x - 1.5) / (1.0 + 1.5 * x), -1.0 / x],
                      x)
    z = t * t
    w = z * z
    s1 = z * _horner(w, _AT[0::2])
    s2 = w * _horner(w, _AT[1::2])
    k = np.maximum(idx, 0)
    near = t - t * (s1 + s2)
    far = _ATANHI[k] - ((t * (s1 + s2) - _ATANLO[k]) - t)
    return np.where(big, _ATANHI[3] + _ATANLO[3], np.where(idx < 0, near, far))


def atan(x) -> np.ndarray:
    """``atan x``, the same bits on any CPU (fdlibm's ``atan``).

    Examples
    --------
    >>> np.round(atan([0.0, 1.0, -np.sqrt(3.0), np.inf]) / np.pi, 12).tolist()
    [0.0, 0.25, -0.333333333333, 0.5]
    """
    x = _f64(x)
    a = np.abs(x)
    with np.errstate(invalid="ignore"):
        out = np.copysign(_atan_pos(np.where(np.isnan(a), 0.0, a)), x)
    return np.where(np.isnan(x), np.nan, out)


def atan2(y, x) -> np.ndarray:
    """The angle of ``(x, y)`` in ``[-pi, pi]``, the same bits on any CPU (fdlibm's ``atan2``, signed zeros as in C).

    Examples
    --------
    >>> np.round(atan2([1.0, 1.0, -1.0, 0.0], [1.0, -1.0, -1.0, -2.0]) / np.pi, 12).tolist()
    [0.25, 0.75, -0.75, 1.0]
    """
    y, x = np.broadcast_arrays(_f64(y), _f64(x))
    ay, ax = np.abs(y), np.abs(x)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        ratio = ay / ax
    # |y| > 2^64 |x| (x = 0 included): pi/2; x < 0 and |y| < 2^-64 |x|: the angle of -1 alone.
    steep = (ax == 0) | (ratio > 2.0 ** 64)
    flat_neg = np.signbit(x) & (ratio < 2.0 ** -64)
    z = np.where(steep | flat_neg | (ay == 0), 0.0, _atan_pos(np.where(np.isfinite(ratio), ratio, 0.0)))
    neg_x = np.signbit(x)
    out = np.where(neg_x, _PI - (z - _PI_LO), z)
    out = np.where(steep & (ay > 0), _ATANHI[3] + _ATANLO[3], out)
    out = np.where((ay == 0) & ~neg_x, 0.0, out)
    return np.where(np.isnan(x) | np.isnan(y), np.nan, np.copysign(out, y))


def acos(x) -> np.ndarray:
    """``arccos x`` in ``[0, pi]`` for ``x`` in ``[-1, 1]`` (NaN outside), the same bits on any CPU:
    ``atan2(sqrt((1 - x)(1 + x)), x)``, within two units in the last place.

    Examples
    --------
    >>> np.round(acos([1.0, 0.5, 0.0, -1.0]) / np.pi, 12).tolist()
    [0.0, 0.333333333333, 0.5, 1.0]
    """
    x = _f64(x)
    with np.errstate(invalid="ignore"):
        return np.where(np.abs(x) <= 1.0, atan2(np.sqrt((1.0 - x) * (1.0 + x)), x), np.nan)


def cbrt(x) -> np.ndarray:
    """Cube root, the same bits on any CPU: ``exp(log|x| / 3)`` and one Newton step, the sign of ``x``.

    Examples
    --------
    >>> np.round(cbrt([27.0, -8.0, 0.0, 0.001]), 12).tolist()
    [3.0, -2.0, 0.0, 0.1]
    """
    x = _f64(x)
    a = np.abs(x)
    pos = np.isfinite(a) & (a > 0)
    y = exp(log(np.where(pos, a, 1.0)) / 3.0)
    y = y - (y * y * y - np.where(pos, a, 1.0)) / (3.0 * y * y)
    return np.copysign(np.where(pos, y, a), x)


def power(x, p: float) -> np.ndarray:
    """``x ** p`` for ``x >= 0`` (float64), the same bits on any CPU: ``exp(p log x)``, exact at ``x = 0`` and 1.

    numpy's ``**`` with an exponent other than 2, 0.5, 1, 0 or -1 runs the ``power`` ufunc, whose AVX-512 loop
    rounds differently from its baseline loop (and whose float32 loop is not correctly rounded).

    Examples
    --------
    >>> np.round(power([0.0, 0.25, 1.0, 4.0], 1.5), 12).tolist()
    [0.0, 0.125, 1.0, 8.0]
    """
    x = _f64(x)
    p = float(p)
    if p <= 0:
        raise ValueError(f"p must be positive, got {p}")
    pos = x > 0
    out = exp(p * log(np.where(pos, x, 1.0)))
    return np.where(pos, out, np.where(x == 0, 0.0, np.nan))


def exp(x) -> np.ndarray:
    """``e ** x``, the same bits on any CPU (fdlibm's ``exp``), compiled; :func:`_exp_ufuncs` is the reference.

    Examples
    --------
    >>> np.round(exp([0.0, 1.0, -2.0]), 12).tolist()
    [1.0, 2.718281828459, 0.135335283237]
    """
    from .fixedmath_kernels import exp as compiled

    return compiled(x)


def _exp_ufuncs(x) -> np.ndarray:
    """:func:`exp` computed one numpy ufunc per operation (the reference of the compiled loop)."""
    x = _f64(x)
    with np.errstate(over="ignore", invalid="ignore"):
        k = np.rint(np.clip(x, -1100.0, 1100.0) * _INVLN2)
        hi = x - k * _LN2HI
        lo = k * _LN2LO
        r = hi - lo
        rr = r * r
        c = r - rr * _horner(rr, _P)
        y = 1.0 + ((r * c) / (2.0 - c) - lo + hi)
        # ldexp in two steps so that 2 ** k never over- or underflows on its own (k spans -1587..1587).
        half = np.trunc(k / 2)
        out = np.ldexp(np.ldexp(y, half.astype(np.int64)), (k - half).astype(np.int64))
    return np.where(x > 709.782712893384, np.inf, np.where(x < -745.1332191019412, 0.0, out))


def log(x) -> np.ndarray:
    """Natural logarithm, the same bits on any CPU (fdlibm's ``log``); NaN for negative inputs.

    Examples
    --------
    >>> np.round(log([1.0, np.e, 0.5, 1e-300]), 12).tolist()
    [0.0, 1.0, -0.69314718056, -690.775527898214]
    >>> log([0.0, np.inf, -1.0]).tolist()
    [-inf, inf, nan]
    """
    x = _f64(x)
    pos = np.isfinite(x) & (x > 0)
    m, e = np.frexp(np.where(pos, x, 1.0))  # x = m 2^e, 0.5 <= m < 1, exact (subnormals too)
    low = m < _SQRT_HALF_HI
    y = np.where(low, 2.0 * m, m)
    k = (e - low).astype(np.float64)
    f = y - 1.0
    hfsq = 0.5 * f * f
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * _horner(w, _LG[1::2])
    t2 = z * _horner(w, _LG[0::2])
    r = t2 + t1
    out = s * (hfsq + r) + k * _LN2LO - hfsq + f + k * _LN2HI
    special = np.where(x == 0, -np.inf, np.where(x == np.inf, np.inf, np.nan))
    return np.where(pos, out, special)


def tanh(x) -> np.ndarray:
    """``tanh x``, the same bits on any CPU: ``(1 - e) / (1 + e)``, ``e = exp(-2|x|)``, Taylor near zero.

    Examples
    --------
    >>> np.round(tanh([-1.0, 0.0, 0.5, 30.0]), 12).tolist()
    [-0.761594155956, 0.0, 0.46211715726, 1.0]
    """
    from .fixedmath_kernels import tanh as compiled

    return compiled(x)


def _tanh_ufuncs(x) -> np.ndarray:
    """:func:`tanh` computed one numpy ufunc per operation (the reference of the compiled loop)."""
    x = _f64(x)
    a = np.abs(x)
    e = _exp_ufuncs(-2.0 * np.minimum(a, 40.0))
    big = (1.0 - e) / (1.0 + e)
    z = a * a
    # tanh a = a - a^3/3 + 2a^5/15 - 17a^7/315 + 62a^9/2835: below 2^-5 the next term is under 2^-57 a.
    small = a + a * (z * (-1 / 3 + z * (2 / 15 + z * (-17 / 315 + z * (62 / 2835)))))
    return np.copysign(np.where(a < 2.0 ** -5, small, big), x)


def hypot(x, y) -> np.ndarray:
    """``sqrt(x² + y²)``, each step correctly rounded, unscaled (``np.hypot`` may follow the CPU)."""
    x, y = _f64(x), _f64(y)
    return np.sqrt(x * x + y * y)


def floor_log2(x) -> np.ndarray:
    """``floor(log2 x)`` of positive floats, exactly (from the binary exponent), as int64.

    Examples
    --------
    >>> floor_log2([0.75, 1.0, 3.999, 4.0]).tolist()
    [-1, 0, 1, 2]
    """
    _, e = np.frexp(_f64(x))  # x = m 2^e with 0.5 <= m < 1
    return e.astype(np.int64) - 1
