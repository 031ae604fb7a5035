"""The matchers a user would pick instead of blob matching + a filter: OpenCV's brute-force matcher.

:func:`opencv_ratio_matches` (Lowe's ratio test) and :func:`opencv_mnn_matches` (mutual nearest
neighbours), float32 L2 as a user calls them; rows sorted by (score, row, column).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["LOWE_RATIO", "OPENCV_MATCHERS", "opencv_ratio_matches", "opencv_mnn_matches"]

#: Lowe's ratio (Lowe 2004, Sec. 7.1).
LOWE_RATIO = 0.8


def _descriptors(desc1, desc2) -> tuple[np.ndarray, np.ndarray]:
    d1 = np.ascontiguousarray(np.asarray(desc1), dtype=np.float32)
    d2 = np.ascontiguousarray(np.asarray(desc2), dtype=np.float32)
    for name, d in (("desc1", d1), ("desc2", d2)):
        if d.ndim != 2:
            raise ValueError(f"{name} must have shape (N, D), got {d.shape}")
    if d1.shape[1] != d2.shape[1]:
        raise ValueError(f"desc1 and desc2 must have the same dimension, got {d1.shape[1]} and {d2.shape[1]}")
    return d1, d2


def _sorted(rows, cols, scores) -> tuple[np.ndarray, np.ndarray]:
    matches = np.c_[np.asarray(rows, np.int64), np.asarray(cols, np.int64)].reshape(-1, 2)
    scores = np.asarray(scores, np.float64).reshape(-1)
    order = np.lexsort((matches[:, 1], matches[:, 0], scores))
    return matches[order], scores[order]


def _empty() -> tuple[np.ndarray, np.ndarray]:
    return np.empty((0, 2), np.int64), np.empty(0)


def opencv_ratio_matches(desc1, desc2, *, ratio: float = LOWE_RATIO) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.BFMatcher(cv2.NORM_L2).knnMatch(k=2)`` with Lowe's test ``d1 < ratio d2`` (Lowe 2004, Sec. 7.1).

    Parameters
    ----------
    desc1, desc2 : array_like of shape (N, D), (M, D)
    ratio : float

    Returns
    -------
    matches : ndarray of shape (K, 2), int64
    scores : ndarray of shape (K,)
        ``d1 / d2``.

    Examples
    --------
    >>> import numpy as np
    >>> d1 = np.array([[0.0, 0.0], [5.0, 5.0]])
    >>> d2 = np.array([[0.0, 0.1], [5.0, 4.0], [5.0, 5.9]])
    >>> opencv_ratio_matches(d1, d2)[0]
    array([[0, 0]])
    """
    if not 0 < ratio <= 1:
        raise ValueError(f"ratio must lie in (0, 1], got {ratio!r}")
    d1, d2 = _descriptors(desc1, desc2)
    if len(d1) == 0 or len(d2) < 2:
        return _empty()
    import cv2

    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(d1, d2, k=2)
    rows, cols, scores = [], [], []
    for pair in knn:
        if len(pair) < 2:
            continue
        a, b = pair
        if a.distance < ratio * b.distance:
            rows.append(a.queryIdx)
            cols.append(a.trainIdx)
            scores.append(a.distance / b.distance if b.distance > 0 else 0.0)
    return _sorted(rows, cols, scores)


def opencv_mnn_matches(desc1, desc2) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours (``BFMatcher(NORM_L2, crossCheck=True)``): ``(matches, distances)``.

    Examples
    --------
    >>> import numpy as np
    >>> matches, scores = opencv_mnn_matches([[0.0, 0.0], [1.0, 0.0]], [[0.2, 0.0], [5.0, 5.0]])
    >>> matches, scores.round(2)
    (array([[0, 0]]), array([0.2]))
    """
    d1, d2 = _descriptors(desc1, desc2)
    if len(d1) == 0 or len(d2) == 0:
        return _empty()
    import cv2

    found = cv2.BFMatcher(cv2.NORM_L2, crossCheck=True).match(d1, d2)
    return _sorted([m.queryIdx for m in found], [m.trainIdx for m in found], [m.distance for m in found])


#: Method name -> matcher ``(desc1, desc2) -> (matches, scores)``: the rows of these methods in the tables.
OPENCV_MATCHERS: dict[str, Callable] = {"opencv_ratio": opencv_ratio_matches, "opencv_mnn": opencv_mnn_matches}
