"""HarrisZ, the affine multi-scale Harris detector of the paper's best setup (Sec. 5, Fig. 5).

Bellavia, Tegolo and Valenti, IET CV 5(2), 2011. Per scale: edge-masked derivatives, the z-scored response
``z(det M) - z((tr M)^2)`` (an adaptive Harris ``k``), positive strict maxima thinned, refined and given
the ellipse of ``M^{-1/2}``. Ladder, mask threshold and ordering follow the author's fb82/HarrisZ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HarrisZResult", "harrisz"]


@dataclass(frozen=True, eq=False)
class HarrisZResult:
    """HarrisZ keypoints ``kpts`` (N, 2), finest scale first and, within a scale, strongest first.

    ``shapes`` (N, 2, 2) are symmetric, with semi-axes ``patch_radius × σ_i`` along the eigenvector of ``M``'s
    smaller eigenvalue and ``patch_radius × σ_i × sqrt(λ_min / λ_max)`` across it; ``scales`` the
    integration scales ``σ_i = base ** levels`` in pixels; ``responses`` the z-scored responses.
    """

    kpts: np.ndarray
    shapes: np.ndarray
    scales: np.ndarray
    responses: np.ndarray
    levels: np.ndarray

    def __len__(self) -> int:
        return len(self.kpts)


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    import cv2

    r = int(max(1, np.ceil(3 * sigma)))  # reflect-101 border, as the author's blur
    return cv2.GaussianBlur(img, (2 * r + 1, 2 * r + 1), sigmaX=sigma, sigmaY=sigma,
                            borderType=cv2.BORDER_REFLECT_101)


def _derivatives(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central differences (unscaled), zero on the one-pixel border."""
    dx = np.zeros_like(img)
    dy = np.zeros_like(img)
    dx[1:-1, 1:-1] = img[1:-1, 2:] - img[1:-1, :-2]
    dy[1:-1, 1:-1] = img[2:, 1:-1] - img[:-2, 1:-1]
    return dx, dy


def _zscore(a: np.ndarray) -> np.ndarray:
    a64 = a.astype(np.float64)
    s = a64.std()
    return np.zeros_like(a64) if s == 0 else (a64 - a64.mean()) / s


def _thin(rc: np.ndarray, radius: float) -> np.ndarray:
    """Indices of ``rc`` (strongest first) kept by greedy thinning: no kept point closer than ``radius``."""
    if len(rc) <= 1:
        return np.arange(len(rc))
    from scipy.spatial import cKDTree

    tree = cKDTree(rc.astype(np.float64))
    # Integer grid: "closer than radius" is "at most radius minus a hair".
    pairs = tree.query_pairs(radius - 1e-6, output_type="ndarray")
    if len(pairs) == 0:
        return np.arange(len(rc))
    a, b = pairs.min(axis=1), pairs.max(axis=1)  # b comes after a in the ranking
    order = np.argsort(a, kind="stable")
    a, b = a[order], b[order]
    starts = np.searchsorted(a, np.arange(len(rc) + 1))
    dead = np.zeros(len(rc), bool)
    keep = []
    for i in range(len(rc)):
        if dead[i]:
            continue
        keep.append(i)
        dead[b[starts[i]:starts[i + 1]]] = True
    return np.asarray(keep, np.int64)


