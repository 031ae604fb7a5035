"""RFM-SCAN: Robust Feature Matching using SpatialClustering with heavy outliers (Jiang et al., TIP 2020).

Each match becomes a point of a motion space made of its two keypoints and its motion vector,
``[x, y, y - x]``, every coordinate min-max normalised to [0, 1] over the matches (Sec. III-A). The distance
between two matches adds the keypoint distances in both images and the motion-vector distance, the latter
amplified when the matches are close (Eq. (3)):

    d_ij = |x_i - x_j| + |y_i - y_j| + (1 + gamma * exp(-min(|x_i - x_j|, |y_i - y_j|))) * |v_i - v_j|.

Inliers form dense clusters, outliers are sparse: DBSCAN (Ester et al., KDD 1996) keeps the matches that are
core points (at least ``MinPts`` matches, itself included, within ``eps``) or lie within ``eps`` of a core
point. The parameters are adaptive (Sec. III-B): ``MinPts = clip(round(pct * N), 3, 30)`` and, with
``L_i`` the distance of match ``i`` to its ``MinPts``-th nearest match, ``eps = min L + mu * (max L - min
L)``. A second round (Sec. III-C) recomputes ``L`` and ``eps`` (``mu = 0.08``) with the matches not
clustered by the first round pushed away (their distances multiplied by 100), and clusters again.

As in the authors' demo, a few uniform random matches (``round(min(0.05 N, 20))``, seeded) are added before
clustering so that the adaptive ``eps`` stays meaningful when the input is almost outlier-free; they are
never returned. Only the kept/rejected mask is needed, so DBSCAN's cluster labels are not built: a match is
kept when it is a core point or is within ``eps`` of one, which is exactly the set DBSCAN assigns to some
cluster.

No K x K matrix is built and the result is the dense computation's, bit for bit. Only the exact ``min L``
and ``max L`` (hence ``eps``), each match's core status and its reachability decide, and every decision is
either taken on the float32 distances of the dense formula or proven from bounds:

- upper bounds of ``L_i`` from k approximate nearest neighbours (a k-d tree over an embedding of the
  points; any k distances bound the k-th), the distances in float64 times ``1 + margin``; in the second
  round most matches get a coarse bound (``MinPts`` matches surely within a radius just below a known
  ``L``), which the search for ``max L`` passes by;
- ``min L``: a ball search of radius ``min upper`` where a grid count finds ``MinPts`` matches possibly
  within it; ``max L``: whole rows of distances for the few matches with the largest bounds (to the second
  round's clustered matches only; the others, at 100 times their distance, ball-searched within the bound);
- core and reach: neighbours counted on uniform grids over the keypoint in image 1 and the motion vector
  (:mod:`ctxmatch_lib.filters._rfm_kernels`, compiled, float64): a match is counted when surely within
  ``eps`` (a relative margin below) or possibly (above); the rare counts the margin leaves open are
  settled on the float32 distances (whole rows, or a ball search in the L1 embedding).
"""

from __future__ import annotations

import random
from itertools import chain

import numpy as np
from scipy.spatial import cKDTree

from ._common import MatchSet, check_positive, match_filter
from ._rfm_kernels import MotionGrid, count_within, upper_kth

__all__ = ["rfm_scan_filter"]

#: Up to this many queries, an exact test the grid counts leave open takes whole rows of distances.
_FEW_ROWS = 64

#: Radius factor of the embedding ball per Minkowski p (see _MotionSpace).
_P_SCALE = {2: 1.0, 1: float(np.sqrt(2.0))}


