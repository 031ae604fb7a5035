"""RootsGLOH2: the shifting Gradient Local Orientation Histogram with RootSIFT square rooting.

sGLOH (Bellavia & Colombo, TPAMI 40(4), 2018): 2 rings × 8 sectors × 8 orientation bins on a non-oriented
patch, so a rotation by one sector permutes the descriptor; sGLOH2 adds the half-sector offset copy, the
distance is the minimum over 16 rotations by π/8 (:class:`SGLOH2Distance`). RootsGLOH2 (IET CV 14(4), 2020)
L1-normalises and square-roots each half. Layout ``[half k][ring r][sector j][bin w]``: sector ``j`` covers
φ/s in [j + k/2, j + 1 + k/2) (s = π/4), bin ``w`` centred on (w + j + k/2) s; radii and binning: fb82/sGLOH.
"""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from .._numerics.fixedmath import atan2, exp, hypot

__all__ = [
    "SGLOH_DIM", "sgloh_descriptors", "sgloh_from_patches", "sgloh_rotate", "SGLOH2Distance",
    "sgloh_distance_matrix",
]

_M = 8  # sectors and orientation bins
_RINGS = (12.0, 20.0)  # outer radius of each ring in patch pixels
_HALF = len(_RINGS) * _M * _M  # 128
SGLOH_DIM = 2 * _HALF  # 256
_PATCH_RADIUS = int(_RINGS[-1])  # 20: descriptor grid 41 x 41
_SIDE = 2 * _PATCH_RADIUS + 3  # 43: the grid plus a margin pixel for the differences
_BIN_SIGMA = 0.7  # Gaussian soft binning, in bins
_FINE = 8  # (power of two) sub-bins per orientation bin of the fine histogram the soft binning is computed from


def _region_maps() -> tuple[np.ndarray, np.ndarray]:
    """Ring (−1 outside and at the centre) and sector of each pixel of the 41×41 grid, for both halves.

    Decided in integers on one quadrant and rotated, so a 90° turn is an exact relabelling on any CPU.
    """
    R = _PATCH_RADIUS
    off = np.arange(-R, R + 1)
    x, y = np.meshgrid(off, off)  # x along columns, y along rows (down)
    rho2 = x * x + y * y
    ring = np.full(x.shape, -1, np.int64)
    for i in reversed(range(len(_RINGS))):
        ring[rho2 <= int(_RINGS[i]) ** 2] = i
    ring[R, R] = -1
    sector = np.zeros((2,) + x.shape, np.int64)
    q = (x > 0) & (y >= 0)  # quadrant of φ in [0, π/2)
    xq, yq = x[q], y[q]
    # Half 0: φ >= π/4 iff y >= x. Half 1 (boundaries at π/8 and 3π/8, tan = √2 ∓ 1): φ >= π/8 iff
    # (x + y)² >= 2x², φ >= 3π/8 iff y - x >= 0 and (y - x)² >= 2x²; integers never sit on those lines.
    labels = [(yq >= xq).astype(np.int64),
              np.where((yq - xq >= 0) & ((yq - xq) ** 2 >= 2 * xq * xq), 1,
                       np.where((xq + yq) ** 2 >= 2 * xq * xq, 0, _M - 1))]
    for k in range(2):
        lab = labels[k]
        xs, ys = xq, yq
        for t in range(4):  # (x, y) -> (-y, x) turns φ by +π/2, i.e. two sectors
            sector[k, ys + R, xs + R] = (lab + 2 * t) % _M
            xs, ys = -ys, xs
    return ring, sector


_RING, _SECTOR = _region_maps()


def _blur(patches: np.ndarray, sigma: float, truncate: float) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter(patches, (0, sigma, sigma), mode="nearest", truncate=truncate)``, its
    kernel from fixedmath's ``exp`` (scipy's calls ``np.exp``, whose last bit follows the CPU's SIMD loop)."""
    from scipy.ndimage import correlate1d

    radius = int(truncate * sigma + 0.5)
    x = np.arange(-radius, radius + 1)
    w = exp(-0.5 / (sigma * sigma) * x ** 2)
    w = w / w.sum()
    return correlate1d(correlate1d(patches, w, axis=1, mode="nearest"), w, axis=2, mode="nearest")