def _subpixel(resp: np.ndarray, r: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parabola vertex along each axis, where both neighbours exist."""
    H, W = resp.shape
    rr, cc = r.astype(np.float64), c.astype(np.float64)
    for axis, (pos, out, size) in enumerate(((r, rr, H), (c, cc, W))):
        ok = (pos >= 1) & (pos <= size - 2)
        i, j = r[ok], c[ok]
        v = resp[i, j]
        lo = resp[i - 1, j] if axis == 0 else resp[i, j - 1]
        hi = resp[i + 1, j] if axis == 0 else resp[i, j + 1]
        den = 2 * (2 * v - lo - hi)  # > 0 at a strict maximum
        with np.errstate(divide="ignore", invalid="ignore"):
            off = np.where(den > 0, (hi - lo) / den, 0.0)
        out[ok] = pos[ok] + np.clip(off, -0.5, 0.5)
    return cc, rr


def _ellipses(mxx, myy, mxy, major: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric affine shapes ∝ M^{-1/2} with major semi-axis ``major``; also sqrt(λ_min / λ_max)."""
    # Closed form without trigonometry (eigh, BLAS and numpy's SIMD trigonometry round by CPU): eigenvalues
    # t -/+ r; the larger one's eigenvector (c, s) has cos 2phi = (mxx - myy) / 2r, sin 2phi = mxy / r.
    half_diff = 0.5 * (mxx - myy)
    t = 0.5 * (mxx + myy)
    r = np.sqrt(half_diff * half_diff + mxy * mxy)
    lam_min, lam_max = np.maximum(t - r, 1e-300), np.maximum(t + r, 1e-300)
    ratio = np.sqrt(lam_min / lam_max)
    iso = r == 0  # a circle: any axes (phi = 0)
    rr = np.where(iso, 1.0, r)
    cos2, sin2 = np.where(iso, 1.0, half_diff / rr), np.where(iso, 0.0, mxy / rr)
    cc, ss, cs = 0.5 * (1.0 + cos2), 0.5 * (1.0 - cos2), 0.5 * sin2
    # A = major (v_min v_min' + ratio v_max v_max') with v_max = (c, s), v_min = (-s, c).
    a_xx = major * (ss + ratio * cc)
    a_yy = major * (cc + ratio * ss)
    a_xy = major * ((ratio - 1.0) * cs)
    A = np.stack([np.stack([a_xx, a_xy], -1), np.stack([a_xy, a_yy], -1)], -2)
    return A, ratio


def harrisz(image, *, base: float = np.sqrt(2), levels=range(3, 9), diff_ratio: float = 1 / np.sqrt(2),
            mask_threshold: float = 0.31, max_elongation: float = 0.75, patch_radius: float = 3.0,
            max_keypoints: int = 0) -> HarrisZResult:
    """HarrisZ corners of a gray ``image`` with their affine elliptical shapes, as a :class:`HarrisZResult`.

    Parameters
    ----------
    base, levels : float, iterable of int
        Integration scales ``σ_i = base ** l`` (default 3..8: σ_i ≈ 2.8 … 16 px).
    diff_ratio, patch_radius : float
        Differentiation scale σ_d and ellipse major semi-axis, in units of σ_i.
    mask_threshold, max_elongation : float
        Keep maxima where the blurred edge mask exceeds ``mask_threshold`` (0..1), ellipses with
        ``1 - minor/major < max_elongation``.
    max_keypoints : int
        Keep the first ``max_keypoints`` (0: all).

    Examples
    --------
    >>> import numpy as np
    >>> img = np.zeros((96, 96), np.uint8)
    >>> img[20:44, 20:44] = 255; img[56:80, 52:76] = 255
    >>> out = harrisz(img, levels=[3])
    >>> out.kpts.shape[1], out.shapes.shape[1:]
    (2, (2, 2))
    """
    import cv2

    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be a 2-D gray array, got shape {img.shape}")
    levels = np.asarray(list(levels), np.int64)
    if not (np.isfinite(base) and base > 1):
        raise ValueError(f"base must be > 1, got {base!r}")
    empty = HarrisZResult(np.empty((0, 2)), np.empty((0, 2, 2)), np.empty(0), np.empty(0),
                          np.empty(0, np.int64))
    if img.size == 0 or min(img.shape) < 3 or len(levels) == 0:
        return empty
    img = img.astype(np.float32)
    dx, dy = _derivatives(img)
    out = []
    for level in levels:
        s_i = float(base) ** int(level)
        s_d = s_i * diff_ratio
        rd = int(max(1, np.ceil(3 * s_d)))
        dxd, dyd = _blur(dx, s_d), _blur(dy, s_d)
        dm = np.sqrt(dxd * dxd + dyd * dyd)
        mask = _blur((dm > dm.mean()).astype(np.float32), s_d)
        dxd *= mask
        dyd *= mask
        mxx, myy, mxy = _blur(dxd * dxd, s_i), _blur(dyd * dyd, s_i), _blur(dxd * dyd, s_i)
        resp = _zscore(mxx.astype(np.float64) * myy - mxy.astype(np.float64) ** 2) - _zscore(
            (mxx.astype(np.float64) + myy) ** 2)
        # Strict local maxima: the only local maximum of its (2 rad + 1)^2 window.
        rad = min(3, max(1, int(np.floor(rd / np.sqrt(2) + 0.5))))
        k = 2 * rad + 1
        r32 = resp.astype(np.float32)
        ismax = cv2.dilate(r32, np.ones((k, k), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf) == r32
        count = cv2.boxFilter(ismax.astype(np.float32), -1, (k, k), normalize=False,
                              borderType=cv2.BORDER_CONSTANT)
        cand = ismax & (count < 1.5) & (resp > 0) & (mask > mask_threshold)
        r, c = np.nonzero(cand)
        if len(r) == 0:
            continue
        val = resp[r, c]
        order = np.lexsort((c, r, -val))  # strongest first; ties by position
        r, c, val = r[order], c[order], val[order]
        keep = _thin(np.stack([r, c], 1), rd)
        r, c, val = r[keep], c[keep], val[keep]
        x, y = _subpixel(resp, r, c)
        A, ratio = _ellipses(mxx[r, c].astype(np.float64), myy[r, c].astype(np.float64),
                             mxy[r, c].astype(np.float64), np.full(len(r), patch_radius * s_i))
        good = (1 - ratio) < max_elongation
        n = int(good.sum())
        out.append((np.stack([x, y], 1)[good], A[good], np.full(n, s_i), val[good],
                    np.full(n, int(level), np.int64)))
    if not out:
        return empty
    kpts, shapes, scales, responses, lv = (np.concatenate(z) for z in zip(*out))
    if max_keypoints:
        kpts, shapes, scales, responses, lv = (a[: int(max_keypoints)] for a in
                                               (kpts, shapes, scales, responses, lv))
    return HarrisZResult(np.ascontiguousarray(kpts), shapes, scales, responses, lv)
