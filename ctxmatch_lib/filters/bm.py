"""BM: bilateral functions for global motion modelling (Lin, Cheng, Lu, Yang, Do, Torr, ECCV 2014).

Lifted to the bilateral domain (image-1 position, motion ``y - x``), piecewise smooth scene motion is
globally smooth and a false match lands in an empty region. :func:`bm_filter` fits the motion robustly on
a bilateral grid (Chen, Paris, Durand, SIGGRAPH 2007), our reading of the method.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d

from .._numerics.fixedmath import exp, hypot
from ._common import MatchSet, match_filter

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
    """Leave-one-out local affine fit ``v ~ b_i + A_i (u - u_i)`` around each match ``i`` from the blurred
    moments, weighted by ``w``: the kernel mass of the others (K,) and ``b_i`` (K, 2)."""
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


@match_filter(label="BM", merge=True, positive=("sigma_s", "sigma_r", "tau"), integer=("n_iter",),
              non_negative=("min_support", "density_ratio", "ridge"))
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

    %(parameters)s
    %(scores_unused)s
    image_size1, image_size2 : (int, int)
        Image sizes (width, height): the grid cells are fractions of the image diagonals.
    %(shapes_unused)s
    sigma_s, sigma_r : float, default 0.1 and 0.05
        Spatial and motion cells of the grid, as fractions of the image-1 and the mean image diagonal.
    tau : float, default 0.25
        Residual threshold and Welsch scale, in motion cells (12.8 px at 800 x 640).
    n_iter : int, default 3
        Reweighting rounds of the robust fit.
    min_support, density_ratio : float, default 2 and 3
        Minimum support, in matches at the centre of the cell, and as a multiple of uniform ``K`` matches'.
    ridge : float, default 0.1
        Ridge on the linear part of the local affine fits, relative to the mass.

    Returns
    -------
    %(keep)s

    Notes
    -----
    The paper's global robust fit is read as ``n_iter`` Welsch-reweighted rounds of local affine fits from
    moments splatted on a 4-D grid and blurred by ``[1, 2, 1] / 4`` (:func:`_local_affine_fit`), linear in
    ``K``. The paper's kernel widths are for its own normalisation: ``sigma_s`` keeps a surface near affine
    over 3 x 3 cells, ``sigma_r`` (40 px at 640 x 480) separates other motions. The authors' code
    (mmcheng.net/bfun) could not be fetched; sweeps: ``docs/filters.md``.

    %(coincident)s

    References
    ----------
    W.-Y. D. Lin et al., "Bilateral functions for global motion modeling", ECCV 2014.
    J. Chen, S. Paris, F. Durand, "Real-time edge-aware image processing with the bilateral grid", SIGGRAPH 2007.
    """
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