class _MotionSpace:
    """Distances of Eq. (3) between normalised motion-space points, computed on demand, with k-d trees.

    A match ``j`` within ``r`` of ``i`` has ``|dx| + |dy| <= r``, hence ``min(|dx|, |dy|) <= r / 2`` and a
    motion weight of at least ``c(r) = 1 + gamma exp(-r / 2)``, so ``d_ij`` is at least the Euclidean
    distance between the embeddings ``[x, y, c(r) v]`` (a sum of norms bounds the norm of the
    concatenation): a ball of radius ``r`` there holds every match within ``r``. So does the ball of radius
    ``sqrt(2) r`` in the L1 distance between the embeddings (a 2-D norm is at least the L1 norm over
    ``sqrt(2)``), often the smaller ball of the two (``p=1``). The true distances of the matches found are
    computed in float32 with the operations of the dense row blocks they replace.
    """

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
        return d1 + d2 + (1.0 + np.float32(self.gamma) * np.exp(-np.minimum(d1, d2))) * dv

    def embed(self, idx: np.ndarray, level: float) -> np.ndarray:
        c = 1.0 + self.gamma * np.exp(-level / 2.0)
        return self.feats[idx] * np.array([1.0, 1.0, 1.0, 1.0, c, c])

    def tree(self, key, members: np.ndarray, level: float) -> cKDTree:
        if (key, level) not in self._trees:
            self._trees[key, level] = cKDTree(self.embed(members, level))
        return self._trees[key, level]

    def ball(self, key, members: np.ndarray, queries: np.ndarray, radius: np.ndarray, chunk: int = 2048, p: int = 2):
        """Members possibly within ``radius`` (true distance, per query) of each query, by radius level.

        Yields ``(sel, lens, j)``: the positions ``sel`` in ``queries``, the number of members found for
        each and their indices ``j`` (concatenated), ``chunk`` queries at a time.
        """
        r = np.asarray(radius, np.float64) * (1 + 1e-5) + 1e-6  # float32 rounding of the true distances
        # One tree per power-of-two level: c(level) holds for every radius up to the level.
        levels = np.exp2(np.ceil(np.log2(np.maximum(r, 1e-3))))
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
        """An upper bound of every ``L_i``: the largest true distance to k (approximately) nearest matches.

        The neighbours come from the least-scaled group alone when it has enough matches (a distance
        multiplied by 100 rarely helps and any k true distances give an upper bound). In that case (the
        second round), most matches get a coarse bound instead (see :meth:`coarse_upper`).
        """
        sp = self.space
        self.coarse = np.zeros(sp.n, bool)
        if len(self.groups) > 1 and len(self.groups[0][1]) >= self.k:
            return self.coarse_upper()
        return self.tree_upper(np.arange(sp.n) if sp.order is None else sp.order)

    def tree_upper(self, rows: np.ndarray) -> np.ndarray:
        """The k-NN upper bound of ``L`` (see :meth:`upper`) of ``rows``, in their order."""
        sp, n = self.space, self.space.n
        groups = self.groups[:1] if len(self.groups[0][1]) >= self.k else self.groups
        cand, cscale = [], []
        for s, g in groups:
            m = min(self.k, len(g))
            tree = sp.tree(s, g, 0.0)
            if sp.order is None and len(g) == n:
                # Queries in the leaf order of a tree over every match (the first round's) walk the same
                # nodes one after another (about 10 % faster than in row order; the same neighbours).
                sp.order = g[tree.indices]
                if len(rows) == n:
                    rows = sp.order
            # Approximate neighbours (eps=1) suffice: any k true distances bound the k-th from above.
            _, nb = tree.query(sp.embed(rows, 0.0), k=m, eps=1.0)
            cand.append(g[nb.reshape(-1, m)])
            cscale.append(np.full(cand[-1].shape, float(s)))
        cand = cand[0] if len(cand) == 1 else np.hstack(cand)
        cscale = cscale[0] if len(cscale) == 1 else np.hstack(cscale)
        if len(rows) == n:
            sp.prev_cand = rows, cand
        out = np.empty(n, np.float32)
        out[rows] = upper_kth(sp.f64, rows, cand, cscale, self.k, sp.gamma32)
        return out[rows] if len(rows) < n else out

    def coarse_upper(self) -> np.ndarray:
        """Upper bounds of ``L`` where the least-scaled group has ``MinPts`` matches or more (second round).

        k-NN bounds (:meth:`tree_upper`) for seeds: the matches densest in the previous round (the smallest
        ``L`` lie among them) and a spread sample. Every other match with ``MinPts`` matches surely within
        ``R`` (just below the largest exact ``L`` of a few seeds; grid counts, cheap at that radius) gets
        ``R`` (marked coarse: refined by :meth:`refine` should the search for ``max L`` reach them), the
        rest k-NN bounds.
        """
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

    def ball_kth(self, queries: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """Exact ``L`` of ``queries`` where it is at most ``radius``, else NaN."""
        rows, vals = [], []
        for s, g in self.groups:
            for sel, lens, j in self.space.ball(s, g, queries, radius / s):
                rows.append(np.repeat(sel, lens))
                vals.append(self.space.dist(queries[rows[-1]], j) * s)
        out = np.full(len(queries), np.nan, np.float32)
        # Sorted by (row, value) in one uint64 sort: the row in the high word, the float32 bits in the low word
        # (the bits of non-negative floats order as the floats; ``+ 0`` turns a -0.0 into +0.0).
        vals = np.concatenate(vals) + np.float32(0)
        key = np.concatenate(rows).astype(np.uint64) << np.uint64(32)
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
        """Whether at least ``MinPts`` matches lie within ``radius`` of each query (scaled distances): the
        grid counts, and where they do not settle it, the float32 distances (whole rows for a few queries,
        :meth:`ball_core` for more)."""
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
        """Whether at least ``MinPts`` matches lie within ``radius`` of each query (scaled distances).

        The same test as ``ball_kth(queries, radius) <= radius`` (the k-th smallest of the same float32
        distances is within ``radius`` exactly when k of them are), by counting instead of sorting.
        """
        count = np.zeros(len(queries), np.int64)
        for s, g in self.groups:
            for sel, lens, j in self.space.ball(s, g, queries, np.full(len(queries), radius / s), p=p):
                rows = np.repeat(sel, lens)
                hit = self.space.dist(queries[rows], j) * s <= radius
                count += np.bincount(rows[hit], minlength=len(queries))
        return count >= self.k

    def dense_kth(self, queries: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """Exact ``L`` of ``queries`` (for the few far matches) from whole rows of distances to the least-scaled
        group, and from the matches of the other groups within ``upper`` (their ``L`` bound; a ball search).

        Only the matches within ``L`` decide the k-th smallest, and ``upper >= L``; when the least-scaled group
        has fewer than ``MinPts`` matches (``upper`` then comes from every group), the rows are whole.
        """
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
            rows, vals = [], []
            for s, g in self.groups[1:]:
                for sel, lens, j in self.space.ball(s, g, q, upper[q] / s):
                    rows.append(np.repeat(sel, lens))
                    vals.append(self.space.dist(q[rows[-1]], j) * s)
            rows = np.concatenate(rows) if rows else np.empty(0, np.int64)
            vals = np.concatenate(vals) if vals else np.empty(0, np.float32)
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
        """Exact ``L`` (into ``kth``) of ``rows`` from the largest upper bound down, until no bound left
        reaches the largest ``L`` in ``kth``: the largest ``L`` of ``rows`` is then in ``kth``."""
        rows = rows[np.argsort(-upper[rows], kind="stable")]
        for b in range(0, len(rows), 64):
            batch = rows[b : b + 64]
            batch = batch[upper[batch] >= np.nanmax(kth)]
            if len(batch) == 0:
                break
            kth[batch] = self.dense_kth(batch, upper)

    def clustered(self, mu: float) -> np.ndarray:
        """Matches that DBSCAN clusters with ``eps = min L + mu (max L - min L)``, as the dense computation.

        ``min L`` is found by a ball search of radius ``min upper`` (small), ``max L`` from whole rows of
        distances, taken from the largest upper bound down until no upper bound exceeds the largest ``L``
        found (a few rows; in the second round, the coarse bounds last). A match is core when at least
        ``MinPts`` matches lie within ``eps`` (scaled; counted on grids, see :meth:`core`), and clustered
        when it is core or within ``eps`` of a core match (counted on a grid of the core matches).
        """
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


def _clustered(space: _MotionSpace, min_pts: int, mu: float, col_scale: np.ndarray | None) -> np.ndarray:
    """Matches that DBSCAN puts in a cluster, with the adaptive eps of Sec. III-B.

    ``col_scale`` multiplies the distances *to* each match (second round: 1 or 100); a non-core match ``j``
    is clustered when some core ``i`` has ``d_ij * col_scale[j] <= eps``.
    """
    scale = np.ones(space.n, np.float32) if col_scale is None else col_scale.astype(np.float32)
    return _Round(space, scale, min_pts).clustered(mu)


def _added_matches(x: np.ndarray, y: np.ndarray, n_noise: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """The demo's random matches: uniform in ``[0, max]`` of each coordinate of the real matches, image 1 first.

    An integer ``rng`` draws as GNU Octave's ``rand`` after ``rand('state', rng)`` (and as Python's
    ``random.Random(rng)``: the Mersenne twister seeded by ``init_by_array([rng])``, 53-bit doubles); a
    ``rand(n, 2)`` fills its first column, then its second.
    """
    if isinstance(rng, np.random.Generator):
        u = rng.random(4 * n_noise)
    else:
        draw = random.Random(None if rng is None else int(rng)).random
        u = np.array([draw() for _ in range(4 * n_noise)], np.float64)
    u = u.reshape(2, 2, n_noise)  # (image, coordinate, match)
    return u[0].T * x.max(0), u[1].T * y.max(0)


@match_filter(label="RFM-SCAN", merge="merge_coincident")
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

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    %(scores_unused)s
    image_size1, image_size2 : (int, int)
        Image sizes (width, height); validated only (the added random matches span the matches' own
        coordinates, as in the authors' demo).
    %(shapes_unused)s
    gamma : float, default 10
        Amplification of the motion distance for nearby matches, Eq. (3) (Sec. IV-A).
    pct : float, default 0.05
        ``MinPts`` as a fraction of the matches (Sec. IV-A: 0.02-0.05).
    min_pts_bounds : (int, int), default (3, 30)
        Range of ``MinPts``.
    mu : (float, float), default (0.1, 0.08)
        ``eps`` rates of the two rounds (Sec. III-B, IV-A).
    add_noise : bool, default True
        Add ``round(min(0.05 K, 20))`` uniform random matches before clustering (authors' demo).
    rng : None, int or numpy.random.Generator, default 0
        Seed of the added matches. An integer ``s`` (or None: fresh entropy) draws them as GNU Octave's
        ``rand`` after ``rand('state', s)`` (Python's ``random.Random(s)``, the same Mersenne twister), so
        the default reproduces the authors' demo run under Octave with its random state reset to 0; a
        Generator draws with its ``random``.
    merge_coincident : bool, default True
        Decide coincident candidates once (see Notes); False clusters the rows as given, as the authors'
        code does.

    Returns
    -------
    %(keep)s

    Notes
    -----
    %(coincident)s
    A location counts once in the density counts. The authors' demo (StaRainJ/RFM-SCAN, Demo_main.m) clusters
    the rows as given, with no step for them (silent: our choice). Without it, MinPts copies of a row (3 below
    about 65 candidates) are a core point of DBSCAN by themselves. ``N`` (for MinPts and the added random
    matches) counts distinct matches. ``merge_coincident=False`` clusters the rows as given, as the authors'
    code does.

    The authors' code (StaRainJ/RFM-SCAN: ``Demo_main.m``, ``myDist.m``, ``GetParamater.m``, ``DBSCAN.m``),
    where Bellavia's paper and Jiang et al.'s are silent: ``mapminmax`` of every coordinate of ``[x, y, y - x]``
    to [0, 1]; Eq. (3) with Euclidean keypoint and motion distances; ``MinPts = min(max(round(pct N'), 3),
    30)`` with ``N'`` the rows including the added random matches (MATLAB's ``round``, halves away from zero);
    ``L`` the ``MinPts``-th smallest distance of each row, itself (0) included, over every row (the added
    matches too); DBSCAN's clusters are every core row (``MinPts`` rows within ``eps``, ``<=``) and every row
    within ``eps`` of one, whatever the visiting order; the second round multiplies by 100 the distances to
    the rows (columns) that the first round left unclustered, the added matches always among them; the kept
    rows are the real ones in a cluster. The added matches (``round(min(0.05 N, 20))``) are uniform in ``[0,
    max]`` of each coordinate of the real keypoints, image 1 drawn before image 2; with ``rng=0`` they are
    Octave's draws after ``rand('state', 0)``. Our port follows all of this (before this alignment: the added
    matches spanned the image sizes, drawn by NumPy, and Python's ``round``).

    Measured against the authors' code under GNU Octave 7.3 (``benchmarks/ref_rfm_scan.py``; 6 shared pairs
    per dataset, 1500 keypoints; Jaccard of the keep masks, P / R ours vs theirs)::

        OMP_NUM_THREADS=1 CTXMATCH_DATA=... python benchmarks/bench_filters_ref.py \
            --ref rfm_scan=/tmp/ref/RFM-SCAN --pairs 6 --configs baseline best [--param rfm_scan:merge_coincident=false]

    ``merge_coincident=False``: every mask identical (Jaccard 1.000) in the four configuration x dataset cells.
    Default: 1.000 on ``best`` (HarrisZ + SOSNet, no coincident rows); baseline (SIFT, 2-5 % coincident rows)
    planar 0.986 (P / R 71.6 / 86.6 vs 72.2 / 86.9), non-planar 0.866 (43.9 / 77.4 vs 47.9 / 76.6: kusvod2/zoom
    and booksh, where the copies are dense enough to move ``eps``). The original is random: over Octave states
    0-5 its masks agree with its state-0 mask at Jaccard 0.95-0.985 (means per cell). Its masks do not depend
    on the row order (``--permutations 1``: Jaccard 1.000). Before this alignment: Jaccard 0.962 / 0.846 /
    0.975 / 0.954 (baseline planar / non-planar, best planar / non-planar). Ours takes 1-7 % of its CPU time.
    At the paper's scale (the 55 shared pairs, baseline, no model; ``benchmarks/ablate_peer_filters.py --sweep
    rfm_scan:merge_coincident=true,false --pairs 40``): planar P / R 54.2 / 91.1, non-planar 49.2 / 80.6 by
    default; 55.0 / 93.1 and 51.0 / 79.9 with ``merge_coincident=False`` (the original's own result on our
    candidates); 52.3 / 93.8 and 45.1 / 85.7 before this alignment (``figures/paper/tables.md``); the paper's
    Table 2 (as quoted there) 57.7 / 92.8 and 54.0 / 92.7. The non-planar recall gap (12 points) is the
    original's on our data.

    Speed at real sizes (issues 22 and 33; ``CTXMATCH_DATA=... python benchmarks/bench_filters_real.py
    --pairs 3 --repeat 2 --filters rfm_scan``, process time; sift-rootsift, paper-best-overlap, 8000
    keypoints, 19 033 - 30 155 candidates): 2.33 - 2.38x DTM's time summed over the three pairs, 2.42 -
    2.47x on the worst pair (three runs), with the same keep masks as before (4.85x / 6.25x before the grid
    counts and coarse bounds; in one process, the earlier code 6.10x / 4.60x / 4.02x DTM on
    kusvod2/Brussels / Leuven1 / hpatches v_wormhole 1-4, this one 2.44x / 2.40x / 2.19x).

    References
    ----------
    X. Jiang, J. Ma, J. Jiang, X. Guo, "Robust feature matching using spatial clustering with heavy
    outliers", IEEE TIP 29, 2020.
    M. Ester, H.-P. Kriegel, J. Sander, X. Xu, "A density-based algorithm for discovering clusters in large
    spatial databases with noise", KDD 1996.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
    >>> y = g + (7.0, -3.0)
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = rfm_scan_filter(g, y, np.c_[np.arange(64), np.arange(64)], image_size1=(400, 300),
    ...                        image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 63)
    """
    gamma = check_positive(gamma, "gamma", allow_zero=True)
    pct = check_positive(pct, "pct", allow_zero=True)
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
    first = _clustered(space, min_pts, mu[0], None)
    # Second round: only first-round clustered real matches stay near (Sec. III-C).
    ci = np.zeros(n_all, bool)
    ci[:n] = first[:n]
    return _clustered(space, min_pts, mu[1], np.where(ci, 1.0, 100.0).astype(np.float32))[:n]
