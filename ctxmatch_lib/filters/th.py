"""``th``: the plain NNR-like threshold on the blob score, the paper's reference "filter".

Not a spatial filter: it keeps a match when its NNR ratio is at most 0.8, the classical ratio threshold of
Lowe. It is listed next to the spatial filters in Sec. 5.1 of the paper. Blob scores made with D+ or D+≥
(Eq. 14) live on another scale, ``r / (1 + r)`` for an NNR ratio ``r``; pass ``ratio`` so that the same
0.8 NNR threshold is applied to them (0.8 / 1.8 on their scale).
"""

from __future__ import annotations

import numpy as np

from ._common import check_positive, prepare

__all__ = ["th_filter"]


def th_filter(
    kpts1,
    kpts2,
    matches,
    scores,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    threshold: float = 0.8,
    ratio: str = "D>=",
) -> np.ndarray:
    """Keep the matches whose score is at most ``threshold``.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel (unused here).
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many allowed.
    scores : ndarray of shape (K,) or None
        NNR-like scores, lower is better. ``None`` means all equal (every match is kept).
    image_size1, image_size2 : (int, int)
        Image sizes (width, height), validated but unused.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    threshold : float, default 0.8
        The NNR ratio threshold of Lowe (IJCV 2004, Sec. 7.1), "th" in Sec. 5.1 of the paper.
    ratio : {"D>=", "D+>=", "D+"}, default "D>="
        The blob ratio that produced ``scores``. For ``"D+"`` and ``"D+>="`` (scores ``r / (1 + r)``) the
        threshold is mapped to ``threshold / (1 + threshold)``, the same NNR ratio on their scale.

    Returns
    -------
    keep : ndarray of shape (K,), bool

    References
    ----------
    D. G. Lowe, "Distinctive image features from scale-invariant keypoints", IJCV 60(2), 2004, Sec. 7.1.
    F. Bellavia, "SIFT Matching by Context Exposed", TPAMI 2022, Sec. 5.1 ("th").

    Examples
    --------
    >>> import numpy as np
    >>> k = np.zeros((3, 2))
    >>> th_filter(k, k, [[0, 0], [1, 1], [2, 2]], [0.5, 0.8, 0.9], image_size1=(8, 8), image_size2=(8, 8))
    array([ True,  True, False])
    >>> th_filter(k, k, [[0, 0], [1, 1], [2, 2]], [0.4, 0.45, 0.5], image_size1=(8, 8), image_size2=(8, 8),
    ...           ratio="D+")
    array([ True, False, False])
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    threshold = check_positive(threshold, "threshold")
    if ratio not in ("D>=", "D+>=", "D+"):
        raise ValueError(f"ratio must be one of 'D>=', 'D+>=', 'D+', got {ratio!r}")
    if ratio != "D>=":
        threshold = threshold / (1.0 + threshold)
    return ms.scores <= threshold


th_filter.uses_blob_ratio = True  # the pipeline passes the blob setup's ratio (see pipeline.run_filter)
