"""The numerics every method shares, private to the package.

:mod:`.fixedmath` (elementary functions with the same bits on every CPU), :mod:`.simd` (numba vector
intrinsics), :mod:`.blas`, :mod:`.jit`, :mod:`.ranking`, :mod:`.validation`, :mod:`.scores`, :mod:`.order`,
:mod:`.docstrings`, :mod:`.extras` (optional imports that name their extra). Nothing here imports the rest
of the library but :mod:`ctxmatch_lib.cache`.
"""
