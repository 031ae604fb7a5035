"""fdlibm's ``exp`` constants, shared by :mod:`ctxmatch_lib._numerics.fixedmath` (the ufunc form) and
:mod:`ctxmatch_lib._numerics.fixedmath_kernels` (the compiled loop), so that neither module imports the other's."""

# ln 2 in two parts (n * _LN2HI exact for |n| < 2^11), 1 / ln 2, and the remez coefficients.
_LN2HI = 6.93147180369123816490e-01
_LN2LO = 1.90821492927058770002e-10
_INVLN2 = 1.44269504088896338700e+00
_P = (1.66666666666666019037e-01, -2.77777777770155933842e-03, 6.61375632143793436117e-05,
      -1.65339022054652515390e-06, 4.13813679705723846039e-08)