def sgloh_from_patches(patches: np.ndarray, *, root: bool = True, chunk: int = 64) -> np.ndarray:
    """sGLOH2 (``root=False``, halves L2-normalised) or RootsGLOH2 descriptors of ``(N, 43, 43)`` patches.

    41×41 grid plus a margin pixel for the differences; each half of the ``(N, 256)`` result has norm 1/√2
    (zero for a flat patch); ``chunk`` patches per step keep the temporaries in cache."""
    p = np.asarray(patches, np.float32)
    if p.ndim != 3 or p.shape[1:] != (_SIDE, _SIDE):
        raise ValueError(f"patches must have shape (N, {_SIDE}, {_SIDE}), got {p.shape}")
    n = len(p)
    out = np.zeros((n, SGLOH_DIM), np.float32)
    if n == 0:
        return out
    inside = _RING >= 0
    n_reg = len(_RINGS) * _M
    region = [_RING[inside] * _M + _SECTOR[k][inside] for k in range(2)]  # (P,) per half
    # Gaussian soft binning as a linear map from a fine orientation histogram (F sub-bins per bin, linear
    # interpolation): bin w of sector j in half k is centred on orientation w + j + k/2 (in bins).
    fine = _M * _FINE
    kern = np.empty((2, n_reg, fine, _M), np.float32)
    f_pos = np.arange(fine) / _FINE
    for k in range(2):
        for r in range(n_reg):
            c = np.arange(_M) + (r % _M) + k / 2
            d = np.mod(f_pos[:, None] - c[None, :] + _M / 2, _M) - _M / 2
            kern[k, r] = exp(-(d * d) / (2 * _BIN_SIGMA ** 2))  # not np.exp: its last bit follows the CPU
    s = 2 * np.pi / _M
    for c0 in range(0, n, chunk):
        q = p[c0 : c0 + chunk]
        gx = (q[:, 1:-1, 2:] - q[:, 1:-1, :-2])[:, inside]  # (B, P)
        gy = (q[:, 2:, 1:-1] - q[:, :-2, 1:-1])[:, inside]
        B, P = gx.shape
        # fixedmath, not numpy's float32 hypot / arctan2, which follow its SIMD loop.
        mag = hypot(gx, gy).astype(np.float32)
        # Fine position in [0, fine): fine is a power of two, so the wrap is a bit mask.
        pos = atan2(gy, gx).astype(np.float32) * np.float32(fine / (2 * np.pi)) + np.float32(fine)
        lo = pos.astype(np.int64)  # truncation = floor: pos > 0
        frac = pos - lo
        lo &= fine - 1
        hi = (lo + 1) & (fine - 1)
        w_hi = (mag * frac).ravel().astype(np.float64)
        w_lo = mag.ravel().astype(np.float64) - w_hi
        base = np.arange(B)[:, None] * n_reg
        desc = np.empty((B, 2, n_reg, _M), np.float64)
        for k in range(2):
            cell = (base + region[k][None, :]) * fine
            size = B * n_reg * fine
            hist = (np.bincount((cell + lo).ravel(), w_lo, size)
                    + np.bincount((cell + hi).ravel(), w_hi, size)).reshape(B, n_reg, fine)
            # float64: a float32 GEMM's rounding follows the OpenBLAS kernel.
            desc[:, k] = np.einsum("brf,rfw->brw", hist, np.asarray(kern[k], np.float64), optimize=True)
        desc = desc.reshape(B, 2, _HALF)
        if root:
            tot = desc.sum(-1, keepdims=True)
            desc = np.sqrt(np.divide(desc, tot, out=np.zeros_like(desc), where=tot > 0))
        else:
            nrm = np.linalg.norm(desc, axis=-1, keepdims=True)
            desc = np.divide(desc, nrm, out=np.zeros_like(desc), where=nrm > 0)
        out[c0 : c0 + B] = (desc / np.sqrt(2)).reshape(B, SGLOH_DIM)
    return out


def sgloh_descriptors(gray: np.ndarray, kpts: np.ndarray, shapes: np.ndarray, *, support: float = 2.0,
                      root: bool = True, smooth: float = 1.0) -> np.ndarray:
    """RootsGLOH2 (``root=False``: sGLOH2) descriptors ``(N, 256)`` of keypoints on non-oriented patches.

    The outer ring covers ``support × A`` of each shape; ``smooth``: blur σ in patch pixels."""
    from .patches import extract_patches

    pad = int(np.ceil(3 * smooth)) if smooth > 0 else 0
    size = _SIDE + 2 * pad
    patches = extract_patches(gray, kpts, shapes, size, radius=_PATCH_RADIUS, support=support)
    if smooth > 0:
        if len(patches):
            patches = _blur(patches, smooth, truncate=3.0)
        patches = patches[:, pad : pad + _SIDE, pad : pad + _SIDE]
    return sgloh_from_patches(patches, root=root)


