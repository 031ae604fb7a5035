"""BM: bilateral functions for global motion modelling (Lin, Cheng, Lu, Yang, Do, Torr, ECCV 2014).

Scene motion is piecewise smooth; lifted to the bilateral domain (image-1 position, motion ``y - x``) it is
globally smooth: the motions of different objects lie far apart, and a false match lands in an empty region.
:func:`bm_filter` fits the motion robustly on a bilateral grid (Chen, Paris, Durand, SIGGRAPH 2007), our
reading of the method.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d

from .._numerics.fixedmath import exp, hypot
from ._common import MatchSet, check_positive, match_filter

__all__ = ["bm_filter"]

_KERNEL = np.array([0.25, 0.5, 0.25])
_CENTRE = 0.5**4  # weight of a cell on itself after the 4-D blur


def _grid_index(z: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
    """Flat cell index of the rounded coordinates ``z`` (K, 4) in a padded grid, and the grid shape."""
    cell = np.rint(z).astype(np.int64)
    cell -= cell.min(axis=0) - 1  # one empty cell of padding on each side for the blur
    shape = tuple(int(s) for s in cell.max(axis=0) + 2)
    return np.ravel_multi_index(cell.T, shape), shape


def _blur_slice(flat: np.ndarray, shape, values: np.ndarray) -> np.ndarray:
    """Splat ``values`` (K, C) at the cells ``flat``, blur the 4-D grid, return the grid at ``flat``."""
    size = int(np.prod(shape))
    out = np.empty_like(values)
    for ch in range(values.shape[1]):
        g = np.bincount(flat, values[:, ch], size).reshape(shape)
        for axis in range(4):
            g = correlate1d(g, _KERNEL, axis=axis, mode="constant")
        out[:, ch] = g.ravel()[flat]
    return out


def _local_affine_fit(flat, shape, u, v, w, ridge: float):
    """Leave-one-out local affine fit ``v ~ b_i + A_i (u - u_i)`` of the motion of the other matches around
    each match ``i``, weighted by ``w`` and the blur kernel (a ``ridge`` on ``A_i`` relative to the mass), from
    the blurred moments up to second order: the kernel mass of the others (K,) and ``b_i`` (K, 2)."""
    ux, uy, vx, vy = u[:, 0], u[:, 1], v[:, 0], v[:, 1]
    own = np.c_[w, w * ux, w * uy, w * ux * ux, w * ux * uy, w * uy * uy,
                w * vx, w * vy, w * ux * vx, w * ux * vy, w * uy * vx, w * uy * vy]
    m = _blur_slice(flat, shape, own) - _CENTRE * own  # leave-one-out moments, absolute coordinates
    s0 = m[:, 0]
    # Centre the moments on the match itself: sums of w (u - u_i) and w (u - u_i)(u - u_i)'.
    s1 = m[:, 1:3] - s0[:, None] * u
    sxx = m[:, 3] - 2 * ux * m[:, 1] + ux * ux * s0
    sxy = m[:, 4] - ux * m[:, 2] - uy * m[:, 1] + ux * uy * s0
    syy = m[:, 5] - 2 * uy * m[:, 2] + uy * uy * s0
    sv = m[:, 6:8]
    suv = np.stack([m[:, 8:10] - ux[:, None] * sv, m[:, 10:12] - uy[:, None] * sv], 1)  # (K, 2, 2)
    lam = ridge * s0 + 1e-12
    M = np.zeros((len(u), 3, 3))
    M[:, 0, 0] = s0 + 1e-12
    M[:, 0, 1:] = M[:, 1:, 0] = s1
    M[:, 1, 1], M[:, 1, 2], M[:, 2, 1], M[:, 2, 2] = sxx + lam, sxy, sxy, syy + lam
    rhs = np.concatenate([sv[:, None, :], suv], 1)  # (K, 3, 2)
    coef = np.linalg.solve(M, rhs)
    return s0, coef[:, 0, :]


@match_filter(label="BM", merge=True)
def bm_filter(
    ms: MatchSet,
    *,
    sigma_s: float = 0.1,
    sigma_r: float = 0.05,
    tau: float = 0.25,
    n_iter: int = 3,
    min_support: float = 2.0,
    density_ratio: float = 3.0,
    ridge: float = 0.1,
) -> np.ndarray:
    r"""Bilateral-function motion model fitted robustly on a bilateral grid.

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    %(scores_unused)s
    image_size1, image_size2 : (int, int)
        Image sizes (width, height): the grid cells are fractions of the image diagonals.
    %(shapes_unused)s
    sigma_s : float, default 0.1
        Spatial cell of the bilateral grid, as a fraction of the image-1 diagonal.
    sigma_r : float, default 0.05
        Range (motion) cell, as a fraction of the mean image diagonal.
    tau : float, default 0.25
        Residual threshold and Welsch scale, in range cells (12.8 pixels for an 800 x 640 image).
    n_iter : int, default 3
        Reweighting rounds of the robust fit.
    min_support : float, default 2
        Minimum support of a kept match, in matches at the centre of its cell (one cell away counts 1/2).
    density_ratio : float, default 3
        The support must also be this many times that of ``K`` matches spread uniformly over the bilateral
        domain (every image-1 position, every motion that stays within image 2).
    ridge : float, default 0.1
        Ridge on the linear part of the local affine fits, relative to the mass (keeps collinear or tiny
        neighbourhoods well posed).

    Returns
    -------
    %(keep)s

    Notes
    -----
    The paper fits the bilateral function by a global robust minimisation; here each of ``n_iter`` rounds
    splats the weighted moments of the matches on a 4-D grid, blurs them with ``[1, 2, 1] / 4`` and slices
    them at each match (:func:`_local_affine_fit`), linear in ``K``; Welsch weights follow the residuals.
    Keypoint shapes are not used. The paper's kernel widths are for its own normalisation; here
    ``sigma_s = 0.1`` keeps a surface's motion close to affine over 3 x 3 cells, ``sigma_r = 0.05`` (40 px at
    640 x 480) separates motions more than a cell apart (other objects, most wrong matches), ``tau = 0.25``
    keeps most of the precision of smaller values and more recall on hard pairs, ``min_support = 2`` asks for
    two consistent neighbours, ``density_ratio = 3`` keeps the test meaningful in a full grid. The authors'
    code (mmcheng.net/bfun) could not be fetched here. Sweeps: ``docs/filters.md``; example:
    :mod:`ctxmatch_lib.filters`.

    %(coincident)s
    A location counts once in the support and in the local fits of the others.

    References
    ----------
    W.-Y. D. Lin, M.-M. Cheng, J. Lu, H. Yang, M. N. Do, P. Torr, "Bilateral functions for global motion
    modeling", ECCV 2014. J. Chen, S. Paris, F. Durand, "Real-time edge-aware image processing with the
    bilateral grid", SIGGRAPH 2007.
    """
    sigma_s = check_positive(sigma_s, "sigma_s")
    sigma_r = check_positive(sigma_r, "sigma_r")
    tau = check_positive(tau, "tau")
    n_iter = check_positive(n_iter, "n_iter", integer=True)
    min_support = check_positive(min_support, "min_support", allow_zero=True)
    density_ratio = check_positive(density_ratio, "density_ratio", allow_zero=True)
    ridge = check_positive(ridge, "ridge", allow_zero=True)
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    diag1 = float(np.hypot(*ms.size1))
    diag = 0.5 * (diag1 + float(np.hypot(*ms.size2)))
    v = ms.y - ms.x
    z = np.c_[ms.x / (sigma_s * diag1), v / (sigma_r * diag)]
    flat, shape = _grid_index(z)
    # Support of a match if the K matches were spread uniformly over every possible (position, motion):
    # image 1 times the motions from image 1 into image 2; in centre-cell units.
    (w1, h1), (w2, h2) = ms.size1, ms.size2
    n_cells = (w1 * h1) / (sigma_s * diag1) ** 2 * ((w1 + w2) * (h1 + h2)) / (sigma_r * diag) ** 2
    support_floor = max(min_support, density_ratio * n / max(n_cells, 1.0) / _CENTRE)
    v_r = v / (sigma_r * diag)  # motion in range cells
    u = z[:, :2]  # image-1 position in spatial cells
    w = np.ones(n)
    for _ in range(n_iter):
        mass, f = _local_affine_fit(flat, shape, u, v_r, w, ridge)
        # _fixedmath's hypot and exp: the weights and the r <= tau test are the same on any CPU.
        r = hypot(*(v_r - f).T)
        r = np.where(mass > 1e-12, r, np.inf)
        w = exp(-0.5 * (r / tau) ** 2)  # Welsch weights
    support = mass / _CENTRE
    return (r <= tau) & (support >= support_floor)
