"""The per-pair state of blob matching (Sec. 3): :class:`BlobContext` keeps the ``T`` best entries of every
row and column of D from one pass over it (Eqs. 10-11 and 13-14 read only those, and rarely a whole line).
The setups of Sec. 5.2 share one context: G depends only on (f, ∩/∪, f'), the ranking on (t_o, D, W)."""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from .._numerics.blas import one_blas_thread
from . import _kernels, _select_kernels, _walk_kernels
from ._fused_kernels import fused_product_fast
from ._pass import fused_pass, tile_pass
from ._workspace import give_back, take_codes
from ._lists import _column_group_minima, _first_t, _group_size, _row_thresholds
from .overlap import _largest_singular_value, circle_overlap_bounds, ellipse_overlap_error

__all__ = ["BlobContext", "SortedLists"]

_MiB = 1 << 20


#: The most memory per side that :class:`LineMemo` keeps computed lines in (2 bytes an entry).
LINE_MEMO_BYTES = 32 * _MiB


def coded_lines(own: np.ndarray, other: np.ndarray, n_own: np.ndarray, n_other: np.ndarray, which: np.ndarray,
                qoff, qinv) -> np.ndarray:
    """Codes (:func:`._kernels.encode`) of ``|a|² + |b|² − 2 a·b`` from the float32 rows ``own[which]`` to
    every row of ``other``, about 8 MiB of float32 at a time on one BLAS thread."""
    out, step = np.empty((len(which), len(other)), np.uint16), max(1, (8 * _MiB) // (4 * len(other)))
    for s in range(0, len(which), step):
        w = which[s : s + step]
        with one_blas_thread():
            g = own[w] @ other.T
        g *= np.float32(-2)
        g += n_own[w][:, None]
        out[s : s + step] = _kernels.encode(g + n_other[None, :], qoff, qinv)
    return out


class LineMemo:
    """The lines of one side computed so far (up to :data:`LINE_MEMO_BYTES`): :meth:`get` computes the
    missing ones and returns copies, so a sweep computes each line once."""

    def __init__(self, n_lines: int, line_len: int):
        self.keep = n_lines * line_len * 2 <= LINE_MEMO_BYTES
        self._shape = (n_lines, line_len)
        self._codes = self._have = None

    def get(self, which: np.ndarray, compute) -> np.ndarray:
        which = np.asarray(which, np.int64)
        if not self.keep:
            return compute(which)
        if self._codes is None:
            self._codes, self._have = np.empty(self._shape, np.uint16), np.zeros(self._shape[0], bool)
        need = np.unique(which[~self._have[which]])
        if len(need):
            self._codes[need] = compute(need)
            self._have[need] = True
        return self._codes[which]


@dataclass(frozen=True)
class SortedLists:
    """The ``T`` best entries of every row (or column) of D, sorted by (value, index); ``complete``: ``T`` is
    the whole line."""

    idx: np.ndarray  # (N, T) int64
    val: np.ndarray  # (N, T) float64
    complete: bool


class BlobContext:
    """Per-pair state of blob matching (Sec. 3): best entries of the rows and columns of D.

    Parameters
    ----------
    desc1, desc2, distances, distance, kpts1, kpts2, shapes1, shapes2
        As :func:`~ctxmatch_lib.blob.blob_matching` (which validates them).
    depth : int
        Largest ``f`` (and ``f'``) this context will serve.
    keep_dense : bool, optional
        Keep D, or its 16-bit codes on the L2 path (needed by f = Ω); default: when D fits 256 MiB.
    max_dense_bytes : int
        Above this size (of D, or of its codes) f = Ω raises ``MemoryError``.
    block_bytes : int
        Size of the row blocks a ``distance`` hook is called on.
    margin : int, optional
        Entries kept per line beyond ``depth`` (default :attr:`margin`); speed only.
    columns : bool, default True
        Keep the columns' lists too (the pre-filter and image 2's ratio need them).
    """

    #: Default entries per line beyond ``depth``, so that FGINN and D≥ rarely need a whole line.
    margin = 22

    def __init__(self, desc1=None, desc2=None, *, distances=None, kpts1=None, kpts2=None, shapes1=None,
                 shapes2=None, depth: int = 10, keep_dense: bool | None = None,
                 max_dense_bytes: int = 1024 * _MiB, block_bytes: int = 64 * _MiB, distance=None,
                 margin: int | None = None, columns: bool = True):
        self.kpts = (kpts1, kpts2)
        self.columns = bool(columns)
        self.cols: SortedLists | None = None
        if margin is not None:
            if isinstance(margin, bool) or not isinstance(margin, (int, np.integer)) or margin < 0:
                raise ValueError(f"margin must be a non-negative integer, got {margin!r}")
            self.margin = int(margin)
        self.shapes = (shapes1, shapes2)
        self._radii = [None, None]
        self._line_memo: list = [None, None]  # LineMemo per side, made with the first whole-line look-up
        self.max_dense_bytes = int(max_dense_bytes)
        self._metric = self._A = self._B = self._dense = None
        if distances is not None:
            D = np.asarray(distances)
            if D.dtype not in (np.float32, np.float64):
                D = D.astype(np.float64)
            self.n, self.m = D.shape
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
            dense_bytes = self.n * self.m * self._dtype.itemsize
            if keep_dense is None:
                keep_dense = dense_bytes <= 256 * _MiB
            if keep_dense:
                self._check_dense(dense_bytes, "f='omega' (keep_dense=True)")
        else:
            # L2: float32 products propose, exact float64 distances decide (see _kernels).
            dtype = np.result_type(desc1.dtype, desc2.dtype, np.float32)
            self._X = (np.ascontiguousarray(desc1, dtype), np.ascontiguousarray(desc2, dtype))
            self.n, self.m = len(self._X[0]), len(self._X[1])
            if keep_dense:  # fail fast, before any work
                self._check_dense(self.n * self.m * 2, "f='omega' (keep_dense=True)")
        self._exact = distances is None and distance is None
        self._approx = self._codes = None
        self.depth = int(depth)
        # One BLAS thread: OpenBLAS's float32 rounding depends on the thread count; the results must not.
        with one_blas_thread():
            if self._exact:
                self._scan_exact(bool(keep_dense))
            else:
                self._scan(bool(keep_dense), block_bytes)

    # -- the one pass over D ------------------------------------------------------------------------
    def _blocks(self, step: int):
        """``(r0, D[r0 : r0 + step])`` for every block of ``step`` rows of a precomputed D or of the distance
        hook's (the L2 path has its own pass)."""
        for r0 in range(0, self.n, step):
            yield r0, (self._dense[r0 : r0 + step] if self._dense is not None
                       else self._hook(self._A[r0 : r0 + step], self._B))

    def _hook(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        blk = np.asarray(self._metric(a, b))
        if blk.shape != (len(a), len(b)):
            raise ValueError(f"distance returned shape {blk.shape}, expected {(len(a), len(b))}")
        return blk.astype(self._dtype, copy=False)

    def _scan(self, keep_dense: bool, block_bytes: int) -> None:
        n, m = self.n, self.m
        Tr, Tc = min(m, self.depth + self.margin), min(n, self.depth + self.margin)
        Gr, Gc = _group_size(m, Tr), _group_size(n, Tc)
        rows_per_block = max(Gc, (block_bytes // max(1, m * self._dtype.itemsize)) // Gc * Gc)
        dense = np.empty((n, m), self._dtype) if keep_dense and self._dense is None else None
        r_g, r_o, r_v, col_min = [], [], [], []
        for r0, blk in self._blocks(rows_per_block):
            if dense is not None:
                dense[r0 : r0 + len(blk)] = blk
            tau = _row_thresholds(blk, Tr, Gr)
            flat = np.flatnonzero(blk <= tau[:, None])
            r_g.append(flat // m + r0)
            r_o.append(flat % m)
            r_v.append(blk.ravel()[flat])
            if Tc < n and self.columns:
                col_min.append(_column_group_minima(blk, Gc))
        if dense is not None:
            self._dense = dense
        self.rows = SortedLists(*_first_t(np.concatenate(r_g), np.concatenate(r_o), np.concatenate(r_v),
                                          n, m, Tr), complete=Tr == m)
        if not self.columns:
            return
        # Columns: thresholds from the group minima of all blocks, then a second look at each block.
        tau_c = (np.partition(np.vstack(col_min), Tc - 1, axis=0)[Tc - 1] if Tc < n
                 else np.full(m, np.inf))
        c_g, c_o, c_v = [], [], []
        for r0, blk in self._blocks(rows_per_block):
            flat = np.flatnonzero(blk <= tau_c[None, :])
            c_g.append(flat % m)
            c_o.append(flat // m + r0)
            c_v.append(blk.ravel()[flat])
        g, o, v = np.concatenate(c_g), np.concatenate(c_o), np.concatenate(c_v)
        # Candidates come row-major; a stable sort by column keeps rows ascending within ties.
        self.cols = SortedLists(*_first_t(g, o, v, m, n, Tc), complete=Tc == n)

    #: GEMM tile (rows x columns) of ``product="tiles"``, 2 MiB of float32, scanned while in cache.
    tile = (1024, 512)
    #: Entries per line beyond the T kept: room for the certified band of the float32 rounding (with fewer
    #: than 2, many lines fail the band test and are recomputed whole).
    slack = 4
    #: The pass's float32 product: ``"tiles"`` (BLAS GEMM tiles), ``"fused"`` (:mod:`._fused_kernels`) or
    #: ``"auto"`` (fused where :func:`fused_product_fast`); the results are the same either way.
    product = "auto"

    def _scan_exact(self, keep_dense: bool) -> None:
        """One pass over the float32 products keeps each line's K smallest; exact float64 distances decide."""
        X1, X2 = self._X
        n, m = self.n, self.m
        d = X1.shape[1]
        Tr, Tc = min(m, self.depth + self.margin), min(n, self.depth + self.margin)
        Kr, Kc = min(m, Tr + self.slack), min(n, Tc + self.slack)
        A32 = np.ascontiguousarray(X1, np.float32)
        B32 = np.ascontiguousarray(X2, np.float32)
        self._X32 = (A32, B32)
        # Squared norms summed in float64 (fixed order), rounded once: part of the certified bound.
        nrm1, nrm2 = _kernels.sq_norms(X1), _kernels.sq_norms(X2)
        self._scale = _kernels.error_scale(d)
        self._norms = (nrm1, nrm2)
        # Each line's K best so far, sorted, +inf in empty slots; padded to 16 (16-lane registers).
        Wr, Wc = max(Kr, 16), max(Kc, 16)
        rv, ri = np.full((n, Wr), np.inf, np.float32), np.zeros((n, Wr), np.int64)
        cv, ci = np.full((m, Wc), np.inf, np.float32), np.zeros((m, Wc), np.int64)
        rthr = np.full(n, np.inf, np.float32)
        cthr = np.full(m, np.inf if self.columns else -np.inf, np.float32)  # -inf: no entry enters a column
        dense, self._codes = take_codes(n, m) if keep_dense else (np.empty((1, 1), np.uint16), None)
        n1, n2 = nrm1.astype(np.float32), nrm2.astype(np.float32)
        # 16-bit codes for the look-ups beyond the lists: v is within E_max of an exact one, in [0, (|a| + |b|)²].
        E1, E2 = float(nrm1.max(initial=0.0)), float(nrm2.max(initial=0.0))
        E_max = self._scale * (E1 + E2) if n and m else 0.0
        top = (np.sqrt(E1) + np.sqrt(E2)) ** 2 + E_max
        self._qoff, self._qinv, self._qstep = _kernels.code_scale(-E_max, float(top))
        state = (rv, ri, rthr, cv, ci, cthr, Kr, Kc, dense, keep_dense, self._qoff, self._qinv)
        if self._fused():
            fused_pass(A32, B32, n1, n2, *state, columns=self.columns)
        else:
            tile_pass(A32, B32, n1, n2, *state, tile=self.tile)
        rc = np.count_nonzero(rv[:, :Kr] < np.inf, axis=1)
        self._approx = dense if keep_dense else None
        idx, val = np.empty((n, Tr), np.int64), np.empty((n, Tr))
        self.work = _kernels.certify_lines(X1, X2, rv, ri, rc, Kr, Tr, nrm1, E2, self._scale, idx, val)
        self.rows = SortedLists(idx, val, complete=Tr == m)
        if not self.columns:
            return
        cc = np.count_nonzero(cv[:, :Kc] < np.inf, axis=1)
        idx, val = np.empty((m, Tc), np.int64), np.empty((m, Tc))
        self.work += _kernels.certify_lines(X2, X1, cv, ci, cc, Kc, Tc, nrm2, E1, self._scale, idx, val)
        self.cols = SortedLists(idx, val, complete=Tc == n)

    def release(self) -> None:
        """Hand f = Ω's codes of D back for the next call to reuse (:mod:`._workspace`); the context stays
        usable and recomputes them if asked."""
        if self._codes is not None:
            self._approx, codes, self._codes = None, self._codes, None
            give_back(codes)

    def _fused(self) -> bool:
        """Whether the pass keeps the product in registers (:attr:`product`)."""
        if self.product not in ("auto", "fused", "tiles"):
            raise ValueError(f"BlobContext.product must be 'auto', 'fused' or 'tiles', got {self.product!r}")
        return self.product == "fused" or (self.product == "auto" and fused_product_fast())

    def _line_bounds(self, side: int) -> np.ndarray:
        """Per line of ``side``, the bound E on |decoded code - exact squared distance| (the float32 bound
        plus the codes' step, :func:`._kernels.code_scale`)."""
        own, other = self._norms[side], self._norms[1 - side]
        return self._scale * (own + other.max()) + self._qstep

    def _approx_lines(self, side: int, which: np.ndarray) -> np.ndarray:
        """Coded approximate squared distances of rows (side 0) or columns (side 1) ``which`` of D, within
        :meth:`_line_bounds` of the exact ones (:func:`coded_lines`), kept by :class:`LineMemo`."""
        if self._approx is not None and side == 0:
            return self._approx[which]
        if self._line_memo[side] is None:
            self._line_memo[side] = LineMemo(*((self.n, self.m) if side == 0 else (self.m, self.n)))
        return self._line_memo[side].get(which, lambda w: self._compute_lines(side, w))

    def _compute_lines(self, side: int, which: np.ndarray) -> np.ndarray:
        # Columns by their own GEMM rows: gathering them from the dense matrix reads all of it per chunk.
        return coded_lines(self._X32[side], self._X32[1 - side], self._norms[side].astype(np.float32),
                           self._norms[1 - side].astype(np.float32), which, self._qoff, self._qinv)

    # -- whole rows / columns, for the rare look-ups beyond the sorted lists ------------------------
    def _check_dense(self, nbytes: int, what: str) -> None:
        if nbytes > self.max_dense_bytes:
            raise MemoryError(
                f"{what} needs the full {self.n}x{self.m} distance matrix: {nbytes / 2**30:.2f} GiB, above "
                f"max_dense_bytes={self.max_dense_bytes / 2**30:.2f} GiB; use a finite f (f=10 is as good, "
                "Sec. 5.2) or raise max_dense_bytes"
            )

    def _ensure_dense(self) -> np.ndarray:
        """D itself (precomputed, or the distance hook's, computed on demand)."""
        if self._dense is None:
            self._check_dense(self.n * self.m * self._dtype.itemsize, "f='omega'")
            dense = np.empty((self.n, self.m), self._dtype)
            step = max(1, (64 * _MiB) // max(1, self.m * self._dtype.itemsize))
            with one_blas_thread():
                for r0, blk in self._blocks(step):
                    dense[r0 : r0 + len(blk)] = blk
            self._dense = dense
        return self._dense

    def _lines(self, side: int, which: np.ndarray) -> np.ndarray:
        """Whole rows (side 0) or columns (side 1) of D as float64 (precomputed D or distance hook only)."""
        if self._dense is not None:
            raw = self._dense[which] if side == 0 else self._dense[:, which].T
        else:  # columns as distance(desc1, desc2[cols]): the hook need not be symmetric
            with one_blas_thread():
                raw = self._hook(self._A[which], self._B) if side == 0 else self._hook(self._A, self._B[which]).T
        return np.asarray(raw, np.float64)

    def _need_columns(self, what: str) -> None:
        if self.cols is None:
            raise ValueError(f"{what} needs the columns' lists: this BlobContext was built with columns=False")

    # -- steps 1-2: candidate set G ------------------------------------------------------------------
    def candidates(self, f, prefilter: str = "cup", f_prime: int = 5) -> tuple[np.ndarray, np.ndarray]:
        """Steps 1-2 of Sec. 3: pre-filter F (Eq. 10 or 11) and greedy many-to-many selection with f'.

        Returns G ``(K, 2)`` in the order the greedy accepted it (distance, then row, column) and its
        D entries ``(K,)``.
        """
        n, m = self.n, self.m
        if n == 0 or m == 0:
            return np.empty((0, 2), np.int64), np.empty(0)
        if f == "omega" or (f >= n and f >= m):
            return self._greedy_dense(f_prime)
        if f > self.depth:
            raise ValueError(f"f={f} exceeds the depth={self.depth} this BlobContext was built for")
        fr, fc = min(f, m), min(f, n)
        self._need_columns("the pre-filter (f < Ω)")
        rows, cols, vals = _select_kernels.prefilter_lists(self.rows.idx, self.rows.val, self.cols.idx,
                                                           self.cols.val, fr, fc, prefilter == "cup")
        # By value, then row, then column.
        order = _select_kernels.break_ties(np.argsort(vals), vals, rows, cols)
        rows, cols, vals = rows[order], cols[order], vals[order]
        accepted = _select_kernels.greedy_sorted(rows, cols, n, m, int(f_prime))
        return np.stack([rows[accepted], cols[accepted]], axis=1), vals[accepted]

    def _greedy_dense(self, f_prime: int):
        """Greedy over all of D (f = Ω) without sorting it: a heap of each row's next entry in (value, column)
        order, skipping saturated columns."""
        if self._exact:
            if self._approx is None:  # the codes of all of D, computed on demand
                self._check_dense(self.n * self.m * 2, "f='omega'")
                self._approx = self._compute_lines(0, np.arange(self.n))
            X1, X2 = self._X
            gi, gj, gd = _walk_kernels.greedy_dense(self._approx, X1, X2, self.rows.idx, self.rows.val,
                                                    self._line_bounds(0), int(f_prime), self._qoff, self._qstep)
            return np.stack([gi, gj], axis=1).reshape(-1, 2), gd
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
        """Denominator entry of Eqs. (13)-(14) for each match: for side 0, the lowest entry of row
        ``anchors[r]`` over columns ``k != others[r]`` that FGINN keeps, ``>= dist[r]`` when ``geq``; side 1
        the same on columns; ``inf`` when none qualifies."""
        if side == 1:
            self._need_columns("image 2's ratio (side 1)")
        lists = self.rows if side == 0 else self.cols
        out = np.full(len(anchors), np.inf)
        if len(anchors) == 0:
            return out
        anchors, others = np.asarray(anchors, np.int64), np.asarray(others, np.int64)
        dist = np.asarray(dist, np.float64)
        if t_o is not None and t_o_kind == "overlap":
            first = self._first_not_overlapping(1 - side, lists, anchors, others, dist, geq, t_o)
            ok = first >= 0
            out[ok] = lists.val[anchors[ok], first[ok]]
        else:
            pts = self.kpts[1 - side] if t_o is not None else None
            out[:], ok = _kernels.first_allowed(
                lists.idx, lists.val, anchors, others, dist, geq,
                np.zeros((1, 2)) if pts is None else np.asarray(pts, np.float64),
                0.0 if t_o is None else float(t_o) * float(t_o))
        if not lists.complete:
            # Nothing qualified among the T best: look beyond the sorted list.
            miss = np.flatnonzero(~ok)
            if len(miss):
                out[miss] = self._second_best_lines(side, anchors[miss], others[miss], dist[miss], geq, t_o,
                                                    t_o_kind)
        return out

    def _second_best_lines(self, side: int, anchors: np.ndarray, others: np.ndarray, dist: np.ndarray,
                           geq: bool, t_o, t_o_kind: str) -> np.ndarray:
        """:meth:`second_best` on whole lines, for anchors whose list holds none; entries are visited in
        (distance, index) order."""
        size = self.m if side == 0 else self.n
        out = np.full(len(anchors), np.inf)
        by_overlap = t_o is not None and t_o_kind == "overlap"
        px2 = float(t_o) ** 2 if t_o is not None and not by_overlap else 0.0
        pts = np.asarray(self.kpts[1 - side], np.float64) if px2 > 0 else np.zeros((1, 2))
        step = max(1, (8 * _MiB) // (8 * size))
        E = self._line_bounds(side) if self._exact else None
        for s in range(0, len(anchors), step):
            a, o = anchors[s : s + step], others[s : s + step]
            d = dist[s : s + step] if geq else np.zeros(len(a))
            if self._exact:
                X = self._X
                if self._approx is not None and side == 0:  # rows of the dense matrix, read in place
                    Dap, rows = self._approx, a
                else:
                    Dap, rows = self._approx_lines(side, a), np.arange(len(a))
                e, k = _walk_kernels.next_in_lines(Dap, rows, X[side], a, X[1 - side], E, d, np.full(len(a), -1),
                                                   np.zeros(len(a), np.bool_), o, pts, px2, self._qoff,
                                                   self._qstep)
                live = np.flatnonzero(k >= 0) if by_overlap else rows[:0]
                while len(live):
                    near = self.overlap_near(1 - side, o[live], k[live], t_o)
                    live = live[near]
                    if not len(live):
                        break
                    e[live], k[live] = _walk_kernels.next_in_lines(
                        Dap, rows[live], X[side], a[live], X[1 - side], E, e[live], k[live],
                        np.ones(len(live), np.bool_), o[live], pts, 0.0, self._qoff, self._qstep)
                    live = live[k[live] >= 0]
                out[s : s + step] = e
                continue
            line = self._lines(side, a)
            allowed = np.ones(line.shape, bool)
            allowed[np.arange(len(a)), o] = False
            if geq:
                allowed &= line >= d[:, None]
            if px2 > 0:
                allowed &= _kernels.outside_px(pts, o, px2)
            line = np.where(allowed, line, np.inf)
            if not by_overlap:
                out[s : s + step] = line.min(axis=1)
                continue
            # One round per entry in (distance, index) order (first minimum, then taken out as inf), so no
            # line is sorted whole. NaN ends a line as inf does.
            line[np.isnan(line)] = np.inf
            live = np.arange(len(a))
            while len(live):
                k = np.argmin(line[live], axis=1)
                val = line[live, k]
                live, k, val = live[val < np.inf], k[val < np.inf], val[val < np.inf]
                if not len(live):
                    break
                near = self.overlap_near(1 - side, o[live], k, t_o)
                out[s + live[~near]] = val[~near]
                live, k = live[near], k[near]
                line[live, k] = np.inf
        return out

    def _first_not_overlapping(self, img: int, lists: SortedLists, anchors: np.ndarray, others: np.ndarray,
                               dist: np.ndarray, geq: bool, t_o: float) -> np.ndarray:
        """FGINN by overlap on sorted lists: per anchor, the position of the first entry that is not the match,
        not below ``dist`` (``geq``) and with overlap error above ``t_o`` (``-1``: none)."""
        K, L = len(anchors), lists.idx.shape[1]
        first = np.full(K, -1, np.int64)
        pos = np.zeros(K, np.int64)
        active = np.arange(K)
        pts, radius = np.asarray(self.kpts[img], np.float64), self._radius(img)
        while len(active):
            nxt, far = _kernels.next_allowed(lists.idx, lists.val, anchors[active], others[active], dist[active],
                                             geq, pos[active], pts, radius, 1.0 > t_o)
            first[active[far]] = nxt[far]  # bounding circles apart: overlap error 1 (as computed below)
            near = ~far & (nxt < L)
            active, nxt = active[near], nxt[near]
            if not len(active):
                break
            cand = lists.idx[anchors[active], nxt]
            keep = ~self.overlap_near(img, others[active], cand, t_o)
            first[active[keep]] = nxt[keep]
            pos[active[~keep]] = nxt[~keep] + 1
            active = active[~keep]
        return first

    def _radius(self, img: int) -> np.ndarray:
        """Bounding radius of every patch of image ``img + 1`` (as :func:`ellipse_overlap_error` takes it)."""
        if self._radii[img] is None:
            self._radii[img] = _largest_singular_value(np.asarray(self.shapes[img], np.float64).reshape(-1, 2, 2))
        return self._radii[img]

    def overlap_near(self, img: int, other: np.ndarray, cand: np.ndarray, t_o: float) -> np.ndarray:
        """Whether keypoint ``other[k]``'s and ``cand[k]``'s patches (image ``img``) overlap with error
        ``<= t_o``: by :func:`circle_overlap_bounds` where they decide, else :meth:`overlap_errors`."""
        pts, shapes = self.kpts[img], self.shapes[img]
        lo, hi = circle_overlap_bounds(pts[other], shapes[other], pts[cand], shapes[cand])
        near = hi <= t_o
        open_ = np.flatnonzero((lo <= t_o) & ~near)
        if len(open_):
            near[open_] = self.overlap_errors(img, other[open_], cand[open_, None]).reshape(-1) <= t_o
        return near

    def overlap_errors(self, img: int, other: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """Overlap errors ``(K, L)`` between keypoint ``other[k]`` and ``cand[k, l]`` of image ``img`` (the one
        place FGINN computes them; sweeps override it with a table look-up)."""
        pts, shapes = self.kpts[img], self.shapes[img]
        K, L = cand.shape
        anchor = np.broadcast_to(other[:, None], (K, L)).ravel()
        err = ellipse_overlap_error(pts[anchor], shapes[anchor], pts[cand.ravel()], shapes[cand.ravel()])
        return err.reshape(K, L)
