"""One buffer for f = Ω's 16-bit codes of D, reused from one call of blob matching to the next.

f = Ω's greedy reads the whole of D (Sec. 3): on the L2 path the pass writes 16-bit codes of all of it
(:meth:`.context.BlobContext._scan_exact`), 2 bytes an entry, 50 MB at n = m = 5000. A fresh array each call
costs its page faults, about as much as writing the codes, and on virtual machines whose host takes freed
memory back, several times that. :func:`blob_matching` hands its buffer back when it returns
(:meth:`.context.BlobContext.release`), and the next call with at most as many entries takes it over, as a
BLAS GEMM's caller keeps its output. Only buffers of at most :data:`HOLD_BYTES` are held, one per thread;
:func:`free_workspace` drops it. The codes are rewritten in full each pass, so reuse changes no result.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["HOLD_BYTES", "free_workspace", "take_codes", "give_back"]

#: The largest codes buffer held between calls (128 MiB holds n = m = 8192; larger ones are freed).
HOLD_BYTES = 128 << 20

_held = threading.local()


def take_codes(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """An (n, m) uint16 array for the codes, and the flat buffer behind it to :func:`give_back`.

    The held buffer when it is large enough (it is no longer held: two contexts never share it), else a
    fresh one.
    """
    buf = getattr(_held, "buf", None)
    if buf is not None and buf.size >= n * m:
        _held.buf = None
    else:
        buf = np.empty(n * m, np.uint16)
    return buf[: n * m].reshape(n, m), buf


def give_back(buf: np.ndarray) -> None:
    """Hold ``buf`` (from :func:`take_codes`) for the next call, if it is small enough and larger than the
    buffer held now; the caller must not use it afterwards."""
    held = getattr(_held, "buf", None)
    if buf.nbytes <= HOLD_BYTES and (held is None or held.size < buf.size):
        _held.buf = buf


def free_workspace() -> None:
    """Drop the codes buffer this thread holds between calls of blob matching (at most :data:`HOLD_BYTES`)."""
    _held.buf = None
