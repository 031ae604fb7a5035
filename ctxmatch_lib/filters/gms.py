"""GMS: Grid-based Motion Statistics (Bian et al., CVPR 2017; IJCV 2020).

Image 1 is split into a ``grid_size x grid_size`` grid, image 2 into a grid scaled by the assumed relative
scale. Every match votes for the pair (cell of its image-1 keypoint, cell of its image-2 keypoint). For each
image-1 cell the most voted image-2 cell is its candidate; the pair is accepted when the votes summed over
the 3x3 block of neighbouring cell pairs reach ``alpha * sqrt(n)``, ``n`` the mean number of matches in the
nine image-1 cells. A match is kept when its cell pair is an accepted candidate pair. The grid is run four
times, shifted by half a cell in x, y and both, and the results are OR-ed (grid-occlusion fix of the CVPR
paper, Sec. 4).

Scale and rotation (IJCV 2020, Sec. 5, "multi-scale and multi-rotation" motion kernels): the image-2 grid
is scaled by each ratio of ``scale_ratios`` (default {1, 1/2, 1/sqrt 2, sqrt 2, 2}), and the 3x3
neighbourhood of the image-2 cell is rotated by multiples of 45 degrees (8 kernels); the combination with
the most inliers wins. ``with_scale=True`` (the multi-scale grids the paper under reproduction credits to
GMS, Sec. 2) and ``with_rotation=False`` are the defaults here; the authors' reference code has both off.
"""

from __future__ import annotations

import numpy as np

from ._common import check_positive, prepare

__all__ = ["gms_filter", "GMS_SCALE_RATIOS"]

GMS_SCALE_RATIOS = (1.0, 0.5, 1.0 / np.sqrt(2.0), np.sqrt(2.0), 2.0)

# The 8 ring neighbours of a cell, clockwise from the top-left; rotating the kernel by 45 degrees shifts
# the ring by one position (IJCV 2020, Fig. 6).
_RING = np.array([(-1, -1), (0, -1), (1, -1), (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0)])
# Half-cell shifts of the image-1 grid (CVPR 2017, Sec. 4.2).
_SHIFTS = ((0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.5, 0.5))


