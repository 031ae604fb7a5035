"""Match scores that carry the scale of the ratio that made them (used by ``blob`` and ``filters``).

With ``"D>="`` the scores (Sec. 3, Eq. 14) are the NNR ratio ``r``, with ``"D+>="`` / ``"D+"`` ``r / (1 + r)``;
:class:`NNRScores` carries its ``ratio`` so that a filter maps its NNR thresholds (:func:`nnr_threshold`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["RATIOS", "NNRScores", "nnr_scores", "score_ratio", "nnr_threshold"]

#: The blob ratios (Eq. 13-14).
RATIOS = ("D>=", "D+>=", "D+")


def check_ratio(ratio, name: str = "ratio") -> str:
    if not isinstance(ratio, str) or ratio not in RATIOS:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, RATIOS))}, got {ratio!r}")
    return ratio


class NNRScores(np.ndarray):
    """A float64 score array with the blob ``ratio`` that made it; indexing, sorting, copies and pickling
    keep it, ufuncs and reductions return plain arrays."""

    ratio: str | None

    def __new__(cls, scores, ratio: str):
        obj = np.asarray(scores, dtype=np.float64).view(cls)
        obj.ratio = check_ratio(ratio)
        return obj

    def __array_finalize__(self, obj) -> None:
        self.ratio = getattr(obj, "ratio", None)

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        # Arithmetic leaves the scale: compute on plain arrays and return plain results.
        inputs = tuple(np.asarray(x) if isinstance(x, NNRScores) else x for x in inputs)
        if "out" in kwargs:
            kwargs["out"] = tuple(np.asarray(x) if isinstance(x, NNRScores) else x for x in kwargs["out"])
        return getattr(ufunc, method)(*inputs, **kwargs)

    def __reduce__(self):
        fn, args, state = super().__reduce__()
        return fn, args, (state, self.ratio)

    def __setstate__(self, state) -> None:
        base, self.ratio = state
        super().__setstate__(base)

    def __repr__(self) -> str:
        return f"NNRScores({np.asarray(self)!r}, ratio={self.ratio!r})"


def nnr_scores(scores, ratio: str) -> NNRScores:
    """``scores`` as :class:`NNRScores` of ``ratio`` (``ValueError`` if they carry another).

    Examples
    --------
    >>> s = nnr_scores([0.3, 0.1, 0.45], "D+")
    >>> np.sort(s)[:2].ratio
    'D+'
    >>> type(s * 2).__name__
    'ndarray'
    """
    ratio = check_ratio(ratio)
    carried = score_ratio(scores)
    if carried is not None and carried != ratio:
        raise ValueError(f"scores carry ratio {carried!r}, not {ratio!r}")
    return NNRScores(scores, ratio)


def score_ratio(scores) -> str | None:
    """The blob ratio that ``scores`` carries (an :class:`NNRScores`), or None when its scale is unknown."""
    return getattr(scores, "ratio", None) if isinstance(scores, NNRScores) else None


def nnr_threshold(threshold: float, ratio: str) -> float:
    """A threshold ``t`` on the NNR ratio on ``ratio``'s scale: ``t`` or ``t / (1 + t)``.

    Examples
    --------
    >>> nnr_threshold(0.8, "D>="), round(nnr_threshold(0.8, "D+"), 4)
    (0.8, 0.4444)
    """
    return float(threshold) if check_ratio(ratio) == "D>=" else float(threshold) / (1.0 + float(threshold))
