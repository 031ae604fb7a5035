"""RFM-SCAN: Robust Feature Matching using Spatial Clustering (Jiang et al., TIP 2020), :func:`rfm_scan_filter`.

Matches are points ``[x, y, y - x]`` of a min-max normalised motion space (Sec. III-A) with the distance
of Eq. (3), ``|dx| + |dy| + (1 + gamma exp(-min(|dx|, |dy|))) |dv|``. DBSCAN (Ester et al., KDD 1996) with
adaptive ``MinPts`` and ``eps = min L + mu (max L - min L)`` (Sec. III-B) clusters them twice, the second
time with the unclustered pushed away (Sec. III-C). Seeded random matches are added as in the authors' demo.
No K x K matrix is built, yet every decision is the dense float32 computation's (bounds, :mod:`._kernels`).
"""

from __future__ import annotations

import random
from itertools import chain

import numpy as np
from scipy.spatial import cKDTree

from ..._numerics.fixedmath import exp
from .._common import MatchSet, check_positive, match_filter
from ._kernels import MotionGrid, count_within, upper_kth

__all__ = ["rfm_scan_filter"]

#: Up to this many queries, an exact test the grid counts leave open takes whole rows of distances.
_FEW_ROWS = 64

#: Radius factor of the embedding ball per Minkowski p (see _MotionSpace).
_P_SCALE = {2: 1.0, 1: float(np.sqrt(2.0))}