def sgloh_rotate(desc: np.ndarray, a: int) -> np.ndarray:
    """The ``(N, 256)`` descriptors of the patches turned by ``a`` × π/8 (φ increasing, ``a`` mod 16): entry
    (k, r, j, w) moves to ((k + a) mod 2, r, (j + ⌊(k + a)/2⌋) mod 8, w)."""
    d = np.asarray(desc).reshape(-1, 2, len(_RINGS), _M, _M)
    a = int(a) % (2 * _M)
    out = np.empty_like(d)
    for k in range(2):
        out[:, (k + a) % 2] = np.roll(d[:, k], (k + a) // 2, axis=2)
    return out.reshape(-1, SGLOH_DIM)


def _first_half_shifts(desc1: np.ndarray, shifts) -> dict[int, np.ndarray]:
    """Half 0 of ``desc1`` with sectors rolled back by ``c``, for each c in ``shifts``: (B, 128) each."""
    h = np.asarray(desc1).reshape(-1, 2, len(_RINGS), _M, _M)[:, 0]
    return {c: np.ascontiguousarray(np.roll(h, -c, axis=2).reshape(len(h), _HALF)) for c in shifts}


class SGLOH2Distance:
    """The sGLOH2 matching distance ``min_a ‖h1 − rot_a(h2)‖₂`` over half 0 (distance hook of
    :func:`ctxmatch_lib.blob.blob_matching`), one GEMM per rotation with a running minimum.

    ``h1 · rot_a(h2) = roll(h1, −⌈a/2⌉) · h2[half a mod 2]``, so desc1 is rolled instead of desc2.
    ``rotations`` (steps of π/8, default all 16) around 0 give the paper's upright-biased sGOr2 variants.
    """

    def __init__(self, rotations=None):
        rot = np.arange(2 * _M) if rotations is None else np.unique(np.asarray(list(rotations), np.int64) % 16)
        if len(rot) == 0:
            raise ValueError("rotations must allow at least one rotation")
        self.rotations = tuple(int(a) for a in rot)

    def __repr__(self) -> str:
        return f"SGLOH2Distance(rotations={self.rotations})"

    #: Rows of every GEMM (the last chunk zero-padded, one BLAS thread), so a row's distances depend neither on
    #: the rows passed with it nor on the thread count.
    ROWS = 64

    def __call__(self, desc1: np.ndarray, desc2: np.ndarray) -> np.ndarray:
        d1 = np.asarray(desc1, np.float32).reshape(-1, SGLOH_DIM)
        d2 = np.asarray(desc2, np.float32).reshape(-1, SGLOH_DIM)
        B, m = len(d1), len(d2)
        if B == 0 or m == 0:
            return np.zeros((B, m), np.float32)
        # float64, rounded once: a float32 GEMM rounds by the OpenBLAS kernel, and |a|^2 + |b|^2 - 2ab loses
        # the small distances' digits that the ratio test reads.
        halves2 = [np.ascontiguousarray(d2[:, k * _HALF : (k + 1) * _HALF].T, np.float64) for k in range(2)]
        n2 = [np.einsum("ij,ij->j", h, h) for h in halves2]
        out = np.empty((B, m), np.float32)
        R = self.ROWS
        rows = np.zeros((R, SGLOH_DIM), np.float64)
        with threadpool_limits(1):
            for r0 in range(0, B, R):
                r1 = min(B, r0 + R)
                rows[: r1 - r0] = d1[r0:r1]
                rows[r1 - r0 :] = 0
                out[r0:r1] = self._chunk(rows, halves2, n2)[: r1 - r0]
        return out

    def _chunk(self, d1: np.ndarray, halves2, n2) -> np.ndarray:
        """Distances of ``ROWS`` rows of desc1 to every desc2 row: one GEMM per rotation, running minimum."""
        B, m = len(d1), halves2[0].shape[1]
        shifts = _first_half_shifts(d1, {(a + 1) // 2 % _M for a in self.rotations})
        n1 = np.einsum("ij,ij->i", shifts[next(iter(shifts))], shifts[next(iter(shifts))])
        best = np.full((B, m), np.inf, np.float64)
        tmp = np.empty((B, m), np.float64)
        for a in self.rotations:
            k = a % 2
            np.matmul(shifts[(a + 1) // 2 % _M], halves2[k], out=tmp)
            tmp *= -2
            tmp += n2[k][None, :]  # squared distance minus |h1|^2
            np.minimum(best, tmp, out=best)
        best += n1[:, None]
        np.maximum(best, 0, out=best)
        return np.sqrt(best, out=best)


def sgloh_distance_matrix(desc1: np.ndarray, desc2: np.ndarray, *, rotations=None) -> np.ndarray:
    """Brute-force float64 ``D[i, j] = min_a ‖desc1[i, :128] − sgloh_rotate(desc2[j], a)[:128]‖₂``, the
    reference for :class:`SGLOH2Distance`."""
    d1 = np.asarray(desc1, np.float64).reshape(-1, SGLOH_DIM)
    d2 = np.asarray(desc2, np.float64).reshape(-1, SGLOH_DIM)
    rot = range(16) if rotations is None else sorted({int(a) % 16 for a in rotations})
    out = np.full((len(d1), len(d2)), np.inf)
    for a in rot:
        r = sgloh_rotate(d2, a)[:, :_HALF]
        diff = d1[:, None, :_HALF] - r[None]
        out = np.minimum(out, np.sqrt(np.einsum("ijk,ijk->ij", diff, diff)))
    return out
