"""GMS: Grid-based Motion Statistics (Bian et al., CVPR 2017; IJCV 2020).

:func:`gms_filter`: every match votes for its pair of grid cells; the most voted image-2 cell of each image-1
cell is accepted when the votes of the 3x3 block reach ``alpha * sqrt(n)`` (CVPR 2017, Eq. (5)). Four
half-cell-shifted grids are OR-ed (Sec. 4); optionally image-2 grid scales and rotated kernels (IJCV 2020,
Sec. 5). The defaults follow ``cv2.xfeatures2d.matchGMS``, the authors' code the paper ran (Sec. 5.3);
the agreement with it: ``docs/filters.md``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .._numerics.jit import user_cache
from ._common import MatchSet, check_positive, match_filter

__all__ = ["gms_filter", "GMS_SCALE_RATIOS"]

GMS_SCALE_RATIOS = (1.0, 0.5, 1.0 / np.sqrt(2.0), np.sqrt(2.0), 2.0)

# The 8 ring neighbours of a cell, clockwise from the top-left; rotating the kernel by 45 degrees shifts
# the ring by one position (IJCV 2020, Fig. 6).
_RING = np.array([(-1, -1), (0, -1), (1, -1), (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0)])
# Half-cell shifts of the image-1 grid (CVPR 2017, Sec. 4.2).
_SHIFTS = ((0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.5, 0.5))


def _unit(p: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    # x / width, as the authors' code normalises OpenCV keypoints (same pixel-centre origin as ours), so that
    # cell borders fall where theirs do; clipped to [0, 1) for the half pixel left of the first centre.
    u = p / np.asarray(size, dtype=np.float64)
    return np.clip(u, 0.0, np.nextafter(1.0, 0.0))


with user_cache() as _cache:

    @numba.njit(cache=_cache, nogil=True)
    def _gms_kernel(c1, c2, g1w, g1h, g2w, g2h, off1, off2, alpha):
        """The four shifted passes of one grid pair and kernel (CVPR 2017, Sec. 4), OR-ed.

        ``c1`` (4, K): image-1 cell per shifted grid (-1 outside); ``c2`` (K,): image-2 cell. O(K) per pass."""
        n1, n2 = g1w * g1h, g2w * g2h
        k = c2.shape[0]
        votes = np.zeros(n1 * n2, np.int32)
        per_cell = np.zeros(n1, np.int64)
        best = np.full(n1, -1, np.int64)
        best_votes = np.zeros(n1, np.int32)
        winner = np.full(n1, -1, np.int64)
        keep = np.zeros(k, np.bool_)
        for t in range(c1.shape[0]):
            for i in range(k):
                a = c1[t, i]
                if a < 0:
                    continue
                b = c2[i]
                v = votes[a * n2 + b] + 1
                votes[a * n2 + b] = v
                per_cell[a] += 1
                if v > best_votes[a] or (v == best_votes[a] and b < best[a]):
                    best_votes[a] = v
                    best[a] = b
            for i in range(k):
                a = c1[t, i]
                if a < 0 or winner[a] != -1:
                    continue
                # Score of the cell pair (a, best[a]) over its 3x3 block, Eq. (5): tau = alpha sqrt(mean n).
                ax, ay, bx, by = a % g1w, a // g1w, best[a] % g2w, best[a] // g2w
                score = 0
                total = 0
                count = 0
                for j in range(9):
                    lx, ly = ax + off1[j, 0], ay + off1[j, 1]
                    rx, ry = bx + off2[j, 0], by + off2[j, 1]
                    if lx < 0 or lx >= g1w or ly < 0 or ly >= g1h or rx < 0 or rx >= g2w or ry < 0 or ry >= g2h:
                        continue
                    ll = ly * g1w + lx
                    score += votes[ll * n2 + ry * g2w + rx]
                    total += per_cell[ll]
                    count += 1
                thresh = alpha * math.sqrt(total / max(count, 1))
                winner[a] = best[a] if score >= thresh else -2
            for i in range(k):
                a = c1[t, i]
                if a < 0:
                    continue
                if winner[a] == c2[i]:
                    keep[i] = True
            for i in range(k):  # clear the tables for the next pass
                a = c1[t, i]
                if a < 0:
                    continue
                votes[a * n2 + c2[i]] = 0
                per_cell[a] = 0
                best[a] = -1
                best_votes[a] = 0
                winner[a] = -1
        return keep


def _run(u1, u2, g1: tuple[int, int], g2: tuple[int, int], rotation: int, alpha: float) -> np.ndarray:
    """One GMS pass for one image-2 grid and one rotation kernel, OR-ed over the four shifted grids."""
    c2x = np.minimum((u2[:, 0] * g2[0]).astype(np.int64), g2[0] - 1)
    c2y = np.minimum((u2[:, 1] * g2[1]).astype(np.int64), g2[1] - 1)
    shift = np.asarray(_SHIFTS)[:, :, None]  # (4, 2, 1)
    c1x = np.floor(u1[:, 0] * g1[0] + shift[:, 0]).astype(np.int64)  # (4, K)
    c1y = np.floor(u1[:, 1] * g1[1] + shift[:, 1]).astype(np.int64)
    c1 = np.where((c1x < g1[0]) & (c1y < g1[1]), c1y * g1[0] + c1x, -1)
    # Kernel offsets: centre first, then the ring; image 2 uses the ring rotated by ``rotation`` steps.
    off1 = np.vstack([[0, 0], _RING]).astype(np.int64)
    off2 = np.vstack([[0, 0], np.roll(_RING, -rotation, axis=0)]).astype(np.int64)
    return _gms_kernel(c1, c2y * g2[0] + c2x, g1[0], g1[1], g2[0], g2[1], off1, off2, float(alpha))


@match_filter(label="GMS", shapes="check")
def gms_filter(
    ms: MatchSet,
    *,
    grid_size: int = 20,
    alpha: float = 6.0,
    with_scale: bool = False,
    with_rotation: bool = False,
    scale_ratios=GMS_SCALE_RATIOS,
    distinct_votes: bool = False,
) -> np.ndarray:
    """Grid-based Motion Statistics.

    Parameters
    ----------
    %(kpts)s
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many matches vote several times.
    %(scores_unused)s
    image_size1, image_size2 : (int, int)
        Image sizes (width, height); the grids span the images.
    %(shapes_unused)s
    grid_size : int, default 20
        Cells per side of the image-1 grid (CVPR 2017 Sec. 5, IJCV 2020 Sec. 6.1).
    alpha : float, default 6
        Threshold factor of ``tau = alpha * sqrt(n)`` (CVPR 2017 Eq. (5), Sec. 5).
    with_scale, with_rotation : bool, default False
        Try the image-2 grid scales ``scale_ratios`` / the 8 rotated kernels (IJCV 2020, Sec. 5).
    scale_ratios : sequence of float, default :data:`GMS_SCALE_RATIOS`
        Relative scales tried when ``with_scale``.
    distinct_votes : bool, default False
        Rows joining the same pair of locations vote once (the authors' code: each row votes, so copies of a
        wrong match can outvote sparse correct ones).

    Returns
    -------
    %(keep)s

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
    grid_size = check_positive(grid_size, "grid_size", integer=True)
    alpha = check_positive(alpha, "alpha", allow_zero=True)
    ratios = [check_positive(r, "scale_ratios") for r in np.atleast_1d(scale_ratios)] if with_scale else [1.0]
    if len(ms) == 0:
        return np.zeros(0, bool)
    x, y, inverse = ms.x, ms.y, None
    if distinct_votes:
        _, first, inverse = np.unique(np.hstack([x, y]), axis=0, return_index=True, return_inverse=True)
        x, y, inverse = x[first], y[first], inverse.reshape(-1)
    u1, u2 = _unit(x, ms.size1), _unit(y, ms.size2)
    g1 = (grid_size, grid_size)
    rotations = range(8) if with_rotation else [0]
    best = np.zeros(len(u1), bool)
    for r in ratios:
        side = max(int(grid_size * r), 1)  # truncated, as the reference sizes its image-2 grid
        for rot in rotations:
            keep = _run(u1, u2, g1, (side, side), rot, alpha)
            if keep.sum() > best.sum():
                best = keep
    return best if inverse is None else best[inverse]
