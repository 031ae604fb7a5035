"""One BLAS thread around the float32 products whose rounding must not depend on the thread count."""

from __future__ import annotations

from threadpoolctl import ThreadpoolController

_controller: ThreadpoolController | None = None


def one_blas_thread():
    """Context manager limiting every thread pool (BLAS, OpenMP) to one thread, as
    ``threadpoolctl.threadpool_limits(1)`` does, through one controller made at the first call.

    A new controller inspects every loaded library: 1-2 ms per call with OpenCV, numba and SciPy loaded,
    paid by every blob matching call before. Libraries loaded after the first call are not limited;
    numpy's BLAS, the one the GEMM tiles run on, is loaded with numpy.
    """
    global _controller
    if _controller is None:
        _controller = ThreadpoolController()
    return _controller.limit(limits=1)
