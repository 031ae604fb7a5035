"""The order a filter decides its candidate rows in: one that depends only on the set of rows, never on the
order they were given in, and the way back to the input order."""

from __future__ import annotations

import numpy as np

__all__ = ["canonical_order", "spread_back"]


def canonical_order(x, y, matches, scores) -> tuple[np.ndarray, np.ndarray | None]:
    """Rows sorted by score, image-1 (x, y), image-2 (x, y), then the keypoint indices (float64 lexsort).

    Parameters
    ----------
    x, y : ndarray of shape (K, 2)
        Image-1 and image-2 keypoint of each row.
    matches : ndarray of shape (K, 2)
    scores : ndarray of shape (K,)

    Returns
    -------
    order : ndarray of shape (K,) int64
        Row ``order[j]`` of the input is row ``j`` of the sorted set.
    twins : ndarray of shape (K,) int64, or None
        Group of each sorted row, rows equal in every key sharing one; None when there are none.

    Examples
    --------
    >>> x = np.array([[5.0, 5.0], [1.0, 2.0], [5.0, 5.0]])
    >>> m = np.array([[2, 0], [1, 1], [2, 0]])
    >>> order, twins = canonical_order(x, x, m, np.array([0.5, 0.5, 0.5]))
    >>> order.tolist(), twins.tolist()
    ([1, 0, 2], [0, 1, 1])
    """
    n = len(matches)
    keys = np.empty((7, n), np.float64)
    keys[0] = scores
    keys[1:3] = np.asarray(x, np.float64).T
    keys[3:5] = np.asarray(y, np.float64).T
    keys[5:7] = np.asarray(matches).T
    order = np.lexsort(keys[::-1])  # the last key is the primary one
    if n < 2:
        return order, None
    k = keys[:, order]
    same = (k[:, 1:] == k[:, :-1]).all(axis=0)
    if not same.any():
        return order, None
    return order, np.r_[0, np.cumsum(~same)]


def spread_back(keep: np.ndarray, order: np.ndarray, twins: np.ndarray | None) -> np.ndarray:
    """The decisions ``keep`` made in canonical order, in input order; twins are all kept when any is."""
    keep = np.asarray(keep, bool)
    if twins is not None:
        keep = (np.bincount(twins, weights=keep) > 0)[twins]
    out = np.empty(len(order), bool)
    out[order] = keep
    return out
