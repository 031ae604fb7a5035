"""The order a filter decides its candidate rows in: one that depends only on the set of rows, never on the
order they were given in, and the way back to the input order."""

from __future__ import annotations

import numpy as np

__all__ = ["canonical_order", "spread_back"]


def canonical_order(x, y, matches, scores) -> tuple[np.ndarray, np.ndarray | None]:
    """The order of candidate rows a filter decides in, which depends only on the set of rows.

    The rows are sorted (``np.lexsort``, in float64) by score, image-1 keypoint (x, y), image-2 keypoint
    (x, y), then the two keypoint indices. Rows equal in every key are one candidate given twice; their
    relative order is all that is left to the input, and :func:`spread_back` gives them one decision.

    Parameters
    ----------
    x, y : ndarray of shape (K, 2)
        Image-1 and image-2 keypoint of each row, (x, y) pixels.
    matches : ndarray of shape (K, 2)
        Keypoint indices of each row.
    scores : ndarray of shape (K,)
        Score of each row (lower is better; zeros when none were given).

    Returns
    -------
    order : ndarray of shape (K,) int64
        The rows in canonical order: row ``order[j]`` of the input is row ``j`` of the sorted set.
    twins : ndarray of shape (K,) int64, or None
        None when no two rows are equal in every key; else the group of each *sorted* row, numbered
        ``0, 1, ...`` in order, equal rows sharing a group.

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
    """The decisions ``keep`` made on the rows in canonical order (:func:`canonical_order`), in input order.

    Rows equal in every key (``twins``) are one candidate: all are kept when any is (a one-to-one core keeps
    one copy), so the mask never depends on the input order.
    """
    keep = np.asarray(keep, bool)
    if twins is not None:
        keep = (np.bincount(twins, weights=keep) > 0)[twins]
    out = np.empty(len(order), bool)
    out[order] = keep
    return out
