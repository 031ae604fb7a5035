"""Blob matching's one pass with the product in registers: a compiled float32 GEMM fused with the scan.

:func:`product_scan` does what the GEMM tiles and :func:`~._kernels.scan_tile` do together, keeping 4 x 64
blocks of ``d1 @ d2.T`` in 16-lane registers and walking only the flagged entries; the results are the tile
path's, bit for bit. Needs AVX-512 (:func:`fused_product_fast`); see docs/blob-matching.md.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numba import config, literal_unroll, njit

from .._numerics.jit import user_cache
from .._numerics.simd import fill16, fma16, insert16, lane16, load16, row_codes, row_flags, row_reflag, store16
from ._kernels import TAKEN, _flush, _insert, _kth_of, _lowest_bit, code

__all__ = ["CHUNK", "FRESH_ROWS", "NR", "ROW_BLOCK", "fused_product_fast", "pack_columns", "product_scan"]

#: Columns per register block: four 16-lane registers per row.
NR = 64
#: Column blocks per chunk: 512 columns, swept by every row (the packed columns of d = 128: 256 KiB).
CHUNK = 8
#: Rows of a chunk whose distances start its fresh columns' thresholds (:func:`_fresh_columns`).
FRESH_ROWS = 128
#: Entries waiting per column before they are inserted together (as ``scan_tile``'s buckets).
BUCKET = 32
#: Rows per sweep of the chunks when f = Ω's 16-bit codes are written (see :func:`product_scan`).
ROW_BLOCK = 1024


@cache
def fused_product_fast() -> bool:
    """Whether numba compiles for this CPU (no ``NUMBA_CPU_NAME``) and it has AVX-512: the sixteen 512-bit
    accumulators of :func:`product_scan` then stay in registers."""
    if config.CPU_NAME is not None:
        return False
    from llvmlite import binding

    try:  # llvmlite documents a RuntimeError where LLVM cannot tell (0.50 returns an empty map instead)
        return bool(binding.get_host_cpu_features().get("avx512f", False))
    except RuntimeError:
        return False


with user_cache() as _cache:

    @njit(cache=_cache, nogil=True)
    def aligned_zeros(rows, cols):
        """A float32 ``(rows, cols)`` array of zeros starting on a 64-byte boundary (numba aligns to 32 only),
        so that no 16-lane load or store straddles two cache lines (``cols`` a multiple of 16)."""
        buf = np.zeros(rows * cols + 16, np.float32)
        off = ((64 - buf.ctypes.data % 64) % 64) // 4
        return buf[off : off + rows * cols].reshape(rows, cols)

    @njit(cache=_cache, nogil=True)
    def pack_columns(B, n2):
        """``B`` packed coordinate-major in blocks of :data:`NR` columns, ``Bp[blk, k * NR + q] =
        B[blk * NR + q, k]`` (zero past m), and the squared norms padded with +inf (never flagged)."""
        m, d = B.shape
        nb = (m + NR - 1) // NR
        Bp = aligned_zeros(nb, d * NR)
        for j in range(m):
            blk, q = j // NR, j % NR
            for k in range(d):
                Bp[blk, k * NR + q] = B[j, k]
        n2p = np.full(nb * NR, np.inf, np.float32)
        n2p[:m] = n2
        return Bp, n2p

    @njit(cache=_cache, nogil=True, inline="always")
    def _block(A, i0, Bp, blk):
        """The dot products of rows ``i0 .. i0 + 3`` of ``A`` with column block ``blk``: 4 x 4 registers."""
        z = fill16(np.float32(0))
        c00, c01, c02, c03, c10, c11, c12, c13 = z, z, z, z, z, z, z, z
        c20, c21, c22, c23, c30, c31, c32, c33 = z, z, z, z, z, z, z, z
        for k in range(A.shape[1]):
            o = k * NR
            b0, b1 = load16(Bp, blk, o), load16(Bp, blk, o + 16)
            b2, b3 = load16(Bp, blk, o + 32), load16(Bp, blk, o + 48)
            s = A[i0 + 0, k]
            c00, c01, c02, c03 = fma16(c00, b0, s), fma16(c01, b1, s), fma16(c02, b2, s), fma16(c03, b3, s)
            s = A[i0 + 1, k]
            c10, c11, c12, c13 = fma16(c10, b0, s), fma16(c11, b1, s), fma16(c12, b2, s), fma16(c13, b3, s)
            s = A[i0 + 2, k]
            c20, c21, c22, c23 = fma16(c20, b0, s), fma16(c21, b1, s), fma16(c22, b2, s), fma16(c23, b3, s)
            s = A[i0 + 3, k]
            c30, c31, c32, c33 = fma16(c30, b0, s), fma16(c31, b1, s), fma16(c32, b2, s), fma16(c33, b3, s)
        return (c00, c01, c02, c03), (c10, c11, c12, c13), (c20, c21, c22, c23), (c30, c31, c32, c33)

    @njit(cache=_cache, nogil=True)
    def _fresh_row(V, r, w, M, mr, nblk, b0, shut, Kr):
        """A fresh row's threshold from ``V[r, :w]`` (as ``scan_tile``'s), and its flags again."""
        ngr = min(w, 2 * Kr)
        roww = np.full((1, max(32, ngr)), np.inf, np.float32)
        rw = roww[0]
        for q in range(ngr):
            rw[q] = V[r, q]
        for q0 in range(ngr, w - ngr + 1, ngr):
            for q in range(ngr):
                v = V[r, q0 + q]
                rw[q] = v if v < rw[q] else rw[q]
        t = np.nextafter(_kth_of(roww, ngr, Kr), np.float32(np.inf))
        for b in range(nblk):
            M[0, mr, b] = row_reflag(V, r, b * NR, t, shut, (b0 + b) * NR)
        return t

    @njit(cache=_cache, nogil=True)
    def _sweep(A, Bp, b0, b1, i_lo, i_hi, n1, n2p, X, early, rv, ri, rthr, cv, ci, cthr, shut, Kr, Kc, cols, M,
               dense, keep, qoff, qinv, pv, pi, pc, tv, tx):
        """Rows ``i_lo .. i_hi - 1``, four at a time, against column blocks ``b0 .. b1 - 1``.

        Distances go into ``X`` (``F``'s rows with ``early``), flags into ``M`` (``M[0]``: row, ``M[1]``:
        column), codes into ``dense`` with ``keep``; flagged entries go to the lines' K best."""
        n, m = rv.shape[0], cv.shape[0]
        nblk, c0 = b1 - b0, b0 * NR
        w = min(nblk * NR, m - c0)
        inf, top = np.float32(np.inf), np.float32(TAKEN - 1)
        for i0 in range(i_lo, i_hi, 4):
            vr = i0 if early else 0
            t = (rthr[i0] if i0 < n else inf, rthr[i0 + 1] if i0 + 1 < n else inf,
                 rthr[i0 + 2] if i0 + 2 < n else inf, rthr[i0 + 3] if i0 + 3 < n else inf)
            flagged = np.int64(0)
            for b in range(nblk):
                j0, k = (b0 + b) * NR, b * NR
                g = _block(A, i0, Bp, b0 + b)
                for r in literal_unroll((0, 1, 2, 3)):
                    fr, fc = row_flags(X, vr + r, k, g[r][0], g[r][1], g[r][2], g[r][3], n1[i0 + r], t[r], n2p,
                                       shut if early else cthr, j0)
                    M[0, r, b], M[1, r, b] = fr, fc
                    flagged |= fr | fc
                if keep:
                    for r in range(min(4, n - i0)):
                        if j0 + NR <= m:
                            row_codes(dense, i0 + r, j0, X, vr + r, k, qoff, qinv, top)
                        else:
                            for q in range(m - j0):
                                dense[i0 + r, j0 + q] = code(X[vr + r, k + q], qoff, qinv)
            if flagged == 0 or i0 >= n:
                continue
            for r in range(min(4, n - i0)):
                i = i0 + r
                if rv[i, 0] == np.inf and rthr[i] == np.inf and w >= Kr:
                    rthr[i] = _fresh_row(X, vr + r, w, M, r, nblk, b0, shut, Kr)
                ti = rthr[i]
                lv, lx = load16(rv, i, 0), load16(ri, i, 0)
                for b in range(nblk):
                    mask = np.uint64(M[0, r, b])
                    while mask != np.uint64(0):
                        mask, bit = _lowest_bit(mask)
                        jj = b * NR + bit
                        if Kr > 16:
                            if X[vr + r, jj] < rthr[i]:
                                _insert(rv, ri, rthr, i, Kr, X[vr + r, jj], c0 + jj, tv, tx)
                        else:
                            lv, lx = insert16(lv, lx, X[vr + r, jj], c0 + jj)
                if Kr <= 16:
                    store16(rv, i, 0, lv)
                    store16(ri, i, 0, lx)
                    kth = lane16(lv, Kr - 1)
                    rthr[i] = kth if kth < ti else ti
                if cols and not early:
                    _to_columns(M, X, vr + r, r, i, nblk, c0, cv, ci, cthr, Kc, pv, pi, pc, tv, tx)

    @njit(cache=_cache, nogil=True)
    def _to_columns(M, X, xr, r, i, nblk, c0, cv, ci, cthr, Kc, pv, pi, pc, tv, tx):
        """Row ``i``'s entries flagged in ``M[1, r]`` into the columns' K best (see :func:`_sweep`)."""
        for b in range(nblk):
            mask = np.uint64(M[1, r, b])
            while mask != np.uint64(0):
                mask, bit = _lowest_bit(mask)
                jj = b * NR + bit
                v, j = X[xr, jj], c0 + jj
                if Kc <= 16:  # no branch on the data: written, and kept if below the threshold
                    q = pc[jj]
                    pv[jj, q] = v
                    pi[jj, q] = i
                    q += v < cthr[j]
                    pc[jj] = q
                    if q == BUCKET:
                        _flush(cv, ci, cthr, j, Kc, pv, pi, jj, BUCKET)
                        pc[jj] = 0
                elif v < cthr[j]:
                    _insert(cv, ci, cthr, j, Kc, v, i, tv, tx)

    @njit(cache=_cache, nogil=True)
    def _fresh_columns(F, R0, nblk, b0, rv, ri, rthr, cv, ci, cthr, Kr, Kc, pv, pi, pc, tv, tx):
        """A chunk's fresh columns from its first ``R0`` rows ``F[:R0]``: thresholds as ``scan_tile``'s, then
        those rows' entries below them into the columns."""
        c0 = b0 * NR
        w = min(nblk * NR, cv.shape[0] - c0)
        ngc = 2 * Kc
        gsz = R0 // ngc
        gm = np.full((ngc, w), np.inf, np.float32)
        for i in range(ngc * gsz):
            grp, row = gm[i // gsz], F[i]
            for jj in range(w):
                v = row[jj]
                grp[jj] = v if v < grp[jj] else grp[jj]
        colw = np.full((1, max(32, ngc)), np.inf, np.float32)
        for jj in range(w):
            for g in range(ngc):
                colw[0, g] = gm[g, jj]
            cthr[c0 + jj] = np.nextafter(_kth_of(colw, ngc, Kc), np.float32(np.inf))
        M = np.zeros((2, 1, nblk), np.int64)
        low = np.float32(-np.inf)
        for i in range(R0):
            for b in range(nblk):
                M[1, 0, b] = row_reflag(F, i, b * NR, low, cthr, c0 + b * NR)
            _to_columns(M, F, i, 0, i, nblk, c0, cv, ci, cthr, Kc, pv, pi, pc, tv, tx)

    @njit(cache=_cache, nogil=True)
    def product_scan(A, n1, Bp, n2p, rv, ri, rthr, cv, ci, cthr, Kr, Kc, cols, dense, keep, qoff, qinv):
        """``scan_tile`` over the whole of ``D`` with the product in registers (see the module docstring).

        ``A``, ``n1``: ``d1`` and its squared norms padded to a multiple of 4 rows (zeros, +inf); ``Bp``,
        ``n2p`` from :func:`pack_columns`; ``cthr`` padded with -inf; the rest as ``scan_tile``'s.
        """
        n, m = rv.shape[0], cv.shape[0]
        n4, nb, W = A.shape[0], Bp.shape[0], CHUNK * NR
        # With codes, rows go in blocks of ROW_BLOCK over every chunk (a page of codes per row would overrun
        # the TLB); the columns' buckets then outlive a chunk's sweep.
        RB = ROW_BLOCK if keep else n4
        nbk = nb * NR if RB < n4 else W
        pv_all, pi_all = np.empty((nbk, BUCKET), np.float32), np.empty((nbk, BUCKET), np.int64)
        pc_all = np.zeros(nbk, np.int64)
        V, M = aligned_zeros(4, W), np.zeros((2, 4, CHUNK), np.int64)
        tv, tx = np.empty(max(Kr, Kc), np.float32), np.empty(max(Kr, Kc), np.int64)
        # A chunk's first R0 rows, kept in F, start its columns (_fresh_columns).
        R0 = min(FRESH_ROWS, n - n % 4) if cols and min(FRESH_ROWS, n - n % 4) >= 2 * Kc else 0
        F = aligned_zeros(R0, W)
        shut = np.full(len(cthr), -np.inf, np.float32)
        for r0 in range(0, n4, RB):
            r1 = min(n4, r0 + RB)
            for b0 in range(0, nb, CHUNK):
                b1, k0 = min(nb, b0 + CHUNK), b0 * NR if RB < n4 else 0
                pv, pi, pc = pv_all[k0 : k0 + W], pi_all[k0 : k0 + W], pc_all[k0 : k0 + W]
                lo = r0
                if r0 == 0 and R0:
                    _sweep(A, Bp, b0, b1, 0, R0, n1, n2p, F, True, rv, ri, rthr, cv, ci, cthr, shut, Kr, Kc, cols,
                           M, dense, keep, qoff, qinv, pv, pi, pc, tv, tx)
                    _fresh_columns(F, R0, b1 - b0, b0, rv, ri, rthr, cv, ci, cthr, Kr, Kc, pv, pi, pc, tv, tx)
                    lo = R0
                _sweep(A, Bp, b0, b1, lo, r1, n1, n2p, V, False, rv, ri, rthr, cv, ci, cthr, shut, Kr, Kc, cols, M,
                       dense, keep, qoff, qinv, pv, pi, pc, tv, tx)
                if r1 < n4:
                    continue
                for jj in range(min(W, m - b0 * NR)):  # the chunk's last sweep: its pending entries go in
                    if pc[jj] > 0:
                        _flush(cv, ci, cthr, b0 * NR + jj, Kc, pv, pi, jj, pc[jj])
                        pc[jj] = 0