class _MotionSpace:
    """Distances of Eq. (3) between motion-space points (float32, as the dense formula), with k-d trees.

    A match within ``r`` has a motion weight of at least ``c(r) = 1 + gamma exp(-r / 2)``, so the ball of
    radius ``r`` (L1: ``sqrt(2) r``) around the embedding ``[x, y, c(r) v]`` holds every match within ``r``."""

    def __init__(self, feats: np.ndarray, gamma: float) -> None:
        self.f = feats.astype(np.float32)
        self.f64 = self.f.astype(np.float64)  # the float32 points, for the compiled counts
        self.feats = feats
        self.gamma = float(gamma)
        self.gamma32 = float(np.float32(gamma))
        self.n = len(feats)
        self._trees: dict = {}
        self.order = None  # the leaf order of a k-d tree over every point, once built (see _Round.upper)
        self.prev_upper = None  # the previous round's upper bounds of L
        self.prev_cand = None  # the matches (rows) and neighbours of its k-NN bounds of L

    def dist(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """float32 distances between the matches ``i`` and ``j`` (broadcast together), Eq. (3)."""
        fi, fj = self.f[i], self.f[j]

        def pair_dist(a: int) -> np.ndarray:
            dx = fi[..., a] - fj[..., a]
            dy = fi[..., a + 1] - fj[..., a + 1]
            return np.sqrt(dx * dx + dy * dy)

        d1, d2, dv = pair_dist(0), pair_dist(2), pair_dist(4)
        # fixedmath's exp rounded to float32 (numpy's float32 exp follows the CPU's SIMD loop).
        return d1 + d2 + (1.0 + np.float32(self.gamma) * exp(-np.minimum(d1, d2)).astype(np.float32)) * dv

    def embed(self, idx: np.ndarray, level: float) -> np.ndarray:
        c = 1.0 + self.gamma * float(exp(-level / 2.0))
        return self.feats[idx] * np.array([1.0, 1.0, 1.0, 1.0, c, c])

    def tree(self, key, members: np.ndarray, level: float) -> cKDTree:
        if (key, level) not in self._trees:
            self._trees[key, level] = cKDTree(self.embed(members, level))
        return self._trees[key, level]

    def ball(self, key, members: np.ndarray, queries: np.ndarray, radius: np.ndarray, chunk: int = 2048, p: int = 2):
        """Members possibly within ``radius`` (per query) of each query: yields ``(sel, lens, j)``.

        ``sel``: positions in ``queries``; ``lens``: members found for each; ``j``: their indices, concatenated."""
        r = np.asarray(radius, np.float64) * (1 + 1e-5) + 1e-6  # float32 rounding of the true distances
        # One tree per power-of-two level: c(level) holds for every radius up to the level.
        # 2^ceil(log2 r), from the binary exponent (exact: np.log2 follows the CPU in its last bit).
        m, e = np.frexp(np.maximum(r, 1e-3))
        levels = np.ldexp(1.0, e - (m == 0.5))
        for level in np.unique(levels):
            tree = self.tree(key, members, float(level))
            for b in range(0, int((levels == level).sum()), chunk):
                sel = np.flatnonzero(levels == level)[b : b + chunk]
                lists = tree.query_ball_point(self.embed(queries[sel], float(level)), _P_SCALE[p] * r[sel], p=p,
                                              return_sorted=False)
                lens = np.fromiter(map(len, lists), np.int64, len(lists))
                yield sel, lens, members[np.fromiter(chain.from_iterable(lists), np.int64, int(lens.sum()))]


class _Round:
    """One DBSCAN round: ``L_i`` is the ``MinPts``-th smallest ``d_ij * scale_j`` (itself included, at 0)."""

    def __init__(self, space: _MotionSpace, scale: np.ndarray, k: int) -> None:
        space._trees.clear()  # the trees are per round
        self.space, self.scale, self.k = space, scale, k
        self.groups = [(np.float32(s), np.flatnonzero(scale == s)) for s in np.unique(scale)]

    def upper(self) -> np.ndarray:
        """Upper bounds of every ``L_i`` (:meth:`tree_upper`, or :meth:`coarse_upper` in the second round)."""
        sp = self.space
        self.coarse = np.zeros(sp.n, bool)
        if len(self.groups) > 1 and len(self.groups[0][1]) >= self.k:
            return self.coarse_upper()
        return self.tree_upper(np.arange(sp.n) if sp.order is None else sp.order)

    def tree_upper(self, rows: np.ndarray) -> np.ndarray:
        """Upper bounds of ``L`` of ``rows`` (in their order): the k-th true distance to k approximate neighbours."""
        sp, n = self.space, self.space.n
        groups = self.groups[:1] if len(self.groups[0][1]) >= self.k else self.groups
        cand, cscale = [], []
        for s, g in groups:
            m = min(self.k, len(g))
            tree = sp.tree(s, g, 0.0)
            if sp.order is None and len(g) == n:
                # Queries in the leaf order of a tree over every match (the first round's) walk the same
                # nodes one after another (faster than in row order; the same neighbours).
                sp.order = g[tree.indices]
                if len(rows) == n:
                    rows = sp.order
            # Approximate neighbours (eps=1) suffice: any k true distances bound the k-th from above.
            _, nb = tree.query(sp.embed(rows, 0.0), k=m, eps=1.0)
            cand.append(g[nb.reshape(-1, m)])
            cscale.append(np.full(cand[-1].shape, float(s)))
        cand, cscale = np.hstack(cand), np.hstack(cscale)
        if len(rows) == n:
            sp.prev_cand = rows, cand
        out = np.empty(n, np.float32)
        out[rows] = upper_kth(sp.f64, rows, cand, cscale, self.k, sp.gamma32)
        return out[rows] if len(rows) < n else out

    def coarse_upper(self) -> np.ndarray:
        """Second-round upper bounds of ``L``: k-NN bounds for seeds and the rest, ``R`` for the matches with
        ``MinPts`` matches surely within ``R`` (just below the seeds' largest exact ``L``; marked coarse)."""
        sp, n = self.space, self.space.n
        out = np.empty(n, np.float32)
        order = np.arange(n) if sp.order is None else sp.order
        seeds = [order[:: max(1, n // 512)]]
        if sp.prev_upper is not None:
            seeds.append(np.argsort(sp.prev_upper, kind="stable")[:256])
        seeds = np.unique(np.concatenate(seeds))
        out[seeds] = self.tree_upper(seeds)
        # R: just below the largest exact L of the seeds with the largest bounds (at most max L, so the
        # search for max L passes the coarse bounds by)
        top = seeds[np.argsort(-out[seeds], kind="stable")[:8]]
        radius = np.float32(self.dense_kth(top, out).max() * np.float32(1 - 1e-3))
        self.coarse = self.counts(np.arange(n), float(radius))[0] >= self.k
        self.coarse[seeds] = False
        out[self.coarse] = radius  # MinPts float32 distances within radius: L is at most radius
        rest = np.flatnonzero(~self.coarse)
        rest = rest[np.isin(rest, seeds, assume_unique=True, invert=True)]
        if len(rest):
            out[rest] = self.tree_upper(rest)
        if sp.prev_cand is not None:
            # The previous round's neighbours at this round's scales: as tight where they are all clustered.
            rows, cand = sp.prev_cand
            again = upper_kth(sp.f64, rows, cand, self.scale[cand].astype(np.float64), self.k, sp.gamma32)
            out[rows] = np.minimum(out[rows], again)
        return out

    def refine(self, upper: np.ndarray) -> None:
        """Replace the coarse upper bounds (see :meth:`coarse_upper`) by k-NN ones, in place."""
        rows = np.flatnonzero(self.coarse)
        if len(rows):
            upper[rows] = np.minimum(upper[rows], self.tree_upper(rows))
        self.coarse[:] = False

    def ball_distances(self, groups, queries: np.ndarray, radius: np.ndarray):
        """``(rows, vals)``: the position in ``queries`` and scaled float32 distance of every member of
        ``groups`` the ball search of ``radius`` (per query) finds around each query."""
        rows, vals = [np.empty(0, np.int64)], [np.empty(0, np.float32)]
        for s, g in groups:
            for sel, lens, j in self.space.ball(s, g, queries, radius / s):
                rows.append(np.repeat(sel, lens))
                vals.append(self.space.dist(queries[rows[-1]], j) * s)
        return np.concatenate(rows), np.concatenate(vals)

    def ball_kth(self, queries: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """Exact ``L`` of ``queries`` where it is at most ``radius``, else NaN."""
        rows, vals = self.ball_distances(self.groups, queries, radius)
        out = np.full(len(queries), np.nan, np.float32)
        # Sorted by (row, value) in one uint64 sort: the row in the high word, the float32 bits in the low word
        # (the bits of non-negative floats order as the floats; ``+ 0`` turns a -0.0 into +0.0).
        vals = vals + np.float32(0)
        key = rows.astype(np.uint64) << np.uint64(32)
        key |= vals.view(np.uint32)
        key.sort()
        vals = (key & np.uint64(0xFFFFFFFF)).astype(np.uint32).view(np.float32)
        bounds = np.arange(len(queries) + 1, dtype=np.uint64) << np.uint64(32)
        edges = np.searchsorted(key, bounds)
        start, end = edges[:-1], edges[1:]
        ok = np.flatnonzero(end - start >= self.k)
        kth = vals[start[ok] + self.k - 1]
        good = kth <= radius[ok]  # k matches within radius: the k-th of the ball is the k-th of all
        out[ok[good]] = kth[good]
        return out

    def counts(self, queries: np.ndarray, radius: float, on_possible: bool = False):
        """Matches surely / possibly within ``radius`` (scaled distances) of each query, counted on grids
        until the sure count (the possible count with ``on_possible``) reaches ``MinPts``."""
        sp = self.space
        sure = np.zeros(len(queries), np.int64)
        possible = np.zeros(len(queries), np.int64)
        qf, ones, stop = sp.f64[queries], np.ones(len(queries)), np.full(len(queries), self.k, np.int64)
        for s, g in self.groups:
            grid = MotionGrid(sp.f64, g, float(radius) / float(s), sp.gamma32)
            count_within(grid, qf, ones, stop, float(radius), sp.gamma32, gscale=float(s), sure=sure,
                         possible=possible, on_possible=on_possible)
        return sure, possible

    def core(self, queries: np.ndarray, radius: float) -> np.ndarray:
        """Whether ``MinPts`` matches lie within ``radius`` of each query: grid counts, else float32 distances."""
        sure, possible = self.counts(queries, radius)
        out = sure >= self.k
        und = np.flatnonzero(~out & (possible >= self.k))
        if len(und) > _FEW_ROWS:
            out[und] = self.ball_core(queries[und], radius, p=1)
        elif len(und):
            every = np.arange(self.space.n)[None, :]
            d = self.space.dist(queries[und][:, None], every) * self.scale[None, :]
            out[und] = (d <= radius).sum(1) >= self.k
        return out

    def ball_core(self, queries: np.ndarray, radius: float, p: int = 2) -> np.ndarray:
        """``ball_kth(queries, radius) <= radius``, by counting instead of sorting."""
        count = np.zeros(len(queries), np.int64)
        for s, g in self.groups:
            for sel, lens, j in self.space.ball(s, g, queries, np.full(len(queries), radius / s), p=p):
                rows = np.repeat(sel, lens)
                hit = self.space.dist(queries[rows], j) * s <= radius
                count += np.bincount(rows[hit], minlength=len(queries))
        return count >= self.k

    def dense_kth(self, queries: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """Exact ``L`` of a few ``queries``: whole rows to the least-scaled group, ball searches for the rest."""
        k = self.k
        split = len(self.groups) > 1 and len(self.groups[0][1]) >= k
        cols = self.groups[0][1] if split else np.arange(self.space.n)
        out = np.empty(len(queries), np.float32)
        step = max(1, int(2e6 // len(cols)))
        for b in range(0, len(queries), step):
            q = queries[b : b + step]
            d = self.space.dist(q[:, None], cols[None, :]) * self.scale[cols][None, :]
            if not split:
                out[b : b + step] = np.partition(d, k - 1, axis=1)[:, k - 1]
                continue
            rows, vals = self.ball_distances(self.groups[1:], q, upper[q])
            # The k smallest of each whole row, then each row's ball matches, padded with inf.
            counts = np.bincount(rows, minlength=len(q))
            both = np.full((len(q), k + int(counts.max(initial=0))), np.inf, np.float32)
            both[:, :k] = np.partition(d, k - 1, axis=1)[:, :k]
            order = np.argsort(rows, kind="stable")
            pos = np.arange(len(rows)) - np.repeat(np.cumsum(counts) - counts, counts)
            both[rows[order], k + pos] = vals[order]
            out[b : b + step] = np.partition(both, k - 1, axis=1)[:, k - 1]
        return out

    def max_search(self, rows: np.ndarray, upper: np.ndarray, kth: np.ndarray) -> None:
        """Exact ``L`` into ``kth`` of ``rows``, largest bound first, until the largest ``L`` is known."""
        rows = rows[np.argsort(-upper[rows], kind="stable")]
        for b in range(0, len(rows), 64):
            batch = rows[b : b + 64]
            batch = batch[upper[batch] >= np.nanmax(kth)]
            if len(batch) == 0:
                break
            kth[batch] = self.dense_kth(batch, upper)

    def clustered(self, mu: float) -> np.ndarray:
        """Matches DBSCAN clusters with ``eps = min L + mu (max L - min L)``: core ones and those within ``eps``."""
        n = self.space.n
        everyone = np.arange(n)
        upper = self.upper()
        # min L: a ball search of radius min upper, where the grid counts k matches possibly within it
        # (elsewhere fewer than k matches lie within it, and the ball search would give NaN too)
        kth = np.full(n, np.nan, np.float32)
        near = np.flatnonzero(self.counts(everyone, np.float64(upper.min()), on_possible=True)[1] >= self.k)
        if len(near):
            kth[near] = self.ball_kth(near, np.full(len(near), upper.min(), np.float64))
        # max L: the matches with k-NN bounds, then the coarse ones (below max L as a rule; else their
        # k-NN bounds, and the same search)
        rest = np.isnan(kth)
        self.max_search(np.flatnonzero(rest & ~self.coarse), upper, kth)
        coarse = np.flatnonzero(rest & self.coarse)
        if len(coarse) and upper[coarse].max() >= np.nanmax(kth):
            self.refine(upper)
            self.max_search(coarse, upper, kth)
        self.space.prev_upper = upper
        lo, hi = np.nanmin(kth), np.nanmax(kth)
        eps = lo + np.float32(mu) * (hi - lo)
        # Core: sure where the upper bound is within eps; the grid counts decide the rest.
        core = upper <= eps
        todo = np.flatnonzero(~core)
        if len(todo):
            core[todo] = self.core(todo, np.float64(eps))
        # Reached: a non-core match with a core match within eps (distance scaled by its own scale).
        reached = core.copy()
        core_idx, others = np.flatnonzero(core), np.flatnonzero(~core)
        if len(core_idx) == 0 or len(others) == 0:
            return reached
        # A core match surely within eps on the grid: reached; none possibly: not; the float32 distances
        # decide the rest (whole rows for a few, else a ball search).
        sp = self.space
        qscale = self.scale[others].astype(np.float64)
        grid = MotionGrid(sp.f64, core_idx, float(eps), sp.gamma32)
        sure, possible = count_within(grid, sp.f64[others], qscale, np.ones(len(others), np.int64), float(eps),
                                      sp.gamma32)
        reached[others[sure >= 1]] = True
        und = others[(sure < 1) & (possible >= 1)]
        if 0 < len(und) <= _FEW_ROWS:
            d = sp.dist(und[:, None], core_idx[None, :]) * self.scale[und][:, None]
            reached[und[(d <= eps).any(1)]] = True
        elif len(und):
            for sel, lens, i in sp.ball("core", core_idx, und, np.float64(eps) / self.scale[und]):
                j = np.repeat(und[sel], lens)
                hit = sp.dist(i, j) * self.scale[j] <= eps
                reached[j[hit]] = True
        return reached


def _added_matches(x: np.ndarray, y: np.ndarray, n_noise: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """The demo's random matches, uniform in ``[0, max]`` of each coordinate, image 1 first.

    An integer ``rng`` draws as Octave's ``rand`` after ``rand('state', rng)`` (Python's Mersenne twister)."""
    if isinstance(rng, np.random.Generator):
        u = rng.random(4 * n_noise)
    else:
        draw = random.Random(None if rng is None else int(rng)).random
        u = np.array([draw() for _ in range(4 * n_noise)], np.float64)
    u = u.reshape(2, 2, n_noise)  # (image, coordinate, match)
    return u[0].T * x.max(0), u[1].T * y.max(0)


@match_filter(label="RFM-SCAN", merge="merge_coincident", non_negative=("gamma", "pct"))
def rfm_scan_filter(
    ms: MatchSet,
    *,
    gamma: float = 10.0,
    pct: float = 0.05,
    min_pts_bounds=(3, 30),
    mu=(0.1, 0.08),
    add_noise: bool = True,
    rng=0,
) -> np.ndarray:
    """RFM-SCAN: density clustering of the matches in a normalised motion space.

    %(parameters_unused)s
    gamma : float, default 10
        Amplification of the motion distance of nearby matches, Eq. (3) (Sec. IV-A).
    pct, min_pts_bounds : float and (int, int), default 0.05 and (3, 30)
        ``MinPts`` as a fraction of the matches (Sec. IV-A: 0.02-0.05), and its range.
    mu : (float, float), default (0.1, 0.08)
        ``eps`` rates of the two rounds (Sec. III-B, IV-A).
    add_noise : bool, default True
        Add ``round(min(0.05 K, 20))`` uniform random matches before clustering (authors' demo).
    rng : None, int or numpy.random.Generator, default 0
        Seed of the added matches; an integer draws as Octave's ``rand('state', s)`` (the authors' demo).
    %(merge_keep_coincident)s
    A location counts once in the density counts and in ``N``. Where the papers are silent, the authors'
    code (StaRainJ/RFM-SCAN) is followed: Euclidean distances in Eq. (3), MATLAB's ``round``, ``L``
    including itself, ``<=`` against ``eps``, added matches always pushed away in the second round.
    The agreement with the original: ``docs/filters.md``.

    References
    ----------
    X. Jiang, J. Ma, J. Jiang, X. Guo, "Robust feature matching using spatial clustering with heavy
    outliers", IEEE TIP 29, 2020. M. Ester et al., "A density-based algorithm for discovering clusters in
    large spatial databases with noise", KDD 1996.
    """
    lo_pts, hi_pts = (check_positive(v, "min_pts_bounds", integer=True) for v in min_pts_bounds)
    if lo_pts > hi_pts:
        raise ValueError(f"min_pts_bounds must be increasing, got {min_pts_bounds!r}")
    mu = [check_positive(v, "mu", allow_zero=True) for v in np.atleast_1d(mu)]
    if len(mu) != 2:
        raise ValueError(f"mu must hold two rates, got {mu!r}")
    if rng is not None and not isinstance(rng, (int, np.integer, np.random.Generator)) or (
            isinstance(rng, (int, np.integer)) and rng < 0):
        raise ValueError(f"rng must be None, a non-negative int or a numpy Generator, got {rng!r}")
    n = len(ms)
    if n == 0:
        return np.zeros(0, bool)
    x, y = ms.x, ms.y
    if add_noise:
        # MATLAB's round: halves away from zero (Python's round would take 0.5 * 5 = 2.5 to 2)
        n_noise = int(np.floor(min(0.05 * n, 20) + 0.5))
        nx, ny = _added_matches(x, y, n_noise, rng)
        x, y = np.vstack([x, nx]), np.vstack([y, ny])
    n_all = len(x)
    feats = np.hstack([x, y, y - x])
    span = feats.max(0) - feats.min(0)
    feats = (feats - feats.min(0)) / np.where(span > 0, span, 1.0)  # per-coordinate min-max to [0, 1]
    min_pts = int(min(max(np.floor(n_all * pct + 0.5), lo_pts), hi_pts))  # MATLAB's round
    if n_all < min_pts:
        return np.zeros(n, bool)
    space = _MotionSpace(feats, gamma)
    first = _Round(space, np.ones(n_all, np.float32), min_pts).clustered(mu[0])  # Sec. III-B
    # Second round: distances to the matches other than the first-round clustered real ones times 100 (Sec. III-C).
    scale = np.where(first & (np.arange(n_all) < n), 1.0, 100.0).astype(np.float32)
    return _Round(space, scale, min_pts).clustered(mu[1])[:n]
