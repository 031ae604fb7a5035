"""BM: bilateral functions for global motion modelling (Lin, Cheng, Lu, Yang, Do, Torr, ECCV 2014).

The motion of the scene between two images is piecewise smooth: smooth inside an object, discontinuous at
its borders. Lin et al. turn this piecewise smoothness into a *global* smoothness by lifting every match to
the bilateral domain, its image-1 position together with its motion ``(x, y - x)``: in that space
the motions of different objects are far apart, so one smooth function models them all, while a false match
lands in an empty region of the space, far from every consistent motion. The motion function is fitted to
all the matches at once with a robust (iteratively reweighted) criterion, and the matches that the fitted
function explains are the output.

Implementation (our reading of the method, not the authors' code; see Notes): the bilateral function is
represented on a bilateral grid (Chen, Paris, Durand, SIGGRAPH 2007), a regular 4-D lattice over (position,
motion) with cells of ``sigma_s`` and ``sigma_r`` times the image diagonal. Each round splats the weighted
motions onto the grid, blurs it with the separable ``[1, 2, 1] / 4`` kernel and slices it at each match, which
gives, in time linear in ``K``, the locally weighted mean motion ``f(x_i, v_i)`` and the kernel mass of the
other matches around the match (its support). The match itself is removed from its own estimate
(leave-one-out), otherwise every match would explain itself. The weights are re-estimated from the residuals
``|v_i - f_i|`` (Welsch function), and a match is kept when its residual is at most ``tau`` times the range
cell and its support reaches ``min_support`` matches and ``density_ratio`` times the support of uniformly
spread matches.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d

from ._common import check_positive, prepare

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


def bm_filter(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    sigma_s: float = 0.1,
    sigma_r: float = 0.05,
    tau: float = 0.5,
    n_iter: int = 3,
    min_support: float = 2.0,
    density_ratio: float = 3.0,
) -> np.ndarray:
    """Bilateral-function motion model fitted robustly on a bilateral grid.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many allowed (each match is one sample of the motion).
    scores : ndarray of shape (K,) or None
        Unused by BM (validated only).
    image_size1, image_size2 : (int, int)
        Image sizes (width, height): the grid cells are fractions of the image diagonals.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused (the motion is the keypoint displacement).
    sigma_s : float, default 0.1
        Spatial cell of the bilateral grid, as a fraction of the image-1 diagonal.
    sigma_r : float, default 0.05
        Range (motion) cell, as a fraction of the mean image diagonal.
    tau : float, default 0.5
        Residual threshold and scale of the Welsch weights, in range cells (``tau * sigma_r`` of the
        diagonal).
    n_iter : int, default 3
        Reweighting rounds of the robust fit.
    min_support : float, default 2
        Minimum support of a kept match, in matches at the centre of its own cell (a match one cell away
        in one dimension counts 1/2, in two dimensions 1/4, ...).
    density_ratio : float, default 3
        The support must also be this many times the support every match would get if the ``K`` matches
        were spread uniformly over the bilateral domain (every image-1 position, every motion that stays
        within image 2).

    Returns
    -------
    keep : ndarray of shape (K,), bool

    Notes
    -----
    The ECCV 2014 paper fits the bilateral function by a global robust minimisation; this implementation uses
    the bilateral grid's splat-blur-slice as the smoothing operator of an iteratively reweighted fit, which is
    linear in ``K`` and deterministic (no randomness, so no ``rng``). The paper's keypoint affine shapes are
    not used: the motion is the displacement of the keypoint. Constants chosen here (the paper states its
    kernel widths for its own normalisation): ``sigma_s = 0.1`` of the diagonal keeps a spatial cell small
    enough for the motion of a planar surface under a moderate homography to vary by about one range cell
    inside it; ``sigma_r = 0.05`` of the diagonal (40 pixels at 640 x 480) is far above the keypoint noise, so
    consistent matches share a cell, and small enough that uniformly random motions, spread over the whole
    image range, rarely meet; ``tau = 0.5`` cell is the residual a consistent match stays below while a random
    match supported only by other random matches, whose motions differ by up to a cell, mostly exceeds it. On
    the planted-outlier case (40 % inliers, seed 0, no scores) ``tau = 0.5`` gives a precision of 0.996 /
    0.991 / 0.995 at 600 / 6000 / 16000 candidates for a recall of 0.99-1.0, ``tau = 1`` 0.988 / 0.946 /
    0.965; ``sigma_r = 0.03`` is as precise with a recall of 0.97-0.98. ``min_support = 2`` asks for at least
    two consistent neighbours; ``density_ratio = 3`` keeps the test meaningful when very many matches fill the
    grid.

    References
    ----------
    W.-Y. D. Lin, M.-M. Cheng, J. Lu, H. Yang, M. N. Do, P. Torr, "Bilateral functions for global motion
    modeling", ECCV 2014. J. Chen, S. Paris, F. Durand, "Real-time edge-aware image processing with the
    bilateral grid", SIGGRAPH 2007.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
    >>> y = g + (7.0, -3.0)
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = bm_filter(g, y, np.c_[np.arange(64), np.arange(64)], image_size1=(400, 300),
    ...                  image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 63)
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    sigma_s = check_positive(sigma_s, "sigma_s")
    sigma_r = check_positive(sigma_r, "sigma_r")
    tau = check_positive(tau, "tau")
    n_iter = check_positive(n_iter, "n_iter", integer=True)
    min_support = check_positive(min_support, "min_support", allow_zero=True)
    density_ratio = check_positive(density_ratio, "density_ratio", allow_zero=True)
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
    w = np.ones(n)
    for _ in range(n_iter):
        sums = _blur_slice(flat, shape, np.c_[w, w[:, None] * v_r])
        # Leave-one-out: remove the match's own contribution from its cell.
        mass = sums[:, 0] - _CENTRE * w
        mean = sums[:, 1:] - _CENTRE * w[:, None] * v_r
        with np.errstate(invalid="ignore", divide="ignore"):
            f = mean / mass[:, None]
        r = np.hypot(*(v_r - f).T)
        r = np.where(mass > 1e-12 * _CENTRE, r, np.inf)
        w = np.exp(-0.5 * (r / tau) ** 2)  # Welsch weights
    support = mass / _CENTRE
    return (r <= tau) & (support >= support_floor)
