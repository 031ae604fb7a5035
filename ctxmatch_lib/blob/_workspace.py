"""One buffer for f = Ω's 16-bit codes of D, reused from one call of blob matching to the next.

A fresh array each call costs page faults about as large as writing the codes; at most :data:`HOLD_BYTES`
are held, one buffer per thread (:func:`free_workspace` drops it). Codes are rewritten in full each pass.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["HOLD_BYTES", "free_workspace", "take_codes", "give_back"]

#: The largest codes buffer held between calls (128 MiB holds n = m = 8192; larger ones are freed).
HOLD_BYTES = 128 << 20

_held = threading.local()


def take_codes(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """An (n, m) uint16 array for the codes and the flat buffer behind it (:func:`give_back`): the held
    buffer, no longer held, when large enough, else a fresh one."""
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
