"""Compiled (numba) loops of the region-overlap ground truth (methods B and C).

* :func:`overlap_kernel`: overlap error of pairs of ellipses by ray integration from a common interior
  point (the method is described in :mod:`ctxmatch_lib.groundtruth.regions`);
* :func:`homography_ellipse_kernel`: exact image of ellipses under a homography (conic pull-back);
* :func:`flow_transfer_kernel`: ellipses carried by a dense flow and its Jacobian.

One pass over the pairs, constant memory per pair. Compiled code is cached on disk under the ctxmatch
cache directory (``$CTXMATCH_CACHE/numba``) unless ``NUMBA_CACHE_DIR`` is set, as for the DTM kernels.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from functools import partial

import numba
import numpy as np

from .._paths import cache_dir

__all__ = ["overlap_kernel", "homography_ellipse_kernel", "flow_transfer_kernel"]


@contextmanager
def _user_cache():
    previous = numba.config.CACHE_DIR
    if previous:
        yield True
        return
    try:
        numba.config.CACHE_DIR = str(cache_dir("numba"))
    except OSError:
        yield False
        return
    try:
        yield True
    finally:
        numba.config.CACHE_DIR = previous


with _user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def overlap_kernel(c1, A1, c2, A2, cos_t, sin_t):
        """Overlap error of ``{c1 + A1 u}`` and ``{c2 + A2 u}`` (``|u| <= 1``) per pair; 1 where the
        bounding circles are disjoint or a value is not finite, NaN where no common interior point was
        found (the caller falls back to polygons)."""
        n = c1.shape[0]
        na = cos_t.shape[0]
        out = np.ones(n)
        step = 2.0 * math.pi / na
        for k in range(n):
            a00, a01, a10, a11 = A1[k, 0, 0], A1[k, 0, 1], A1[k, 1, 0], A1[k, 1, 1]
            det1 = a00 * a11 - a01 * a10
            if not (math.isfinite(det1) and det1 != 0.0):
                continue
            # Map E1 onto the unit disk: x -> A1^-1 (x - c1).
            i00, i01, i10, i11 = a11 / det1, -a01 / det1, -a10 / det1, a00 / det1
            dx, dy = c2[k, 0] - c1[k, 0], c2[k, 1] - c1[k, 1]
            mx, my = i00 * dx + i01 * dy, i10 * dx + i11 * dy
            b00 = i00 * A2[k, 0, 0] + i01 * A2[k, 1, 0]
            b01 = i00 * A2[k, 0, 1] + i01 * A2[k, 1, 1]
            b10 = i10 * A2[k, 0, 0] + i11 * A2[k, 1, 0]
            b11 = i10 * A2[k, 0, 1] + i11 * A2[k, 1, 1]
            detb = b00 * b11 - b01 * b10
            if not (math.isfinite(detb) and math.isfinite(mx) and math.isfinite(my) and detb != 0.0):
                continue
            rb = math.sqrt(b00 * b00 + b01 * b01 + b10 * b10 + b11 * b11)  # >= bounding radius
            if mx * mx + my * my >= (1.0 + rb) * (1.0 + rb):
                continue
            # N = B^-T B^-1, the ellipse is (x - m)^T N (x - m) <= 1.
            j00, j01, j10, j11 = b11 / detb, -b01 / detb, -b10 / detb, b00 / detb
            n00 = j00 * j00 + j10 * j10
            n01 = j00 * j01 + j10 * j11
            n11 = j01 * j01 + j11 * j11
            # Interior point p = argmin |p|^2 + (p - m)^T N (p - m) = (I + N)^-1 N m.
            gx, gy = n00 * mx + n01 * my, n01 * mx + n11 * my
            e00, e11 = 1.0 + n00, 1.0 + n11
            de = e00 * e11 - n01 * n01
            px, py = (e11 * gx - n01 * gy) / de, (e00 * gy - n01 * gx) / de
            vx, vy = px - mx, py - my
            q1 = px * px + py * py
            nvx, nvy = n00 * vx + n01 * vy, n01 * vx + n11 * vy
            q2 = vx * nvx + vy * nvy
            if not (q1 < 1.0 - 1e-9 and q2 < 1.0 - 1e-9):
                out[k] = np.nan
                continue
            acc = 0.0
            for j in range(na):
                c, s = cos_t[j], sin_t[j]
                pd = px * c + py * s
                r1 = -pd + math.sqrt(max(pd * pd + 1.0 - q1, 0.0))
                a = n00 * c * c + 2.0 * n01 * c * s + n11 * s * s
                b = nvx * c + nvy * s
                r2 = (-b + math.sqrt(max(b * b - a * (q2 - 1.0), 0.0))) / a
                r = r1 if r1 < r2 else r2
                acc += r * r
            inter = 0.5 * acc * step
            area2 = math.pi * abs(detb)
            e = 1.0 - inter / (math.pi + area2 - inter)
            out[k] = min(max(e, 0.0), 1.0)
        return out

    @_jit
    def homography_ellipse_kernel(Hinv, c, A):
        """Image under ``H`` of each ellipse ``{c + A u}``: centre and lower-triangular shape, NaN where the
        image is unbounded. ``Hinv`` is the inverse of ``H``."""
        n = c.shape[0]
        c2 = np.full((n, 2), np.nan)
        A2 = np.full((n, 2, 2), np.nan)
        Q = np.empty((3, 3))
        q = np.zeros((3, 3))
        for k in range(n):
            a00, a01, a10, a11 = A[k, 0, 0], A[k, 0, 1], A[k, 1, 0], A[k, 1, 1]
            det = a00 * a11 - a01 * a10
            if not (math.isfinite(det) and det != 0.0):
                continue
            i00, i01, i10, i11 = a11 / det, -a01 / det, -a10 / det, a00 / det
            m00 = i00 * i00 + i10 * i10  # (A A^T)^-1 = A^-T A^-1
            m01 = i00 * i01 + i10 * i11
            m11 = i01 * i01 + i11 * i11
            cx, cy = c[k, 0], c[k, 1]
            mcx, mcy = m00 * cx + m01 * cy, m01 * cx + m11 * cy
            Q[0, 0], Q[0, 1], Q[1, 1] = m00, m01, m11
            Q[1, 0] = m01
            Q[0, 2] = Q[2, 0] = -mcx
            Q[1, 2] = Q[2, 1] = -mcy
            Q[2, 2] = cx * mcx + cy * mcy - 1.0
            # Q2 = Hinv^T Q Hinv, only its upper triangle.
            for i in range(3):
                for j in range(i, 3):
                    acc = 0.0
                    for u in range(3):
                        t = 0.0
                        for v in range(3):
                            t += Q[u, v] * Hinv[v, j]
                        acc += Hinv[u, i] * t
                    q[i, j] = acc
            M00, M01, M11 = q[0, 0], q[0, 1], q[1, 1]
            dM = M00 * M11 - M01 * M01
            if not (dM > 0.0 and M00 > 0.0):
                continue
            ox = -(M11 * q[0, 2] - M01 * q[1, 2]) / dM
            oy = -(M00 * q[1, 2] - M01 * q[0, 2]) / dM
            kk = ox * (M00 * ox + M01 * oy) + oy * (M01 * ox + M11 * oy) - q[2, 2]
            if not kk > 0.0:
                continue
            # A2 A2^T = kk M^-1; lower Cholesky factor.
            s00, s01, s11 = kk * M11 / dM, -kk * M01 / dM, kk * M00 / dM
            l00 = math.sqrt(s00)
            l10 = s01 / l00
            l11 = math.sqrt(max(s11 - l10 * l10, 0.0))
            c2[k, 0], c2[k, 1] = ox, oy
            A2[k, 0, 0], A2[k, 0, 1], A2[k, 1, 0], A2[k, 1, 1] = l00, 0.0, l10, l11
        return c2, A2

    @_jit
    def flow_transfer_kernel(flow, pts, A):
        """Ellipses ``{p + A u}`` carried by ``x -> x + flow(x)``: centre moved by the flow at the nearest
        pixel, shape multiplied by the map's Jacobian there (central differences, one-sided at the border);
        NaN where the flow or a neighbour is unknown or the point lies outside the field."""
        h, w = flow.shape[0], flow.shape[1]
        n = pts.shape[0]
        c2 = np.full((n, 2), np.nan)
        A2 = np.full((n, 2, 2), np.nan)
        for k in range(n):
            x, y = pts[k, 0], pts[k, 1]
            if not (math.isfinite(x) and math.isfinite(y)):
                continue
            col, row = int(np.rint(x)), int(np.rint(y))  # nearest pixel, as sample_flow
            if col < 0 or col >= w or row < 0 or row >= h:
                continue
            cl, cr = max(col - 1, 0), min(col + 1, w - 1)
            ru, rd = max(row - 1, 0), min(row + 1, h - 1)
            c2[k, 0], c2[k, 1] = x + flow[row, col, 0], y + flow[row, col, 1]
            if cr == cl or rd == ru:
                continue
            j00 = 1.0 + (flow[row, cr, 0] - flow[row, cl, 0]) / (cr - cl)
            j10 = (flow[row, cr, 1] - flow[row, cl, 1]) / (cr - cl)
            j01 = (flow[rd, col, 0] - flow[ru, col, 0]) / (rd - ru)
            j11 = 1.0 + (flow[rd, col, 1] - flow[ru, col, 1]) / (rd - ru)
            for i in range(2):
                A2[k, 0, i] = j00 * A[k, 0, i] + j01 * A[k, 1, i]
                A2[k, 1, i] = j10 * A[k, 0, i] + j11 * A[k, 1, i]
        return c2, A2
