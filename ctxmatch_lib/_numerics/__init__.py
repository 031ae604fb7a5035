"""The numerics every method shares, private to the package.

* :mod:`.fixedmath`, :mod:`.fixedmath_kernels`, :mod:`.fdlibm`: elementary functions with the same bits on
  every CPU;
* :mod:`.simd`: numba vector intrinsics with a fixed summation order; :mod:`.blas`: BLAS on one thread;
* :mod:`.jit`: numba's cache folder; :mod:`.ranking`: the compiled area under a ranking (AP);
* :mod:`.validation`: argument checks naming the argument; :mod:`.scores`: NNR scores that know their scale;
* :mod:`.order`: the order filters decide in; :mod:`.docstrings`: shared parameter texts.

Nothing here imports the rest of the library but :mod:`ctxmatch_lib.cache`.
"""
