"""Compiled kernels of blob matching: the scan of float32 GEMM tiles and the exact float64 decisions.

The float32 product only *proposes* each line's ``K`` smallest entries; those that can be among the ``T``
best under the certified bound are recomputed in float64 without BLAS (:func:`_exact_sq`) and ranked by
(distance, index), so decisions are the same on any CPU. Bound (Higham, *Accuracy and Stability*, Sec. 3.1):
``|a|² + |b|² − 2 a·b`` in float32 is within ``(2 γ_d + 8u)(|a|² + |b|²)``, ``γ_d = d u / (1 - d u)``,
``u = 2^-24`` (``+ 4u`` for float64 input); :func:`error_scale` doubles it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._numerics.jit import user_cache
from .._numerics.simd import add_sqdiff8, below16, count16, insert16, lane16, lanes8, load16, prefetch, store16, zero8

__all__ = ["TAKEN", "code_scale", "code", "encode", "error_scale", "sq_norms", "scan_tile", "certify_lines",
           "first_allowed", "next_allowed", "outside_px"]

_U = 2.0**-24

#: The code of an entry taken out of a line's look-up; approximate squared distances are coded 0 .. TAKEN - 1.
TAKEN = 0xFFFF

# Flag masks (scan_tile): (bytes of 0 / 1 as a uint64) * _GATHER >> 56 puts byte k's flag in bit k; the
# index of a 64-bit mask's lowest set bit b is _DEBRUIJN_BIT[(b * _DEBRUIJN) >> 58].
_GATHER = np.uint64(0x0102040810204080)
_DEBRUIJN = np.uint64(0x03F79D71B4CB0A89)
_DEBRUIJN_BIT = np.zeros(64, np.int64)
for _bit in range(64):
    _DEBRUIJN_BIT[((1 << _bit) * 0x03F79D71B4CB0A89 % 2**64) >> 58] = _bit
del _bit
_S56, _S58 = np.uint64(56), np.uint64(58)


def code_scale(lo: float, hi: float) -> tuple[np.float32, np.float32, float]:
    """``(qoff, qinv, step)`` of the 16-bit codes of approximate squared distances in ``[lo, hi]``.

    ``qoff + q step`` lies within ``0.51 step`` of ``v``, so codes add ``step`` to the bound; ``qinv`` leaves
    two codes of headroom below :data:`TAKEN`.
    """
    qoff = np.nextafter(np.float32(lo), np.float32(-np.inf))
    qinv = np.float32((TAKEN - 2) / max(hi - float(qoff), 1e-30))
    return qoff, qinv, 1.0 / float(qinv)


def error_scale(d: int) -> float:
    """Factor ``c`` with ``|approx − exact| <= c (|a|² + |b|²)`` for the float32 squared distance, doubled."""
    gamma = d * _U / (1 - d * _U)
    return 2.0 * (2 * gamma + 12 * _U)


with user_cache() as _cache:

    @njit(cache=_cache, nogil=True, inline="always")
    def _lowest_bit(mask):
        """A 64-bit mask without its lowest set bit, and that bit's index (de Bruijn)."""
        low = mask & (~mask + np.uint64(1))
        return mask ^ low, _DEBRUIJN_BIT[np.int64((low * _DEBRUIJN) >> _S58)]

    @njit(cache=_cache, nogil=True)
    def _exact_sq(A, i, B, j):
        """Squared L2 distance of ``A[i]`` and ``B[j]`` in float64: eight running sums (k mod 8), summed in a
        fixed tree (:func:`_tree`); no fast-math, so the same bits on any CPU."""
        a, b = A[i], B[j]
        d = a.shape[0]
        d8 = d - d % 8
        acc = zero8()
        for k in range(0, d8, 8):
            acc = add_sqdiff8(acc, a, b, k)
        return _tree(acc, a, b, d8, d)

    @njit(cache=_cache, nogil=True)
    def sq_norms(A):
        """Squared norms of the rows of ``A`` in float64 (:func:`_exact_sq` against a zero row)."""
        zero = np.zeros((1, A.shape[1]), A.dtype)
        out = np.empty(A.shape[0])
        for i in range(A.shape[0]):
            out[i] = _exact_sq(A, i, zero, 0)
        return out

    @njit(cache=_cache, nogil=True, inline="always")
    def _tree(acc, a, b, d8, d):
        """The end of :func:`_exact_sq`: the last d mod 8 terms into lane 0, the lanes summed in a fixed tree."""
        s0, s1, s2, s3, s4, s5, s6, s7 = lanes8(acc)
        for k in range(d8, d):
            t0 = np.float64(a[k]) - np.float64(b[k])
            s0 += t0 * t0
        return ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))

    @njit(cache=_cache, nogil=True)
    def _exact_sq4(A, i, B, j0, j1, j2, j3):
        """:func:`_exact_sq` of ``A[i]`` against four rows of ``B``, four independent chains (the same bits)."""
        a, b0, b1, b2, b3 = A[i], B[j0], B[j1], B[j2], B[j3]
        d = a.shape[0]
        d8 = d - d % 8
        c0, c1, c2, c3 = zero8(), zero8(), zero8(), zero8()
        for k in range(0, d8, 8):
            c0 = add_sqdiff8(c0, a, b0, k)
            c1 = add_sqdiff8(c1, a, b1, k)
            c2 = add_sqdiff8(c2, a, b2, k)
            c3 = add_sqdiff8(c3, a, b3, k)
        return _tree(c0, a, b0, d8, d), _tree(c1, a, b1, d8, d), _tree(c2, a, b2, d8, d), _tree(c3, a, b3, d8, d)

    @njit(cache=_cache, nogil=True)
    def _exact_block(A, i, B, js, q, out):
        """``out[p] = sqrt(_exact_sq(A, i, B, js[p]))`` for p < q, four at a time (:func:`_exact_sq4`)."""
        q4 = q - q % 4
        for p in range(0, q4, 4):
            e0, e1, e2, e3 = _exact_sq4(A, i, B, js[p], js[p + 1], js[p + 2], js[p + 3])
            out[p], out[p + 1], out[p + 2], out[p + 3] = np.sqrt(e0), np.sqrt(e1), np.sqrt(e2), np.sqrt(e3)
        for p in range(q4, q):
            out[p] = np.sqrt(_exact_sq(A, i, B, js[p]))

    @njit(cache=_cache, nogil=True)
    def _exact_row(A, i, B, out):
        """``out[j]`` = exact distance of ``A[i]`` and ``B[j]`` for every j (:func:`_exact_block`)."""
        _exact_block(A, i, B, np.arange(B.shape[0]), B.shape[0], out)

    @njit(cache=_cache, nogil=True, inline="always")
    def code(v, qoff, qinv):
        """The 16-bit code of an approximate squared distance ``v`` (see :func:`code_scale`)."""
        x = (v - qoff) * qinv + np.float32(0.5)
        return np.uint16(min(max(x, np.float32(0)), np.float32(TAKEN - 1)))

    @njit(cache=_cache, nogil=True)
    def encode(V, qoff, qinv):
        """:func:`code` of every entry of a float32 matrix."""
        out = np.empty(V.shape, np.uint16)
        for r in range(V.shape[0]):
            for k in range(V.shape[1]):
                out[r, k] = code(V[r, k], qoff, qinv)
        return out

    @njit(cache=_cache, nogil=True)
    def _kth(work, cnt, k):
        """The k-th smallest (0-based) of ``work[:cnt]`` (quickselect; reorders ``work``)."""
        lo, hi = 0, cnt - 1
        while lo < hi:
            pivot = work[(lo + hi) >> 1]
            a, b = lo, hi
            while a <= b:
                while work[a] < pivot:
                    a += 1
                while work[b] > pivot:
                    b -= 1
                if a <= b:
                    work[a], work[b] = work[b], work[a]
                    a += 1
                    b -= 1
            if k <= b:
                hi = b
            elif k >= a:
                lo = a
            else:
                break
        return work[k]

    @njit(cache=_cache, nogil=True, inline="always")
    def _insert(val, idx, thr, line, K, v, x, tv, tx):
        """Insert ``(v, x)`` into the line's K sorted entries (after equal values), without a branch on the
        data (``tv``/``tx``: scratch); the threshold becomes the K-th entry when lower."""
        a = val[line]
        b = idx[line]
        pos = 0
        for p in range(K):
            pos += a[p] <= v
        for p in range(K):
            tv[p] = a[p]
            tx[p] = b[p]
        for p in range(1, K):
            a[p] = tv[p - 1] if p > pos else tv[p]
            b[p] = tx[p - 1] if p > pos else tx[p]
        q = pos if pos < K else K - 1
        a[q] = v if pos < K else a[q]
        b[q] = x if pos < K else b[q]
        t = a[K - 1]
        thr[line] = t if t < thr[line] else thr[line]

    @njit(cache=_cache, nogil=True)
    def _kth_of(work, cnt, K):
        """The K-th smallest (1-based) of ``work[0, :cnt]``: for ``K <= 16`` by ranks counted in two 16-lane
        registers, else :func:`_kth`."""
        if K > 16:
            return _kth(work[0], cnt, K - 1)
        lo, hi = load16(work, 0, 0), load16(work, 0, 16)
        out = np.float32(np.inf)
        for p in range(cnt):
            v = work[0, p]
            below = below16(lo, v, cnt) + below16(hi, v, cnt - 16)
            upto = count16(lo, v, cnt) + count16(hi, v, cnt - 16)
            out = v if (below < K) & (upto >= K) else out
        return out

    @njit(cache=_cache, nogil=True)
    def _flush(val, idx, thr, line, K, pv, pi, q, cnt):
        """Insert the pending entries ``(pv[q, :cnt], pi[q, :cnt])`` into a line of at most 16, in registers."""
        lv, lx = load16(val, line, 0), load16(idx, line, 0)
        for p in range(cnt):
            lv, lx = insert16(lv, lx, pv[q, p], pi[q, p])
        store16(val, line, 0, lv)
        store16(idx, line, 0, lx)
        kth = lane16(lv, K - 1)
        thr[line] = kth if kth < thr[line] else thr[line]

    @njit(cache=_cache, nogil=True)
    def _fresh_columns(G, r0, c0, n1, n2, cv, cthr, Kc):
        """Fresh columns' thresholds from the first tile (see :func:`scan_tile`)."""
        B, C = G.shape
        ngc = min(B, 2 * Kc)
        gsz = B // ngc
        gm = np.full((ngc, C), np.inf, np.float32)
        n2t = n2[c0 : c0 + C]
        for bi in range(ngc * gsz):
            grp = gm[bi // gsz]
            grow = G[bi]
            a = n1[r0 + bi]
            for jj in range(C):
                g = grow[jj]
                v = (a + n2t[jj]) - (g + g)
                grp[jj] = v if v < grp[jj] else grp[jj]
        colw = np.full((1, max(32, ngc)), np.inf, np.float32)
        for jj in range(C):
            j = c0 + jj
            if cv[j, 0] == np.inf and cthr[j] == np.inf:
                for q in range(ngc):
                    colw[0, q] = gm[q, jj]
                cthr[j] = np.nextafter(_kth_of(colw, ngc, Kc), np.float32(np.inf))

    @njit(cache=_cache, nogil=True)
    def scan_tile(G, r0, c0, n1, n2, rv, ri, rthr, cv, ci, cthr, Kr, Kc, dense, keep, qoff, qinv):
        """Feed the GEMM tile ``G = d1[r0:r0+B] @ d2[c0:c0+C].T`` to the rows' and columns' K best.

        Entries of ``v = |a|² + |b|² − 2 a·b`` (float32) below their line's threshold are inserted into
        ``rv[i, :Kr]`` / ``cv[j, :Kc]`` (sorted, +inf in empty slots); with ``keep`` every ``v``'s 16-bit
        :func:`code` goes to ``dense``. Each row of ``G`` is zeroed once read, for the next accumulation.
        """
        B, C = G.shape
        reg = Kr <= 16
        regc = Kc <= 16
        P = 32
        pv = np.empty((C, P), np.float32)
        pi = np.empty((C, P), np.int64)
        pc = np.zeros(C, np.int64)
        ng = (C + 63) // 64  # groups of 64 flags, read as one bit mask each
        fl = np.zeros(64 * ng, np.uint8)
        words = fl.view(np.uint64)
        up = np.float32(np.inf)
        tv, tx = np.empty(max(Kr, Kc), np.float32), np.empty(max(Kr, Kc), np.int64)
        # A fresh line's threshold: the K-th smallest of the minima of 2K groups of its first tile (K groups
        # have an entry at or below it, so the K smallest pass), nudged up one float32 step.
        if B >= Kc and cv[c0, 0] == np.inf and cthr[c0] == np.inf:
            _fresh_columns(G, r0, c0, n1, n2, cv, cthr, Kc)
        ngr = min(C, 2 * Kr)
        roww = np.full((1, max(32, ngr)), np.inf, np.float32)
        n2t = n2[c0 : c0 + C]  # views: plain jj indices let LLVM vectorise the pass below
        ctt = cthr[c0 : c0 + C]
        for bi in range(B):
            i = r0 + bi
            a = n1[i]
            grow = G[bi]
            if rv[i, 0] == np.inf and rthr[i] == np.inf and C >= Kr:  # a fresh row
                rw = roww[0]
                for q in range(ngr):
                    g = grow[q]
                    rw[q] = (a + n2t[q]) - (g + g)
                for q0 in range(ngr, C - ngr + 1, ngr):  # strided groups {q, q + 2K, q + 4K, ...}
                    for q in range(ngr):
                        g = grow[q0 + q]
                        v = (a + n2t[q0 + q]) - (g + g)
                        rw[q] = v if v < rw[q] else rw[q]
                rthr[i] = np.nextafter(_kth_of(roww, ngr, Kr), up)
            # Vectorisable pass: a flag per entry (the values are recomputed where needed, not stored).
            t = rthr[i]
            if keep:  # the same pass writes the row's codes
                drow = dense[i, c0 : c0 + C]
                for jj in range(C):
                    g = grow[jj]
                    v = (a + n2t[jj]) - (g + g)
                    c = ctt[jj]
                    fl[jj] = np.uint8(v < (t if t > c else c))
                    drow[jj] = code(v, qoff, qinv)
            else:
                for jj in range(C):
                    g = grow[jj]
                    v = (a + n2t[jj]) - (g + g)
                    c = ctt[jj]
                    fl[jj] = np.uint8(v < (t if t > c else c))
            lv, lx = load16(rv, i, 0), load16(ri, i, 0)  # the row in registers while walked
            # Flag bytes gathered into 64-bit masks, their set bits taken lowest first.
            for g in range(ng):
                mask = np.uint64(0)
                for q in range(8):
                    mask |= ((words[8 * g + q] * _GATHER) >> _S56) << np.uint64(8 * q)
                while mask != np.uint64(0):
                    mask, bit = _lowest_bit(mask)
                    jj = 64 * g + bit
                    gv = grow[jj]
                    v = (a + n2t[jj]) - (gv + gv)
                    j = c0 + jj
                    if not reg:
                        if v < rthr[i]:
                            _insert(rv, ri, rthr, i, Kr, v, j, tv, tx)
                    else:
                        lv, lx = insert16(lv, lx, v, j)
                    if regc:  # no branch on the data: written, and kept if below the threshold
                        q = pc[jj]
                        pv[jj, q] = v
                        pi[jj, q] = i
                        q += v < cthr[j]
                        pc[jj] = q
                        if q == P:
                            _flush(cv, ci, cthr, j, Kc, pv, pi, jj, P)
                            pc[jj] = 0
                    elif v < cthr[j]:
                        _insert(cv, ci, cthr, j, Kc, v, i, tv, tx)
            if reg:
                store16(rv, i, 0, lv)
                store16(ri, i, 0, lx)
                kth = lane16(lv, Kr - 1)
                rthr[i] = kth if kth < t else t
            for jj in range(C):  # the next tile's GEMM accumulates into zeros (no zeroing pass of its own)
                grow[jj] = 0
        for jj in range(C):
            if pc[jj] > 0:
                _flush(cv, ci, cthr, c0 + jj, Kc, pv, pi, jj, pc[jj])

    @njit(cache=_cache, nogil=True)
    def _sort_pairs(val, idx, count):
        """Insertion sort of the first ``count`` entries by (val, idx), in place."""
        for p in range(1, count):
            v, x = val[p], idx[p]
            q = p - 1
            while q >= 0 and (val[q] > v or (val[q] == v and idx[q] > x)):
                val[q + 1] = val[q]
                idx[q + 1] = idx[q]
                q -= 1
            val[q + 1] = v
            idx[q + 1] = x

    @njit(cache=_cache, nogil=True)
    def _full_line(A, line, B, T, out_idx, out_val):
        """The T best entries of a whole line by exact distance, ties by index (stable sort)."""
        m = B.shape[0]
        dist = np.empty(m)
        _exact_row(A, line, B, dist)
        order = np.argsort(dist, kind="mergesort")
        for t in range(T):
            out_idx[line, t] = order[t]
            out_val[line, t] = dist[order[t]]
        return m

    @njit(cache=_cache, nogil=True)
    def certify_lines(A, B, hv, hi, cnt, K, T, norm_a, max_norm_b, scale, out_idx, out_val):
        """The exact T best entries of every line (rows of ``A`` against ``B``) from its K approximate ones.

        The exact T best have approximate values ``<= τ + 2E`` (``τ``: the T-th approximate value): only
        those are recomputed when the K entries reach past it, else the whole line. Returns the count.
        """
        n, m, d = A.shape[0], B.shape[0], B.shape[1]
        step = max(1, 64 // B.itemsize)  # entries per 64-byte cache line
        val = np.empty(K)
        idx = np.empty(K, np.int64)
        ex = np.empty(K)
        arow = np.empty((1, d))
        work = 0
        for line in range(n):
            c = cnt[line]
            for p in range(c):
                val[p] = hv[line, p]
                idx[p] = hi[line, p]
                for k in range(0, d, step):  # the rows of B arrive while the line is sorted
                    prefetch(B, idx[p], k)
            _sort_pairs(val, idx, c)
            E = scale * (norm_a[line] + max_norm_b)
            band = val[T - 1] + 2.0 * E
            if c == m or val[c - 1] > band:
                q = 0
                while q < c and val[q] <= band:
                    q += 1
                for k in range(d):  # the line's own row widened once (exactly), not once per entry
                    arow[0, k] = A[line, k]
                _exact_block(arow, 0, B, idx, q, ex)
                for p in range(q):
                    val[p] = ex[p]
                work += q
                _sort_pairs(val, idx, q)
                for t in range(T):
                    out_idx[line, t] = idx[t]
                    out_val[line, t] = val[t]
            else:
                work += _full_line(A, line, B, T, out_idx, out_val)
        return work

    @njit(cache=_cache, nogil=True, inline="always")
    def within_px(pts, k, o, t_o2):
        """FGINN by pixels (Eq. 9): whether keypoint ``k`` lies less than ``sqrt(t_o2)`` pixels from the
        matched keypoint ``o``, which excludes it from the second best (the rule's one definition)."""
        dx = pts[k, 0] - pts[o, 0]
        dy = pts[k, 1] - pts[o, 1]
        return dx * dx + dy * dy < t_o2

    @njit(cache=_cache, nogil=True)
    def outside_px(pts, others, t_o2):
        """``(K, N)`` mask of the keypoints not :func:`within_px` of ``others[r]``."""
        out = np.empty((len(others), pts.shape[0]), np.bool_)
        for r in range(len(others)):
            o = others[r]
            for k in range(pts.shape[0]):
                out[r, k] = not within_px(pts, k, o, t_o2)
        return out

    @njit(cache=_cache, nogil=True)
    def first_allowed(idx, val, anchors, others, dist, geq, pts, t_o2):
        """Second best on sorted lists: per anchor line ``idx[anchors[r]]`` the first entry that is not the
        match itself, not below ``dist`` (``geq``) and not within ``sqrt(t_o2)`` pixels of the matched
        keypoint (FGINN, ``t_o2 > 0``); ``inf`` and ``found = False`` when none is."""
        K, L = len(anchors), idx.shape[1]
        out = np.full(K, np.inf)
        found = np.zeros(K, np.bool_)
        for r in range(K):
            a, o = anchors[r], others[r]
            for q in range(L):
                k = idx[a, q]
                if k == o:
                    continue
                if geq and val[a, q] < dist[r]:
                    continue
                if t_o2 > 0 and within_px(pts, k, o, t_o2):
                    continue
                out[r] = val[a, q]
                found[r] = True
                break
        return out, found

    @njit(cache=_cache, nogil=True)
    def next_allowed(idx, val, anchors, others, dist, geq, pos, pts, radius, far_ok):
        """Per anchor line, the first position ``>= pos[r]`` that is not the match, not below ``dist``
        (``geq``) and either near ``others[r]`` (bounding circles intersecting: to be checked) or far from
        it with ``far_ok`` (overlap error 1). Returns the positions (list length: none) and the far flags."""
        L = idx.shape[1]
        out = np.empty(len(anchors), np.int64)
        far = np.zeros(len(anchors), np.bool_)
        for r in range(len(anchors)):
            a, o = anchors[r], others[r]
            q = pos[r]
            while q < L:
                k = idx[a, q]
                if k != o and not (geq and val[a, q] < dist[r]):
                    dx = pts[k, 0] - pts[o, 0]
                    dy = pts[k, 1] - pts[o, 1]
                    rr = radius[k] + radius[o]
                    if dx * dx + dy * dy < rr * rr:
                        break
                    if far_ok:
                        far[r] = True
                        break
                q += 1
            out[r] = q
        return out, far
