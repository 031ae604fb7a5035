"""``th``: the NNR ratio threshold 0.8 (Lowe) on the blob score, the paper's reference (Sec. 5.1), read on
the scores' scale (D+ and D+≥ scores, Eq. 14, are ``r / (1 + r)``: 0.8 / 1.8)."""

from __future__ import annotations

import numpy as np

from ._common import MatchSet, match_filter

__all__ = ["th_filter"]


@match_filter(label="th", nnr=("threshold",), ratio_param="ratio", scores_required=True)
def th_filter(ms: MatchSet, *, threshold: float = 0.8) -> np.ndarray:
    """Keep the matches whose score is at most ``threshold``.

    %(parameters)s
    scores : ndarray of shape (K,) or None
        NNR-like scores, lower is better. ``None`` means all equal (every match is kept).
        %(nnr_scale)s
    %(image_sizes)s
    %(shapes_unused)s
    threshold : float, default 0.8
        The NNR ratio threshold of Lowe (IJCV 2004, Sec. 7.1), "th" in Sec. 5.1 of the paper.
    ratio : {"D>=", "D+>=", "D+"}, optional
        The blob ratio that made ``scores``; default: the one they carry, else ``"D>="`` (a contradiction
        is a ``ValueError``).

    Returns
    -------
    %(keep)s

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
    return ms.scores <= threshold

