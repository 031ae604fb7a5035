"""Compiled (numba) loops of the region-overlap ground truth (methods B and C).

:func:`overlap_kernel` (ray integration, :mod:`ctxmatch_lib.groundtruth.regions`),
:func:`homography_ellipse_kernel` (conic pull-back), :func:`flow_transfer_kernel` (flow and its Jacobian)
and :func:`flow_label_kernel` (methods B and C on a flow pair, fused). One pass, constant memory per pair;
compiled code is cached as for the DTM kernels (:func:`ctxmatch_lib._numerics.jit.user_cache`).
"""

from __future__ import annotations

import math
from functools import partial

import numba
import numpy as np

from .._numerics.jit import user_cache

__all__ = ["overlap_kernel", "homography_ellipse_kernel", "flow_transfer_kernel", "flow_label_kernel"]


with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _lens_area(r, d):
        """Area of the intersection of the unit disk and the disk of radius ``r`` at distance ``d``."""
        if d >= 1.0 + r:
            return 0.0
        if d <= abs(r - 1.0):
            m = min(r, 1.0)
            return math.pi * m * m
        c1 = min(max((d * d + 1.0 - r * r) / (2.0 * d), -1.0), 1.0)
        c2 = min(max((d * d + r * r - 1.0) / (2.0 * d * r), -1.0), 1.0)
        k = (-d + 1.0 + r) * (d + 1.0 - r) * (d - 1.0 + r) * (d + 1.0 + r)
        return math.acos(c1) + r * r * math.acos(c2) - 0.5 * math.sqrt(max(k, 0.0))

    @numba.njit(cache=_cache, nogil=True, error_model="numpy")
    def _ray_sum(px, py, q1, n00, n01, n11, nvx, nvy, q2, cos_t, sin_t):
        """Sum of ``min(r1, r2)^2`` over the rays ``theta`` and ``theta + pi``, in a fixed order and without
        ``fastmath`` (a reordered sum would move, with the CPU, the error a threshold reads);
        ``error_model="numpy"`` drops the zero-division check (``a > 0``, ``N`` positive definite)."""
        acc = 0.0
        for j in range(cos_t.shape[0]):
            c, s = cos_t[j], sin_t[j]
            pd = px * c + py * s
            t1 = pd * pd + 1.0 - q1
            s1 = math.sqrt(t1 if t1 > 0.0 else 0.0)
            a = n00 * c * c + 2.0 * n01 * c * s + n11 * s * s
            b = nvx * c + nvy * s
            t2 = b * b - a * (q2 - 1.0)
            s2 = math.sqrt(t2 if t2 > 0.0 else 0.0)
            u1, u2 = s1 - pd, (s2 - b) / a
            v1, v2 = s1 + pd, (s2 + b) / a
            rf = u1 if u1 < u2 else u2
            rr = v1 if v1 < v2 else v2
            acc += rf * rf + rr * rr
        return acc

    @_jit
    def _overlap_one(c1x, c1y, a00, a01, a10, a11, c2x, c2y, e00, e01, e10, e11, cos_t, sin_t, reject_above):
        """One pair of :func:`overlap_kernel` (1: disjoint, not finite or rejected; NaN: no interior point)."""
        det1 = a00 * a11 - a01 * a10
        if not (math.isfinite(det1) and det1 != 0.0):
            return 1.0
        # Map E1 onto the unit disk: x -> A1^-1 (x - c1).
        i00, i01, i10, i11 = a11 / det1, -a01 / det1, -a10 / det1, a00 / det1
        dx, dy = c2x - c1x, c2y - c1y
        mx, my = i00 * dx + i01 * dy, i10 * dx + i11 * dy
        b00 = i00 * e00 + i01 * e10
        b01 = i00 * e01 + i01 * e11
        b10 = i10 * e00 + i11 * e10
        b11 = i10 * e01 + i11 * e11
        detb = b00 * b11 - b01 * b10
        if not (math.isfinite(detb) and math.isfinite(mx) and math.isfinite(my) and detb != 0.0):
            return 1.0
        fro = b00 * b00 + b01 * b01 + b10 * b10 + b11 * b11
        rb = math.sqrt(fro)  # >= bounding radius
        d2 = mx * mx + my * my
        if d2 >= (1.0 + rb) * (1.0 + rb):
            return 1.0
        area2 = math.pi * abs(detb)
        if reject_above < 1.0:
            # Lower bounds of the overlap error: |E1 ∩ E2| <= min area and <= the lens of the unit disk
            # with the circle of radius sigma_max(B) around m; |E1 ∪ E2| >= max area.
            lo, hi = min(math.pi, area2), max(math.pi, area2)
            if 1.0 - lo / hi > reject_above:
                return 1.0
            smax = math.sqrt(0.5 * (fro + math.sqrt(max(fro * fro - 4.0 * detb * detb, 0.0))))
            lens = min(_lens_area(smax, math.sqrt(d2)), lo)
            if 1.0 - lens / (math.pi + area2 - lens) > reject_above:
                return 1.0
        # N = B^-T B^-1, the ellipse is (x - m)^T N (x - m) <= 1.
        j00, j01, j10, j11 = b11 / detb, -b01 / detb, -b10 / detb, b00 / detb
        n00 = j00 * j00 + j10 * j10
        n01 = j00 * j01 + j10 * j11
        n11 = j01 * j01 + j11 * j11
        # Interior point p = argmin |p|^2 + (p - m)^T N (p - m) = (I + N)^-1 N m.
        gx, gy = n00 * mx + n01 * my, n01 * mx + n11 * my
        f00, f11 = 1.0 + n00, 1.0 + n11
        de = f00 * f11 - n01 * n01
        px, py = (f11 * gx - n01 * gy) / de, (f00 * gy - n01 * gx) / de
        vx, vy = px - mx, py - my
        q1 = px * px + py * py
        nvx, nvy = n00 * vx + n01 * vy, n01 * vx + n11 * vy
        q2 = vx * nvx + vy * nvy
        if not (q1 < 1.0 - 1e-9 and q2 < 1.0 - 1e-9):
            return np.nan
        acc = _ray_sum(px, py, q1, n00, n01, n11, nvx, nvy, q2, cos_t, sin_t)
        inter = 0.5 * acc * (math.pi / cos_t.shape[0])
        e = 1.0 - inter / (math.pi + area2 - inter)
        return min(max(e, 0.0), 1.0)

    @_jit
    def overlap_kernel(c1, A1, c2, A2, cos_t, sin_t, reject_above):
        """Overlap error of ``{c1 + A1 u}`` and ``{c2 + A2 u}`` (``|u| <= 1``) per pair; 1 where the
        bounding circles are disjoint, a value is not finite or the error provably exceeds ``reject_above``
        (area-ratio and lens bounds; ``>= 1``: off), NaN where no common interior point was found (the
        caller falls back to polygons). ``cos_t, sin_t``: the ray angles in ``[0, pi)``."""
        n = c1.shape[0]
        out = np.ones(n)
        for k in range(n):
            out[k] = _overlap_one(c1[k, 0], c1[k, 1], A1[k, 0, 0], A1[k, 0, 1], A1[k, 1, 0], A1[k, 1, 1],
                                  c2[k, 0], c2[k, 1], A2[k, 0, 0], A2[k, 0, 1], A2[k, 1, 0], A2[k, 1, 1],
                                  cos_t, sin_t, reject_above)
        return out

    @_jit
    def _flow_one(flow, x, y, s, a00, a01, a10, a11):
        """Ellipse ``{(x, y) + s A u}`` carried by the flow (see :func:`flow_transfer_kernel`): centre and
        shape, NaN where unknown."""
        nan = np.nan
        h, w = flow.shape[0], flow.shape[1]
        if not (math.isfinite(x) and math.isfinite(y)):
            return nan, nan, nan, nan, nan, nan
        col, row = int(np.rint(x)), int(np.rint(y))  # nearest pixel, as sample_flow
        if col < 0 or col >= w or row < 0 or row >= h:
            return nan, nan, nan, nan, nan, nan
        cl, cr = max(col - 1, 0), min(col + 1, w - 1)
        ru, rd = max(row - 1, 0), min(row + 1, h - 1)
        qx, qy = x + flow[row, col, 0], y + flow[row, col, 1]
        if cr == cl or rd == ru:
            return qx, qy, nan, nan, nan, nan
        a00, a01, a10, a11 = a00 * s, a01 * s, a10 * s, a11 * s
        j00 = 1.0 + (flow[row, cr, 0] - flow[row, cl, 0]) / (cr - cl)
        j10 = (flow[row, cr, 1] - flow[row, cl, 1]) / (cr - cl)
        j01 = (flow[rd, col, 0] - flow[ru, col, 0]) / (rd - ru)
        j11 = 1.0 + (flow[rd, col, 1] - flow[ru, col, 1]) / (rd - ru)
        return (qx, qy, j00 * a00 + j01 * a10, j00 * a01 + j01 * a11, j10 * a00 + j11 * a10,
                j10 * a01 + j11 * a11)

    @_jit
    def flow_label_kernel(flow12, flow21, kpts1, kpts2, S1, S2, i1, i2, scale, centre_max, cos_t, sin_t,
                          reject_above):
        """Methods B and C on a flow pair in one pass: per match ``(i1[k], i2[k])`` the centre distance (the
        smaller transfer) and, where it is at most ``centre_max`` (``inf``: method B), the overlap error of
        the regions scaled by ``scale`` (the smaller direction; ``flow21`` with zero rows: 1 -> 2 only).
        Returns the overlap errors (1 where skipped, NaN for the polygon fallback) and centre distances."""
        n = i1.shape[0]
        err = np.ones(n)
        cen = np.full(n, np.inf)
        back = flow21.shape[0] > 0
        for k in range(n):
            u, v = i1[k], i2[k]
            x1, y1, x2, y2 = kpts1[u, 0], kpts1[u, 1], kpts2[v, 0], kpts2[v, 1]
            qx, qy, b00, b01, b10, b11 = _flow_one(flow12, x1, y1, scale, S1[u, 0, 0], S1[u, 0, 1], S1[u, 1, 0],
                                                   S1[u, 1, 1])
            d = math.sqrt((qx - x2) ** 2 + (qy - y2) ** 2)
            if back:
                rx, ry, c00, c01, c10, c11 = _flow_one(flow21, x2, y2, scale, S2[v, 0, 0], S2[v, 0, 1],
                                                       S2[v, 1, 0], S2[v, 1, 1])
                db = math.sqrt((rx - x1) ** 2 + (ry - y1) ** 2)
                if not d <= db:  # fmin: NaN only when both are
                    d = db if db == db else d
            if d == d:
                cen[k] = d
            if not cen[k] <= centre_max:
                continue
            s = scale
            e = _overlap_one(qx, qy, b00, b01, b10, b11, x2, y2, S2[v, 0, 0] * s, S2[v, 0, 1] * s,
                             S2[v, 1, 0] * s, S2[v, 1, 1] * s, cos_t, sin_t, reject_above)
            if back:
                eb = _overlap_one(rx, ry, c00, c01, c10, c11, x1, y1, S1[u, 0, 0] * s, S1[u, 0, 1] * s,
                                  S1[u, 1, 0] * s, S1[u, 1, 1] * s, cos_t, sin_t, reject_above)
                e = np.nan if (e != e or eb != eb) else min(e, eb)
            err[k] = e
        return err, cen

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
