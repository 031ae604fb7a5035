"""Helpers of :class:`~ctxmatch_lib.blob.context.BlobContext`'s pass over a precomputed D or a distance hook:
the T best entries of each line from row blocks of D (the L2 path has its compiled kernels instead)."""

from __future__ import annotations

import numpy as np


def _first_t(group, other, value, n_groups: int, n_other: int, T: int):
    """The T best candidate entries of every group (each holds at least T), by (value, other index), as
    ``idx`` (n_groups, T) int64 and ``val`` (n_groups, T) float64."""
    gb, ob = max(1, int(n_groups - 1).bit_length()), max(1, int(n_other - 1).bit_length())
    if value.dtype == np.float32 and gb + ob <= 32:
        # One int64 sort: the bits of a non-negative float32 are monotone in its value (31 bits).
        bits = (np.maximum(value, 0) + np.float32(0)).view(np.uint32).astype(np.int64)
        key = np.sort((group.astype(np.int64) << (31 + ob)) | (bits << ob) | other)
        g, o = key >> (31 + ob), key & ((1 << ob) - 1)
        v = ((key >> ob) & 0x7FFFFFFF).astype(np.uint32).view(np.float32)
    else:
        order = np.lexsort((other, value, group))
        g, o, v = group[order], other[order], value[order]
    starts = np.searchsorted(g, np.arange(n_groups))
    pos = np.arange(len(g)) - starts[g]
    keep = pos < T
    idx = np.empty((n_groups, T), np.int64)
    val = np.empty((n_groups, T), np.float64)
    idx[g[keep], pos[keep]] = o[keep]
    val[g[keep], pos[keep]] = np.maximum(v[keep].astype(np.float64), 0)
    return idx, val


def _group_size(size: int, T: int) -> int:
    return int(np.clip(size // (8 * T), 1, 16))


def _row_thresholds(block: np.ndarray, T: int, G: int) -> np.ndarray:
    """Per-row value ``tau`` with at least ``T`` entries ``<= tau``: the T-th smallest minimum of interleaved
    column groups of ``G`` (T groups have an entry at or below it)."""
    B, m = block.shape
    if T >= m:
        return np.full(B, np.inf)
    mg = (m // G) * G
    gmin = block[:, :mg].reshape(B, G, mg // G).min(axis=1) if G > 1 else block
    if G > 1 and mg < m:
        gmin = np.hstack([gmin, block[:, mg:]])
    return np.partition(gmin, T - 1, axis=1)[:, T - 1]


def _column_group_minima(block: np.ndarray, G: int) -> np.ndarray:
    B = block.shape[0]
    bg = (B // G) * G
    parts = [block[:bg].reshape(bg // G, G, -1).min(axis=1)] if bg else []
    if bg < B:
        parts.append(block[bg:])
    return np.vstack(parts)