def _unit(p: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    # Pixel-centre coordinates to [0, 1): the left edge of the image is at -0.5.
    u = (p + 0.5) / np.asarray(size, dtype=np.float64)
    return np.clip(u, 0.0, np.nextafter(1.0, 0.0))


def _run(u1, u2, g1: tuple[int, int], g2: tuple[int, int], rotation: int, alpha: float) -> np.ndarray:
    """One GMS pass for one image-2 grid and one rotation kernel, OR-ed over the four shifted grids."""
    k = len(u1)
    n1, n2 = g1[0] * g1[1], g2[0] * g2[1]
    c2x = np.minimum((u2[:, 0] * g2[0]).astype(np.int64), g2[0] - 1)
    c2y = np.minimum((u2[:, 1] * g2[1]).astype(np.int64), g2[1] - 1)
    c2 = c2y * g2[0] + c2x
    # Kernel offsets: centre first, then the ring; image 2 uses the ring rotated by ``rotation`` steps.
    off1 = np.vstack([[0, 0], _RING])
    off2 = np.vstack([[0, 0], np.roll(_RING, -rotation, axis=0)])
    keep = np.zeros(k, bool)
    for sx, sy in _SHIFTS:
        c1x = np.floor(u1[:, 0] * g1[0] + sx).astype(np.int64)
        c1y = np.floor(u1[:, 1] * g1[1] + sy).astype(np.int64)
        inside = (c1x < g1[0]) & (c1y < g1[1])
        if not inside.any():
            continue
        c1 = c1y * g1[0] + c1x
        votes = np.bincount(c1[inside] * n2 + c2[inside], minlength=n1 * n2).reshape(n1, n2)
        per_cell = np.bincount(c1[inside], minlength=n1)
        best = votes.argmax(axis=1)  # candidate image-2 cell of every image-1 cell
        cx1, cy1 = np.arange(n1) % g1[0], np.arange(n1) // g1[0]
        bx2, by2 = best % g2[0], best // g2[0]
        score = np.zeros(n1)
        total = np.zeros(n1)
        count = np.zeros(n1)
        for (dx1, dy1), (dx2, dy2) in zip(off1, off2):
            lx, ly, rx, ry = cx1 + dx1, cy1 + dy1, bx2 + dx2, by2 + dy2
            ok = (lx >= 0) & (lx < g1[0]) & (ly >= 0) & (ly < g1[1])
            ok &= (rx >= 0) & (rx < g2[0]) & (ry >= 0) & (ry < g2[1])
            ll = np.where(ok, ly * g1[0] + lx, 0)
            rr = np.where(ok, ry * g2[0] + rx, 0)
            score += np.where(ok, votes[ll, rr], 0)
            total += np.where(ok, per_cell[ll], 0)
            count += ok
        # Eq. (5) of the CVPR paper: tau_i = alpha * sqrt(n_i), n_i the mean matches per cell of the block.
        thresh = alpha * np.sqrt(total / np.maximum(count, 1))
        accepted = (score >= thresh) & (per_cell > 0)
        keep[inside] |= accepted[c1[inside]] & (best[c1[inside]] == c2[inside])
    return keep


def gms_filter(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    grid_size: int = 20,
    alpha: float = 6.0,
    with_scale: bool = True,
    with_rotation: bool = False,
    scale_ratios=GMS_SCALE_RATIOS,
) -> np.ndarray:
    """Grid-based Motion Statistics.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many matches simply vote several times.
    scores : ndarray of shape (K,) or None
        Unused by GMS (validated only).
    image_size1, image_size2 : (int, int)
        Image sizes (width, height); the grids span the images.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    grid_size : int, default 20
        Cells per side of the image-1 grid (20 x 20, CVPR 2017 Sec. 5, IJCV 2020 Sec. 6.1).
    alpha : float, default 6
        Threshold factor of ``tau = alpha * sqrt(n)`` (CVPR 2017 Eq. (5) and Sec. 5).
    with_scale : bool, default True
        Try every image-2 grid scale of ``scale_ratios`` and keep the best (IJCV 2020, Sec. 5).
    with_rotation : bool, default False
        Try the 8 rotated 3x3 motion kernels and keep the best (IJCV 2020, Sec. 5).
    scale_ratios : sequence of float
        Relative scales tried when ``with_scale``.

    Returns
    -------
    keep : ndarray of shape (K,), bool

    References
    ----------
    J.-W. Bian et al., "GMS: Grid-based motion statistics for fast, ultra-robust feature correspondence",
    CVPR 2017 and IJCV 128, 2020.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> x = rng.uniform(100, 200, size=(300, 2))
    >>> keep = gms_filter(x, x + 5, np.c_[np.arange(300), np.arange(300)], None,
    ...                   image_size1=(640, 480), image_size2=(640, 480))
    >>> bool(keep.mean() > 0.9)
    True
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    grid_size = check_positive(grid_size, "grid_size", integer=True)
    alpha = check_positive(alpha, "alpha", allow_zero=True)
    ratios = [check_positive(r, "scale_ratios") for r in np.atleast_1d(scale_ratios)] if with_scale else [1.0]
    if len(ms) == 0:
        return np.zeros(0, bool)
    u1, u2 = _unit(ms.x, ms.size1), _unit(ms.y, ms.size2)
    g1 = (grid_size, grid_size)
    rotations = range(8) if with_rotation else [0]
    best = np.zeros(len(ms), bool)
    for r in ratios:
        side = max(int(round(grid_size * r)), 1)
        for rot in rotations:
            keep = _run(u1, u2, g1, (side, side), rot, alpha)
            if keep.sum() > best.sum():
                best = keep
    return best
