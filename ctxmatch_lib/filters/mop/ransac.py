"""One plane search of MOP and MiHo: a RANSAC over minimal samples of four well-spread matches that keeps the
``buffers`` best, mostly disjoint inlier sets it meets (the authors' ``ransac_middle``).

The best set gives the plane, refitted on its members; the runners-up seed the first hypotheses of the next
search, so that a second plane found on the way is not searched for from scratch.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from ..._numerics.fixedmath import log
from .homography import fit_homographies, fit_minimal, keeps_orientation, supports, transfer_errors
from .params import MopParams

__all__ = ["Views", "PlaneFit", "fit_plane", "CHUNK_ELEMENTS"]

#: Point tests computed at once: whole batches of hypotheses are scored together up to about this many.
CHUNK_ELEMENTS = 1 << 19


class Views:
    """The point pairs a plane hypothesis maps: image 1 -> image 2 (MOP), or image 1 -> middle and image 2 ->
    middle (MiHo), the middle points being ``(p1 + p2) / 2``; a hypothesis holds one homography per pair."""

    def __init__(self, p1: np.ndarray, p2: np.ndarray, middle: bool):
        self.p1, self.p2, self.middle = p1, p2, middle
        if middle:
            m = (p1 + p2) / 2.0
            self.pairs = ((p1, m), (p2, m))
        else:
            self.pairs = ((p1, p2),)

    def __len__(self) -> int:
        return len(self.p1)

    def take(self, rows: np.ndarray) -> Views:
        return Views(self.p1[rows], self.p2[rows], self.middle)

    def fit(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hypotheses ``(S, J, 3, 3)`` through the minimal samples (S, 4) and their conditioning ``(S,)``: the
        largest second-smallest singular value among the ``J`` DLT systems (:func:`.homography.fit_minimal`)."""
        fits = [fit_minimal(src[samples], dst[samples]) for src, dst in self.pairs]
        return np.stack([H for H, _ in fits], axis=1), np.max([sv for _, sv in fits], axis=0)

    def refit(self, members: np.ndarray) -> np.ndarray:
        """The maps ``(J, 3, 3)`` fitted by least squares (normalised DLT) on the rows ``members``."""
        return np.stack([fit_homographies(src[None, members], dst[None, members])[0][0] for src, dst in self.pairs])

    def support(self, H: np.ndarray, samples: np.ndarray, th2: float) -> np.ndarray:
        """``(B, n)`` bool: the points within ``sqrt(th2)`` of the hypotheses ``H`` (B, J, 3, 3) with the sign
        references ``samples`` (B, r) (:func:`.homography.supports`)."""
        return supports(H, self.pairs, samples, th2)

    def errors(self, H: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Squared errors ``(B, n)`` of every point under the hypotheses ``H`` (B, J, 3, 3), the largest over the
        ``J`` maps, and whether each hypothesis's reference points ``ref`` (B, r) pass the sign check
        (:func:`.homography.transfer_errors`)."""
        err, ok = None, None
        for j, (src, dst) in enumerate(self.pairs):
            e, c = transfer_errors(H[:, j], src, dst, ref)
            err, ok = (e, c) if err is None else (np.maximum(err, e), ok & c)
        return err, ok


@dataclass(frozen=True)
class PlaneFit:
    """The outcome of one search over ``n`` matches."""

    H: np.ndarray | None  # (J, 3, 3): the plane's maps, None when no hypothesis was found
    strict: np.ndarray  # (n,) bool: within ``strict_threshold``
    loose: np.ndarray  # (n,) bool: within ``loose_threshold``, the plane's members
    seeds: np.ndarray  # (n, buffers - 1) bool: the runner-up sets, to seed the next search
    sample: np.ndarray  # (4,) int64: the minimal sample of the best hypothesis, the sign reference


class _Buffers:
    """The ``size`` best inlier sets, ranked greedily: set ``t`` counts only the points of no better set.

    A candidate is inserted where it beats a set on those restricted counts; the set it displaces is then
    compared further down, and the last one falls off. ``runner[:, t]`` is the largest restricted set at rank
    ``t`` when the buffers last changed."""

    def __init__(self, n: int, size: int):
        self.size = size
        self.sets = np.zeros((size + 1, n), bool)  # the last row holds the candidate
        self.runner = np.zeros((n, size), bool)
        self.min_count = 3  # a candidate with no more inliers cannot enter

    def offer(self, candidate: np.ndarray) -> bool:
        """Insert ``candidate`` (n,) bool; True when it becomes the best set."""
        self.sets[-1] = candidate
        idx = list(range(self.size + 1))
        covered = np.zeros(self.sets.shape[1], bool)
        smallest = self.sets.shape[1] + 1
        for t in range(self.size):
            rest = self.sets[idx[t:]] & ~covered
            counts = np.count_nonzero(rest, axis=1)
            self.runner[:, t] = rest[np.argmax(counts)]
            beaten = counts[-1] > counts[:-1]
            if beaten.any():
                j = t + int(np.argmax(beaten))
                idx[-1], idx[j] = idx[j], idx[-1]
            smallest = min(smallest, int(counts.max()))
            covered |= self.sets[idx[t]]
        self.min_count = max(4, smallest)
        self.sets = self.sets[idx]
        return idx[0] != 0

    @property
    def best(self) -> np.ndarray:
        return self.sets[0]


def _distinct_positions(rng: np.random.Generator, pool_sizes: np.ndarray, draws: int) -> np.ndarray:
    """``(draws, S, 4)`` positions, four distinct ones uniformly in ``range(pool_sizes[s])`` per draw: each
    position is drawn among those left and moved past the ones drawn before it, in increasing order."""
    r = np.floor(rng.random((draws, len(pool_sizes), 4)) * (pool_sizes[None, :, None] - np.arange(4))).astype(np.int64)
    for k in range(1, 4):
        before = np.sort(r[..., :k], axis=-1)
        for j in range(k):
            r[..., k] += r[..., k] >= before[..., j]
    return r


_PAIRS = np.array(list(combinations(range(4), 2)))


def _well_spread(views: Views, r: np.ndarray, spacing: float) -> np.ndarray:
    """``(D, S)`` bool: the four points of the samples ``r`` (D, S, 4) are farther apart than ``spacing`` in
    both images."""
    ok = np.ones(r.shape[:2], bool)
    for p in (views.p1, views.p2):
        q = p[r]  # (D, S, 4, 2)
        d = q[:, :, _PAIRS[:, 0]] - q[:, :, _PAIRS[:, 1]]
        ok &= (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] > spacing * spacing).all(axis=-1)
    return ok


def _spread_samples(rng, views: Views, its: np.ndarray, pools: list, draws: int, spacing: float):
    """One minimal sample per iteration ``its``: the first of ``draws`` random ones whose points are farther
    apart than ``spacing`` in both images; iteration ``c`` draws from the seed set ``pools[c]`` when it has more
    than four members. Returns the samples (S, 4) and their iterations, those without a sample left out.

    The draws come in rounds of growing size for the iterations still without a sample, which gives the first
    success of the same sequence of independent draws without drawing all of them."""
    own = np.array([c < len(pools) and len(pools[c]) > 4 for c in its], bool)
    sizes = np.array([len(pools[c]) if o else len(views) for c, o in zip(its, own)], np.int64)
    out = np.zeros((len(its), 4), np.int64)
    found = np.zeros(len(its), bool)
    pending = np.arange(len(its))
    done, step = 0, 2
    while done < draws and len(pending):
        k = min(step, draws - done)
        r = _distinct_positions(rng, sizes[pending], k)  # (k, P, 4)
        for s in np.flatnonzero(own[pending]):
            r[:, s] = pools[its[pending[s]]][r[:, s]]
        ok = _well_spread(views, r, spacing)
        hit = ok.any(axis=0)
        out[pending[hit]] = r[ok.argmax(axis=0)[hit], np.flatnonzero(hit)]
        found[pending[hit]] = True
        pending = pending[~hit]
        done, step = done + k, 2 * step
    return out[found], its[found]


def _iterations_needed(count: int, n: int, confidence: float) -> float:
    """RANSAC's hypothesis count ``log(1 - p) / log(1 - w^4)`` for four-point samples and the inlier ratio
    ``w = count / n``, evaluated in float32 as the authors' ``steps`` is (their tensors are float32).

    The float32 rounding is part of the algorithm's behaviour: ``1 - w^4`` rounds to exactly 1 once ``w^4`` is
    below about ``2^-25`` (``w`` below about 1.3 %), the logarithm is then 0 and the count is ``-inf``, so the
    search stops as soon as it has run ``min_iterations`` hypotheses. On heavily contaminated candidate sets
    (a few thousand matches, the pool mostly outliers) this is what ends the searches among the outliers
    after about fifty hypotheses instead of ``max_iterations``; a float64 count would let every such search
    run to ``max_iterations``, find larger chance planes and keep many more outliers. Only IEEE float32
    operations (correctly rounded, the same on any CPU) and _fixedmath's ``log`` rounded to float32.

    Examples
    --------
    >>> round(_iterations_needed(1, 2, 0.9), 2), _iterations_needed(1, 1, 0.9)
    (35.68, 0.0)
    >>> _iterations_needed(130, 10000, 0.9), _iterations_needed(135, 10000, 0.9) > 1e6
    (-inf, True)
    """
    f = np.float32
    w = f(count) / f(n)
    q = f(1) - (f(1) - w)
    q2 = q * q
    d = f(1) - q2 * q2
    num = f(log(float(f(1) - f(confidence))))
    den = f(log(float(d))) if d > 0 else f(-np.inf)
    if den == 0:
        return -np.inf
    return float(num / den)


def _classify(views: Views, H: np.ndarray, sample: np.ndarray, prm: MopParams):
    """``(strict, loose)`` members of the plane ``H`` (J, 3, 3) with the sign reference ``sample``."""
    return (views.support(H[None], sample[None], prm.strict_threshold**2)[0],
            views.support(H[None], sample[None], prm.loose_threshold**2)[0])


def _hypotheses(rng, views: Views, its: np.ndarray, pools: list, draws: int, prm: MopParams):
    """The hypotheses of the iterations ``its``: ``(its, samples (S, 4), H (S, J, 3, 3), inliers (S, n))`` of
    those with a well-spread, unmirrored (``reject_reflections``), well-conditioned minimal sample."""
    samples, its = _spread_samples(rng, views, its, pools, draws, prm.min_sample_spacing)
    if prm.reject_reflections and len(samples):
        keep = keeps_orientation(views.p1, views.p2, samples)
        samples, its = samples[keep], its[keep]
    if not len(samples):
        return its, samples, None, np.zeros((0, len(views)), bool)
    H, sv = views.fit(samples)
    good = sv > prm.min_singular_value
    H, samples, its = H[good], samples[good], its[good]
    return its, samples, H, views.support(H, samples, prm.loose_threshold**2)


def fit_plane(views: Views, seeds: np.ndarray, rng: np.random.Generator, prm: MopParams) -> PlaneFit:
    """Search the largest plane among ``views`` (n matches); ``seeds`` (n, S) bool are the runner-up sets of the
    previous search (the sampling pools of the first ``S`` hypotheses).

    Hypotheses come in batches of ``batch_budget // n``, each scored by its members within
    ``loose_threshold`` (:func:`.homography.supports`: both ways, on the side of the line at infinity of the
    sample) and offered to the buffers in decreasing size. The search stops past ``max_iterations``, or at
    the end of a batch past both ``min_iterations`` and RANSAC's count for the best set (in float32 as the
    authors': ``-inf``, so a stop right past ``min_iterations``, while the best set is below about 1.3 % of the
    ``n`` matches; :func:`_iterations_needed`). The best set is
    refitted by least squares (normalised DLT) unless the refit has fewer members than the set. Several
    batches are computed at once (about :data:`CHUNK_ELEMENTS` point tests), then replayed batch by batch.
    """
    n = len(views)
    empty = np.zeros(n, bool)
    if n < 4:
        return PlaneFit(None, empty, empty, np.zeros((n, 0), bool), np.zeros(4, np.int64))
    draws = min(prm.min_iterations, n * (n - 1) * (n - 2) * (n - 3) // 12)
    batch = max(1, prm.batch_budget // n)
    chunk = batch * max(1, CHUNK_ELEMENTS // (batch * n))
    pools = [np.flatnonzero(seeds[:, j]) for j in range(seeds.shape[1])]
    buf = _Buffers(n, prm.buffers)
    best_H, best_sample, needed = None, np.zeros(4, np.int64), np.inf
    c, done = 0, False
    while c < prm.max_iterations and not done:
        end = min(prm.max_iterations, c + chunk)
        its, samples, H, inliers = _hypotheses(rng, views, np.arange(c, end), pools, draws, prm)
        counts = np.count_nonzero(inliers, axis=1)
        for b in range(c, end, batch):
            rows = np.flatnonzero((its >= b) & (its < b + batch))
            for i in rows[np.argsort(-counts[rows], kind="stable")]:
                if counts[i] > buf.min_count and buf.offer(inliers[i]):
                    best_H, best_sample = H[i], samples[i]
                    needed = _iterations_needed(np.count_nonzero(buf.best), n, prm.confidence)
            if b + batch > needed and b + batch > draws:
                done = True
                break
        c = end
    seeds_out = buf.runner[:, 1:].copy()
    if best_H is None:
        return PlaneFit(None, empty, empty, seeds_out, best_sample)
    best_count = np.count_nonzero(buf.best)
    H = views.refit(np.flatnonzero(buf.best))
    strict, loose = _classify(views, H, best_sample, prm)
    if best_count > np.count_nonzero(loose):  # the refit lost members: keep the sampled hypothesis
        H = best_H
        strict, loose = _classify(views, H, best_sample, prm)
    return PlaneFit(H, strict, loose, seeds_out, best_sample)
