"""SCV: sequential correspondence selection by cosegmentation (Čech, Matas, Perdoch, TPAMI 2010), geometric.

Regions grow around each correspondence and Wald's SPRT decides sequentially to accept, reject or grow.
**A match-based stand-in, not the pixel-based method**: the regions grow over the other matches.
"""

from __future__ import annotations

import numpy as np

from .._numerics.fixedmath import log
from ._common import MatchSet, check_positive, knn_without_self, match_filter

__all__ = ["scv_filter", "SCV_GROWTH"]

#: Region sizes (matches) of the growth steps: each step doubles the region.
SCV_GROWTH = (4, 8, 16, 32, 64)


def _shared_counts(n1: np.ndarray, n2: np.ndarray, sizes) -> np.ndarray:
    """(K, len(sizes)): matches common to the first ``s`` entries of ``n1`` and ``n2``, per ``s`` of ``sizes``."""
    out = np.zeros((len(n1), len(sizes)), np.int64)
    for t, s in enumerate(sizes):
        both = np.sort(np.concatenate([n1[:, :s], n2[:, :s]], axis=1), axis=1)
        out[:, t] = (both[:, 1:] == both[:, :-1]).sum(1)
    return out


@match_filter(label="SCV", merge=True, positive=("p1", "p0", "alpha", "beta"))
def scv_filter(
    ms: MatchSet,
    *,
    growth=SCV_GROWTH,
    p1: float = 0.15,
    p0: float = 0.03,
    alpha: float = 0.05,
    beta: float = 0.05,
) -> np.ndarray:
    """Sequential correspondence verification by growing co-segmented match regions (geometric stand-in).

    %(parameters_unused)s
    growth : sequence of int, default (4, 8, 16, 32, 64)
        Increasing region sizes, in matches, of the growth steps (capped at ``K - 1``).
    p1, p0 : float, default 0.15 and 0.03
        Probability that a new image-1 region member is in the image-2 region, for a correct / wrong match
        (``p0`` raised to the chance level ``k_t / (K - 1)``; a chance level reaching ``p1`` ends the test).
    alpha, beta : float, default 0.05
        Probabilities of accepting a wrong / rejecting a correct correspondence (Wald's thresholds).

    Returns
    -------
    %(keep)s

    Notes
    -----
    At step ``t`` the regions of match ``i`` are its ``k_t`` nearest matches around ``x_i`` and ``y_i``; each
    new image-1 member is a Bernoulli trial, a success when also in the image-2 region; undecided matches are
    rejected. The regions double, as the paper's grow geometrically; the paper's constants belong to its pixel
    statistics (choices: ``docs/filters.md``). No code of the authors is public.

    %(coincident)s

    References
    ----------
    J. Čech et al., "Efficient sequential correspondence selection by cosegmentation", IEEE TPAMI 32(9), 2010.
    A. Wald, "Sequential analysis", Wiley, 1947.
    """
    sizes = [check_positive(s, "growth", integer=True) for s in np.atleast_1d(growth)]
    if not sizes or any(b <= a for a, b in zip(sizes, sizes[1:])):
        raise ValueError(f"growth must be a non-empty increasing sequence of sizes, got {growth!r}")
    if not p0 < p1 < 1:
        raise ValueError(f"p0 and p1 must satisfy 0 < p0 < p1 < 1, got p0={p0}, p1={p1}")
    if alpha >= 1 or beta >= 1:
        raise ValueError(f"alpha and beta must be below 1, got alpha={alpha}, beta={beta}")
    n = len(ms)
    sizes = sorted({min(s, n - 1) for s in sizes if min(s, n - 1) > 0})
    if not sizes:
        return np.zeros(n, bool)
    n1, n2 = (knn_without_self(p, np.arange(n), sizes[-1]) for p in (ms.x, ms.y))
    shared = _shared_counts(n1, n2, sizes)
    # _fixedmath's logarithm: the likelihood ratios meet their bounds the same way on any CPU.
    upper, lower = float(log((1 - beta) / alpha)), float(log(beta / (1 - alpha)))
    llr = np.zeros(n)
    decided = np.zeros(n, bool)
    keep = np.zeros(n, bool)
    prev_size, prev_shared = 0, np.zeros(n, np.int64)
    for t, s in enumerate(sizes):
        chance = max(p0, s / (n - 1))
        if chance >= p1:
            break
        trials = s - prev_size
        # Successes among this step's entrants, capped at the trials (earlier image-1 entrants may only now
        # enter the image-2 region).
        success = np.minimum(shared[:, t] - prev_shared, trials)
        step = success * float(log(p1 / chance)) + (trials - success) * float(log((1 - p1) / (1 - chance)))
        llr = np.where(decided, llr, llr + step)
        accept = ~decided & (llr >= upper)
        reject = ~decided & (llr <= lower)
        keep |= accept
        decided |= accept | reject
        prev_size, prev_shared = s, shared[:, t]
        if decided.all():
            break
    return keep
