"""Helpers of :class:`~ctxmatch_lib.blob.context.BlobContext`'s look-ups beyond the sorted lists on the L2 path:
whole lines of D as coded float32 approximations, computed in chunks and kept for the next ask."""

from __future__ import annotations

import numpy as np

from .._numerics.blas import one_blas_thread
from . import _kernels

_MiB = 1 << 20

#: The most memory per side that :class:`LineMemo` keeps computed lines in (2 bytes an entry).
LINE_MEMO_BYTES = 32 * _MiB


def coded_lines(own: np.ndarray, other: np.ndarray, n_own: np.ndarray, n_other: np.ndarray, which: np.ndarray,
                qoff, qinv) -> np.ndarray:
    """Codes (:func:`._kernels.encode`) of ``|a|² + |b|² − 2 a·b`` from the float32 rows ``own[which]`` to
    every row of ``other``, about 8 MiB of float32 at a time on one BLAS thread."""
    out, step = np.empty((len(which), len(other)), np.uint16), max(1, (8 * _MiB) // (4 * len(other)))
    for s in range(0, len(which), step):
        w = which[s : s + step]
        with one_blas_thread():
            g = own[w] @ other.T
        g *= np.float32(-2)
        g += n_own[w][:, None]
        out[s : s + step] = _kernels.encode(g + n_other[None, :], qoff, qinv)
    return out


class LineMemo:
    """The lines of one side computed so far (up to :data:`LINE_MEMO_BYTES`): :meth:`get` computes the
    missing ones and returns copies, so a sweep computes each line once."""

    def __init__(self, n_lines: int, line_len: int):
        self.keep = n_lines * line_len * 2 <= LINE_MEMO_BYTES
        self._shape = (n_lines, line_len)
        self._codes = self._have = None

    def get(self, which: np.ndarray, compute) -> np.ndarray:
        which = np.asarray(which, np.int64)
        if not self.keep:
            return compute(which)
        if self._codes is None:
            self._codes, self._have = np.empty(self._shape, np.uint16), np.zeros(self._shape[0], bool)
        need = np.unique(which[~self._have[which]])
        if len(need):
            self._codes[need] = compute(need)
            self._have[need] = True
        return self._codes[which]
