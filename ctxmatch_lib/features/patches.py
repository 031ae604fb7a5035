"""Affine-normalised patches (Sec. 2, "patch normalization"), their dominant orientation and SIFT descriptors."""

from __future__ import annotations

import numpy as np

from .._numerics.fixedmath import atan2, exp, floor_log2, hypot, sincos

__all__ = ["extract_patches", "rotation_shapes", "dominant_orientation", "sift_from_patches"]


def rotation_shapes(shapes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """``A @ R(θ)``: the same ellipses with their first axis turned by ``θ`` (radians, image frame)."""
    s, c = sincos(angles)  # fixedmath and no matmul: numpy's SIMD loops and BLAS round by CPU
    A = np.asarray(shapes, np.float64)
    col0 = A[..., 0] * c[..., None] + A[..., 1] * s[..., None]
    col1 = A[..., 1] * c[..., None] - A[..., 0] * s[..., None]
    return np.stack([col0, col1], -1)


def _pyramid(img: np.ndarray, levels: int) -> list[np.ndarray]:
    import cv2

    out = [img]
    for _ in range(levels):
        if min(out[-1].shape) < 8:
            break
        out.append(cv2.pyrDown(out[-1]))
    return out


def extract_patches(gray: np.ndarray, kpts: np.ndarray, shapes: np.ndarray, size: int, *, radius: float = None,
                    support: float = 1.0, chunk: int = 512) -> np.ndarray:
    """``(N, size, size)`` float32 patches: pixel ``(c, r)`` of patch ``k`` is the image at
    ``kpt_k + support A_k u``, ``u = ((c, r) - (size - 1) / 2) / radius`` (default radius ``(size - 1) / 2``).

    Bilinear, from the Gaussian-pyramid level whose pixel is at most the sampling step (no aliasing); border
    mirrored; ``chunk`` keypoints per remap call bound the memory.
    """
    import cv2

    kpts = np.asarray(kpts, np.float64).reshape(-1, 2)
    shapes = np.asarray(shapes, np.float64).reshape(-1, 2, 2)
    n = len(kpts)
    size = int(size)
    if not 1 <= size <= 181:
        raise ValueError(f"size must be in 1..181 (OpenCV remap limit), got {size}")
    if radius is None:
        radius = (size - 1) / 2
    out = np.empty((n, size, size), np.float32)
    if n == 0:
        return out
    img = np.asarray(gray, np.float32)
    grid = (np.arange(size, dtype=np.float64) - (size - 1) / 2) / float(radius)
    ux, uy = np.meshgrid(grid, grid)  # (size, size), x along columns
    ux, uy = ux.ravel()[None, :], uy.ravel()[None, :]
    T = support * shapes
    # Sampling step: T's larger singular value over radius; det and log2 written out (LAPACK, np.log2 round
    # by CPU).
    fro = np.sum(T * T, axis=(1, 2))
    det = T[:, 0, 0] * T[:, 1, 1] - T[:, 0, 1] * T[:, 1, 0]
    smax = np.sqrt(np.maximum(0.5 * (fro + np.sqrt(np.maximum(fro * fro - 4 * det * det, 0))), 0))
    step = smax / float(radius)
    level = np.clip(floor_log2(np.maximum(step, 1e-12)), 0, 30)
    pyr = _pyramid(img, int(level.max()))
    level = np.minimum(level, len(pyr) - 1)
    for lv in np.unique(level):
        idx = np.flatnonzero(level == lv)
        f = 2.0 ** -int(lv)  # pyrDown keeps the even pixels: x_level = x / 2^level
        for s in range(0, len(idx), chunk):
            sel = idx[s : s + chunk]
            t, c = T[sel] * f, kpts[sel] * f
            # One map row per keypoint: OpenCV's remap caps both map sides below 32767.
            mx = (t[:, 0, 0:1] * ux + t[:, 0, 1:2] * uy + c[:, 0:1]).astype(np.float32)
            my = (t[:, 1, 0:1] * ux + t[:, 1, 1:2] * uy + c[:, 1:2]).astype(np.float32)
            smp = cv2.remap(pyr[lv], mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
            out[sel] = smp.reshape(len(sel), size, size)
    return out


def dominant_orientation(gray: np.ndarray, kpts: np.ndarray, shapes: np.ndarray, *, support: float = 2.0,
                         n_bins: int = 36) -> np.ndarray:
    """Dominant gradient orientation of each affine-normalised patch (SIFT's rule, one peak per keypoint).

    Stand-in for the paper's learned orientation (Yi et al., CVPR 2016): a smoothed 36-bin histogram, Gaussian
    σ = 1/8 of the support, parabolic peak. Returns θ in (−π, π]: ``A @ R(θ)`` (:func:`rotation_shapes`) has
    its first axis along the dominant gradient.
    """
    n = len(kpts)
    if n == 0:
        return np.empty(0)
    size, rad = 27, 12.0  # |u| = 1 at 12 px; one pixel of margin for the differences
    p = extract_patches(gray, kpts, shapes, size, radius=rad, support=support).astype(np.float64)
    gx = p[:, 1:-1, 2:] - p[:, 1:-1, :-2]
    gy = p[:, 2:, 1:-1] - p[:, :-2, 1:-1]
    off = np.arange(size - 2) - (size - 3) / 2
    ux, uy = np.meshgrid(off, off)
    r2 = (ux ** 2 + uy ** 2) / rad ** 2
    # fixedmath: the binned angles must not follow numpy's SIMD loops.
    w = exp(-r2 / (2 * (1 / 8 * 2) ** 2)) * (r2 <= (3 / 8 * 2) ** 2)  # σ_w = 0.25, reach 0.75 in u
    mag = hypot(gx, gy) * w
    pos = (atan2(gy, gx) % (2 * np.pi)) * (n_bins / (2 * np.pi))
    lo = np.floor(pos).astype(np.int64)
    frac = pos - lo
    hist = np.zeros((n, n_bins))
    rows = np.repeat(np.arange(n), mag.shape[1] * mag.shape[2])
    np.add.at(hist, (rows, (lo % n_bins).ravel()), (mag * (1 - frac)).ravel())
    np.add.at(hist, (rows, ((lo + 1) % n_bins).ravel()), (mag * frac).ravel())
    k = np.array([1, 4, 6, 4, 1]) / 16.0
    hist = sum(k[i] * np.roll(hist, i - 2, axis=1) for i in range(5))
    b = np.argmax(hist, axis=1)
    idx = np.arange(n)
    left, mid, right = hist[idx, (b - 1) % n_bins], hist[idx, b], hist[idx, (b + 1) % n_bins]
    den = left - 2 * mid + right
    with np.errstate(divide="ignore", invalid="ignore"):
        off_b = np.where(den < 0, 0.5 * (left - right) / den, 0.0)
    theta = (b + off_b) * (2 * np.pi / n_bins)
    return np.where(theta > np.pi, theta - 2 * np.pi, theta)


def sift_from_patches(gray: np.ndarray, kpts: np.ndarray, shapes: np.ndarray, *, support: float = 2.0,
                      chunk: int = 2500) -> np.ndarray:
    """Raw SIFT descriptors (OpenCV) of affine-normalised, oriented patches.

    The patches are tiled into a mosaic and described at each tile centre, angle 0, at the scale whose 6σ
    reach is ``support × A``, with image margin for OpenCV's pre-blur. Returns unnormalised ``(N, 128)``.
    """
    import cv2

    n = len(kpts)
    out = np.zeros((n, 128), np.float32)
    if n == 0:
        return out
    tile, rad = 41, 12.0  # descriptor reach 7.5σ = 15 px (σ = 2) plus the pre-blur margin
    sift = cv2.SIFT_create()
    for c0 in range(0, n, chunk):
        p = extract_patches(gray, kpts[c0 : c0 + chunk], shapes[c0 : c0 + chunk], tile, radius=rad,
                            support=support)
        k = len(p)
        cols = int(np.ceil(np.sqrt(k)))
        rows = int(np.ceil(k / cols))
        mosaic = np.zeros((rows * tile, cols * tile), np.float32)
        r, c = np.divmod(np.arange(k), cols)
        view = mosaic.reshape(rows, tile, cols, tile).transpose(0, 2, 1, 3)
        view[r, c] = p
        img = np.clip(np.round(mosaic), 0, 255).astype(np.uint8)
        half = (tile - 1) / 2
        kps = [cv2.KeyPoint(float(cc * tile + half), float(rr * tile + half), 2 * rad / 6, 0.0, 1.0, 0)
               for rr, cc in zip(r.tolist(), c.tolist())]
        kps_out, desc = sift.compute(img, kps)
        if desc is None or len(kps_out) != k:
            raise RuntimeError("OpenCV SIFT dropped mosaic keypoints")  # never expected: all are interior
        out[c0 : c0 + k] = desc
    return out
