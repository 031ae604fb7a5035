"""The per-pair state of blob matching: sorted best entries of every row and column of D.

Blob matching only ever looks at the few best entries of each row and column of the distance matrix
(pre-filter of Eqs. 10-11, second-best search of Eqs. 13-14), plus, rarely, a whole row or column. A
:class:`BlobContext` computes the ``T`` best entries of every row and column in one pass over D, in row
blocks, without ever holding D in float64 nor any n×n matrix. Every setup of the grid of Sec. 5.2 then
reuses it: the candidate set G depends only on (f, ∩/∪, f'), the ranking only on (t_o, D, W).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from .overlap import ellipse_overlap_error

__all__ = ["BlobContext", "SortedLists"]

_MiB = 1 << 20


@dataclass(frozen=True)
class SortedLists:
    """The ``T`` best entries of every row (or column) of D.

    ``idx[r]`` and ``val[r]`` (distances, float64) are sorted by (value, index): exactly the first ``T``
    entries of the line in the order of blob matching's tie-break. ``complete`` is True when ``T`` is the
    whole line.
    """

    idx: np.ndarray  # (N, T) int64
    val: np.ndarray  # (N, T) float64
    complete: bool


def _first_t(group, other, value, n_groups: int, n_other: int, T: int, squared: bool):
    """From candidate entries (every group holds at least T), keep the T best per group.

    Within a group the order is by value, then by the other index (blob matching's tie-break).
    Returns ``idx`` (n_groups, T) int64 and ``val`` (n_groups, T) float64 distances.
    """
    gb, ob = max(1, int(n_groups - 1).bit_length()), max(1, int(n_other - 1).bit_length())
    if value.dtype == np.float32 and gb + ob <= 32:
        # One int64 sort: the bits of a non-negative float32 are monotone in its value (31 bits).
        bits = (np.maximum(value, 0) + np.float32(0)).view(np.uint32).astype(np.int64)
        key = np.sort((group.astype(np.int64) << (31 + ob)) | (bits << ob) | other)
        g, o = key >> (31 + ob), key & ((1 << ob) - 1)
        v = ((key >> ob) & 0x7FFFFFFF).astype(np.uint32).view(np.float32)
    else:
        order = np.lexsort((other, value, group))
        g, o, v = group[order], other[order], value[order]
    starts = np.searchsorted(g, np.arange(n_groups))
    pos = np.arange(len(g)) - starts[g]
    keep = pos < T
    idx = np.empty((n_groups, T), np.int64)
    val = np.empty((n_groups, T), np.float64)
    idx[g[keep], pos[keep]] = o[keep]
    vv = np.maximum(v[keep].astype(np.float64), 0)
    val[g[keep], pos[keep]] = np.sqrt(vv) if squared else vv
    return idx, val


def _group_size(size: int, T: int) -> int:
    return int(np.clip(size // (8 * T), 1, 16))


def _row_thresholds(block: np.ndarray, T: int, G: int) -> np.ndarray:
    """Per-row value ``tau`` with at least ``T`` entries ``<= tau``: the T-th smallest of group minima.

    The columns are split into interleaved groups of ``G``; T distinct groups each have an entry no larger
    than the T-th smallest group minimum, so the bound holds, and it is tight up to a few entries.
    """
    B, m = block.shape
    if T >= m:
        return np.full(B, np.inf)
    mg = (m // G) * G
    gmin = block[:, :mg].reshape(B, G, mg // G).min(axis=1) if G > 1 else block
    if G > 1 and mg < m:
        gmin = np.hstack([gmin, block[:, mg:]])
    return np.partition(gmin, T - 1, axis=1)[:, T - 1]


def _column_group_minima(block: np.ndarray, G: int) -> np.ndarray:
    B = block.shape[0]
    bg = (B // G) * G
    parts = [block[:bg].reshape(bg // G, G, -1).min(axis=1)] if bg else []
    if bg < B:
        parts.append(block[bg:])
    return np.vstack(parts)


class BlobContext:
    """Per-pair state of blob matching (Sec. 3): best entries of the rows and columns of D.

    Parameters
    ----------
    desc1, desc2 : ndarray of shape (n, d) and (m, d), optional
        Descriptors; D is their L2 distance (on RootSIFT descriptors, the Hellinger distance). Computed in
        float32 (float64 if a descriptor array is float64), in row blocks.
    distances : ndarray of shape (n, m), optional
        A precomputed distance matrix instead of descriptors.
    distance : callable, optional
        The descriptors' own distance instead of L2: ``distance(desc1[r0:r1], desc2)`` returns the
        ``(r1 - r0, m)`` block of non-negative distances (e.g. the sGLOH2 rotation-min distance,
        :class:`ctxmatch_lib.features.sgloh.SGLOH2Distance`). It is called on row blocks of about
        ``block_bytes`` and on a few rows or columns (``distance(desc1, desc2[cols])``), so D is never held
        whole unless ``keep_dense``; the hook itself should need O(block) memory.
    kpts1, kpts2 : ndarray of shape (n, 2) and (m, 2), optional
        Keypoints (x, y) in pixels, origin at the centre of the top-left pixel; needed by FGINN.
    shapes1, shapes2 : ndarray of shape (n, 2, 2) and (m, 2, 2), optional
        Affine shapes of the elliptical patches; needed by FGINN by overlap.
    depth : int
        Largest ``f`` (and ``f'``) this context will serve.
    keep_dense : bool, optional
        Keep D in memory (needed by f = Ω, speeds up rare full-row look-ups). Default: when it takes at
        most 256 MiB.
    max_dense_bytes : int
        Above this size f = Ω fails fast with a ``MemoryError`` stating the memory it needs.

    Notes
    -----
    Inputs are assumed validated by :func:`ctxmatch_lib.blob.blob_matching`.
    """

    margin = 22  # extra entries per line beyond `depth`, so FGINN and D≥ rarely need a whole line

    def __init__(self, desc1=None, desc2=None, *, distances=None, kpts1=None, kpts2=None, shapes1=None,
                 shapes2=None, depth: int = 10, keep_dense: bool | None = None,
                 max_dense_bytes: int = 1024 * _MiB, block_bytes: int = 64 * _MiB, distance=None):
        self.kpts = (kpts1, kpts2)
        self.shapes = (shapes1, shapes2)
        self.max_dense_bytes = int(max_dense_bytes)
        self._metric = None
        if distances is not None:
            D = np.asarray(distances)
            if D.dtype not in (np.float32, np.float64):
                D = D.astype(np.float64)
            self.n, self.m = D.shape
            self._squared = False
            self._A = self._B = None
            self._dtype = D.dtype
            self._dense = D
        elif distance is not None:
            if not callable(distance):
                raise ValueError(f"distance must be callable, got {type(distance).__name__}")
            self._metric = distance
            self._dtype = np.dtype(np.result_type(desc1.dtype, desc2.dtype, np.float32))
            self._A = np.asarray(desc1, self._dtype)
            self._B = np.asarray(desc2, self._dtype)
            self.n, self.m = len(self._A), len(self._B)
            self._squared = False
            self._dense = None
            dense_bytes = self.n * self.m * self._dtype.itemsize
            if keep_dense is None:
                keep_dense = dense_bytes <= 256 * _MiB
            if keep_dense:
                self._check_dense(dense_bytes, "f='omega' (keep_dense=True)")
        else:
            dtype = np.result_type(desc1.dtype, desc2.dtype, np.float32)
            a = np.asarray(desc1, dtype)
            b = np.asarray(desc2, dtype)
            self.n, self.m = len(a), len(b)
            self._squared = True
            # Augmented vectors: A @ B.T = |a|^2 + |b|^2 - 2 a.b = squared L2, straight out of one GEMM.
            self._A = np.hstack([a, np.einsum("ij,ij->i", a, a)[:, None], np.ones((self.n, 1), dtype)])
            self._B = np.hstack([-2 * b, np.ones((self.m, 1), dtype), np.einsum("ij,ij->i", b, b)[:, None]])
            self._dtype = np.dtype(dtype)
            self._dense = None
            dense_bytes = self.n * self.m * np.dtype(dtype).itemsize
            if keep_dense is None:
                keep_dense = dense_bytes <= 256 * _MiB
            if keep_dense:  # fail fast, before any work
                self._check_dense(dense_bytes, "f='omega' (keep_dense=True)")
        self.depth = int(depth)
        # One BLAS thread: OpenBLAS's float32 rounding depends on the thread count, and the candidates and
        # scores must not (the same tables on any machine setting).
        with threadpool_limits(1):
            self._scan(bool(keep_dense) if distances is None else True, block_bytes)

    # -- the one pass over D ------------------------------------------------------------------------
    def _block(self, r0: int, r1: int, out: np.ndarray | None = None) -> np.ndarray:
        if self._dense is not None:
            return self._dense[r0:r1]
        if self._metric is not None:
            blk = self._hook(self._A[r0:r1], self._B)
            if out is None:
                return blk
            out[...] = blk
            return out
        return np.matmul(self._A[r0:r1], self._B.T, out=out)

    def _hook(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        blk = np.asarray(self._metric(a, b))
        if blk.shape != (len(a), len(b)):
            raise ValueError(f"distance returned shape {blk.shape}, expected {(len(a), len(b))}")
        return blk.astype(self._dtype, copy=False)

    def _scan(self, keep_dense: bool, block_bytes: int) -> None:
        n, m = self.n, self.m
        Tr = min(m, self.depth + self.margin)
        Tc = min(n, self.depth + self.margin)
        Gr, Gc = _group_size(m, Tr), _group_size(n, Tc)
        itemsize = self._dtype.itemsize
        rows_per_block = max(Gc, (block_bytes // max(1, m * itemsize)) // Gc * Gc)
        dense = None
        if keep_dense and self._dense is None:
            dense = np.empty((n, m), self._dtype)
        r_g, r_o, r_v, col_min = [], [], [], []
        for r0 in range(0, n, rows_per_block):
            r1 = min(n, r0 + rows_per_block)
            blk = self._block(r0, r1, out=None if dense is None else dense[r0:r1])
            tau = _row_thresholds(blk, Tr, Gr)
            flat = np.flatnonzero(blk <= tau[:, None])
            r_g.append(flat // m + r0)
            r_o.append(flat % m)
            r_v.append(blk.ravel()[flat])
            if Tc < n:
                col_min.append(_column_group_minima(blk, Gc))
        if dense is not None:
            self._dense = dense
        self.rows = SortedLists(*_first_t(np.concatenate(r_g), np.concatenate(r_o), np.concatenate(r_v),
                                          n, m, Tr, self._squared), complete=Tr == m)
        # Columns: thresholds from the group minima of all blocks, then a second look at each block.
        tau_c = (np.partition(np.vstack(col_min), Tc - 1, axis=0)[Tc - 1] if Tc < n
                 else np.full(m, np.inf))
        c_g, c_o, c_v = [], [], []
        for r0 in range(0, n, rows_per_block):
            r1 = min(n, r0 + rows_per_block)
            blk = self._block(r0, r1)
            flat = np.flatnonzero(blk <= tau_c[None, :])
            c_g.append(flat % m)
            c_o.append(flat // m + r0)
            c_v.append(blk.ravel()[flat])
        g, o, v = np.concatenate(c_g), np.concatenate(c_o), np.concatenate(c_v)
        # Candidates come row-major; a stable sort by column keeps rows ascending within ties.
        self.cols = SortedLists(*_first_t(g, o, v, m, n, Tc, self._squared), complete=Tc == n)

    # -- whole rows / columns, for the rare look-ups beyond the sorted lists ------------------------
    def _check_dense(self, nbytes: int, what: str) -> None:
        if nbytes > self.max_dense_bytes:
            raise MemoryError(
                f"{what} needs the full {self.n}x{self.m} distance matrix: {nbytes / 2**30:.2f} GiB, above "
                f"max_dense_bytes={self.max_dense_bytes / 2**30:.2f} GiB; use a finite f (f=10 is as good, "
                "Sec. 5.2) or raise max_dense_bytes"
            )

    def _ensure_dense(self) -> np.ndarray:
        if self._dense is None:
            with threadpool_limits(1):
                self._dense = self._dense_matrix()
        return self._dense

    def _dense_matrix(self) -> np.ndarray:
        self._check_dense(self.n * self.m * self._dtype.itemsize, "f='omega'")
        if self._metric is None:
            return self._A @ self._B.T
        dense = np.empty((self.n, self.m), self._dtype)
        step = max(1, (64 * _MiB) // max(1, self.m * self._dtype.itemsize))
        for r0 in range(0, self.n, step):
            dense[r0 : r0 + step] = self._hook(self._A[r0 : r0 + step], self._B)
        return dense

    def _lines(self, side: int, which: np.ndarray) -> np.ndarray:
        """Whole rows (side 0) or columns (side 1) of D as float64 distances."""
        if self._dense is not None:
            raw = self._dense[which] if side == 0 else self._dense[:, which].T
        elif self._metric is not None:
            # Columns as distance(desc1, desc2[cols]): the hook need not be symmetric.
            with threadpool_limits(1):
                raw = self._hook(self._A[which], self._B) if side == 0 else self._hook(self._A, self._B[which]).T
        else:
            with threadpool_limits(1):
                raw = self._A[which] @ self._B.T if side == 0 else self._B[which] @ self._A.T
        raw = np.asarray(raw, np.float64)
        return np.sqrt(np.maximum(raw, 0)) if self._squared else raw

    # -- steps 1-2: candidate set G ------------------------------------------------------------------
    def candidates(self, f, prefilter: str = "cup", f_prime: int = 5) -> tuple[np.ndarray, np.ndarray]:
        """Steps 1-2 of Sec. 3: pre-filter F (Eq. 10 or 11) and greedy many-to-many selection with f'.

        Returns
        -------
        matches : ndarray of shape (K, 2)
            G in the order the greedy accepted it (increasing distance; ties by row, then column).
        dist : ndarray of shape (K,)
            D entries of the matches.
        """
        n, m = self.n, self.m
        if n == 0 or m == 0:
            return np.empty((0, 2), np.int64), np.empty(0)
        if f == "omega" or (f >= n and f >= m):
            return self._greedy_dense(f_prime)
        if f > self.depth:
            raise ValueError(f"f={f} exceeds the depth={self.depth} this BlobContext was built for")
        fr, fc = min(f, m), min(f, n)
        ri = np.repeat(np.arange(n, dtype=np.int64), fr)
        rj = self.rows.idx[:, :fr].ravel()
        cj = np.repeat(np.arange(m, dtype=np.int64), fc)
        ci = self.cols.idx[:, :fc].ravel()
        rk, ck = ri * m + rj, ci * m + cj
        if prefilter == "cup":
            keys = np.concatenate([rk, ck])
            vals = np.concatenate([self.rows.val[:, :fr].ravel(), self.cols.val[:, :fc].ravel()])
            keys, first = np.unique(keys, return_index=True)
            vals = vals[first]
        else:
            keys, pos, _ = np.intersect1d(rk, ck, assume_unique=True, return_indices=True)
            vals = self.rows.val[:, :fr].ravel()[pos]
        order = np.lexsort((keys, vals))  # by value, then row, then column
        keys, vals = keys[order], vals[order]
        accepted = _greedy(keys // m, keys % m, n, m, f_prime)
        keys = keys[accepted]
        return np.stack([keys // m, keys % m], axis=1), vals[accepted]

    def _greedy_dense(self, f_prime: int):
        """Greedy over all of D (f = Ω) without sorting D.

        A heap holds each row's next entry in (value, column) order. Saturated columns stay saturated, so
        a row skips them when it advances; past its sorted list, the next entry of a row is found with one
        vectorised scan of the row.
        """
        D = self._ensure_dense()
        n, m = self.n, self.m
        T = self.rows.idx.shape[1]
        lidx, lval = self.rows.idx.tolist(), self.rows.val.tolist()
        cols = np.arange(m)
        col_full = np.zeros(m, bool)
        rc, cc = [0] * n, [0] * m
        ptr = [0] * n
        heap = [(lval[i][0], i, lidx[i][0]) for i in range(n)]
        heapq.heapify(heap)

        def push_next(i: int, d: float, j: int) -> None:
            p = ptr[i] + 1
            while p < T:
                jj = lidx[i][p]
                if cc[jj] < f_prime:
                    ptr[i] = p
                    heapq.heappush(heap, (lval[i][p], i, jj))
                    return
                p += 1
            if ptr[i] < T:  # leaving the sorted list: continue after its last entry
                ptr[i] = T
                d, j = lval[i][T - 1], lidx[i][T - 1]
            if T == m:
                return
            row = np.asarray(D[i], np.float64)
            row = np.sqrt(np.maximum(row, 0)) if self._squared else row
            ok = ~col_full & ((row > d) | ((row == d) & (cols > j)))
            cand = np.flatnonzero(ok)
            if len(cand):
                k = int(cand[np.argmin(row[cand])])  # first minimum: ties go to the lowest column
                heapq.heappush(heap, (float(row[k]), i, k))

        out_i, out_j, out_d = [], [], []
        free_cols = m
        while heap and free_cols:
            d, i, j = heapq.heappop(heap)
            if cc[j] < f_prime:
                out_i.append(i)
                out_j.append(j)
                out_d.append(d)
                rc[i] += 1
                cc[j] += 1
                if cc[j] == f_prime:
                    col_full[j] = True
                    free_cols -= 1
            if rc[i] < f_prime:
                push_next(i, d, j)
        G = np.stack([np.asarray(out_i, np.int64), np.asarray(out_j, np.int64)], axis=1).reshape(-1, 2)
        return G, np.asarray(out_d, np.float64)

    # -- step 3: NNR-like ratios ---------------------------------------------------------------------
    def second_best(self, side: int, anchors: np.ndarray, others: np.ndarray, dist: np.ndarray, *,
                    geq: bool, t_o: float | None, t_o_kind: str = "px") -> np.ndarray:
        """Denominator entry of Eqs. (13)-(14) for each match.

        For side 0 (image 1 as reference) ``anchors`` are rows ``i`` and ``others`` the matched columns
        ``j``; the result is the lowest entry of row ``i`` over columns ``k != j`` that FGINN does not
        exclude (keypoint ``k`` of image 2 at least ``t_o`` pixels from ``j``, or with overlap error above
        ``t_o``), restricted to entries ``>= D_ij`` when ``geq``. Side 1 is the same on columns. ``inf``
        when no entry qualifies.
        """
        lists = self.rows if side == 0 else self.cols
        out = np.full(len(anchors), np.inf)
        if len(anchors) == 0:
            return out
        cand, vals = lists.idx[anchors], lists.val[anchors]
        ok = ~self._excluded(1 - side, cand, others, t_o, t_o_kind)
        if geq:
            ok &= vals >= dist[:, None]
        out[:] = np.where(ok, vals, np.inf).min(axis=1)
        if not lists.complete:
            # Nothing qualified among the T best: scan the whole line (rare).
            miss = np.flatnonzero(~ok.any(axis=1))
            size = self.m if side == 0 else self.n
            step = max(1, (8 * _MiB) // (8 * size))
            for s in range(0, len(miss), step):
                sel = miss[s : s + step]
                line = self._lines(side, anchors[sel])
                cand = np.broadcast_to(np.arange(size), line.shape)
                ok = ~self._excluded(1 - side, cand, others[sel], t_o, t_o_kind)
                if geq:
                    ok &= line >= dist[sel, None]
                out[sel] = np.where(ok, line, np.inf).min(axis=1)
        return out

    def _excluded(self, img: int, cand: np.ndarray, other: np.ndarray, t_o, t_o_kind) -> np.ndarray:
        """Which candidates ``cand`` (K, L) of image ``img`` the second-best search skips for ``other``."""
        same = cand == other[:, None]
        if t_o is None:
            return same
        pts = self.kpts[img]
        if t_o_kind == "px":
            d2 = np.sum((pts[cand] - pts[other][:, None, :]) ** 2, axis=-1)
            return same | (d2 < t_o * t_o)
        return same | (self.overlap_errors(img, other, cand) <= t_o)

    def overlap_errors(self, img: int, other: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """Overlap errors ``(K, L)`` between keypoint ``other[k]`` and ``cand[k, l]`` of image ``img``.

        The one place FGINN by overlap computes patch overlaps; sweeps override it with a table look-up.
        """
        pts, shapes = self.kpts[img], self.shapes[img]
        K, L = cand.shape
        anchor = np.broadcast_to(other[:, None], (K, L)).ravel()
        err = ellipse_overlap_error(pts[anchor], shapes[anchor], pts[cand.ravel()], shapes[cand.ravel()])
        return err.reshape(K, L)


def _greedy(rows: np.ndarray, cols: np.ndarray, n: int, m: int, f_prime: int) -> np.ndarray:
    """Step 2 of Sec. 3 on entries already sorted: accept while row and column counts stay <= f'."""
    rc, cc = [0] * n, [0] * m
    acc = []
    for k, (i, j) in enumerate(zip(rows.tolist(), cols.tolist())):
        if rc[i] < f_prime and cc[j] < f_prime:
            rc[i] += 1
            cc[j] += 1
            acc.append(k)
    return np.asarray(acc, np.int64)
