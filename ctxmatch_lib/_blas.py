"""One BLAS thread around the float32 products whose rounding must not depend on the thread count."""

from __future__ import annotations

import sys

from threadpoolctl import ThreadpoolController

_controller: ThreadpoolController | None = None
_modules = -1  # len(sys.modules) when the controller was made


def one_blas_thread():
    """Context manager limiting every thread pool (BLAS, OpenMP) to one thread, as
    ``threadpoolctl.threadpool_limits(1)`` does, through a controller kept between calls.

    A new controller inspects every loaded library: 1-2 ms per call with OpenCV, numba and SciPy loaded, paid
    by every blob matching call before. It is made again when modules have been imported since (a library
    such as torch brings its own thread pools), so the limit covers what the process has loaded.
    """
    global _controller, _modules
    if _controller is None or len(sys.modules) != _modules:
        _controller = ThreadpoolController()
        _modules = len(sys.modules)
    return _controller.limit(limits=1)
