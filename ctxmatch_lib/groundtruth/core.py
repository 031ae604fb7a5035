"""Ground-truth methods A and D: centre distances only (Sec. 5.1 and Appendix "Ground truth estimation methods").

Method D, 15 px inclusive: :func:`label_homography` (reprojection in both directions, so the label does not
depend on the image order), :func:`label_epipolar` (both epipolar distances plus :func:`localisation_check`,
our rule: the paper defers it to Bellavia & Colombo, IJCV 2020), :func:`label_flow` (either flow direction,
Sec. 5.1 SUN3D protocol). Method A drops the localisation check.
"""

from __future__ import annotations

import numpy as np

from .._numerics.docstrings import shared_doc
from .._numerics.validation import as_matches, as_points
from ..geometry import epipolar_errors, transfer_errors

__all__ = [
    "GT_THRESHOLD_PX", "LOCALISATION_RATIO", "label_homography", "label_epipolar", "label_flow", "localisation_check",
    "PiecewiseAffineMap", "sample_flow",
]

#: Method-D distance threshold in pixels (Sec. 5.1).
GT_THRESHOLD_PX = 15.0

#: Radius of the localisation check as a fraction of the longest edge of the hand-point triangle.
LOCALISATION_RATIO = 0.5


def _match_points(kpts1, kpts2, matches):
    kpts1 = as_points(kpts1, "kpts1")
    kpts2 = as_points(kpts2, "kpts2")
    matches = as_matches(matches, len(kpts1), len(kpts2))
    return kpts1[matches[:, 0]], kpts2[matches[:, 1]]


@shared_doc
def label_homography(kpts1, kpts2, matches, H, *, threshold: float = GT_THRESHOLD_PX) -> np.ndarray:
    """Method D, planar: reprojection error at most ``threshold`` pixels in both directions.

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    H : array_like of shape (3, 3)
        Maps image 1 to image 2.
    threshold : float
        Pixels (inclusive).

    Returns
    -------
    ndarray of shape (K,), bool

    Examples
    --------
    >>> import numpy as np
    >>> H = np.array([[1.0, 0, 20], [0, 1, 0], [0, 0, 1]])
    >>> k1 = np.array([[0.0, 0.0], [50.0, 50.0]])
    >>> k2 = np.array([[20.0, 0.0], [90.0, 50.0]])
    >>> label_homography(k1, k2, [[0, 0], [1, 1], [0, 1]], H)
    array([ True, False, False])
    """
    p1, p2 = _match_points(kpts1, kpts2, matches)
    fwd, bwd = transfer_errors(np.asarray(H, np.float64), p1, p2)  # p1, p2 validated above
    return (fwd <= threshold) & (bwd <= threshold)


@shared_doc
def label_epipolar(kpts1, kpts2, matches, F, *, hand_pts1=None, hand_pts2=None, threshold: float = GT_THRESHOLD_PX,
                   localise: bool = True, ratio: float = LOCALISATION_RATIO) -> np.ndarray:
    """Method D, non-planar (``localise=True``) or method A (``localise=False``).

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    F : array_like of shape (3, 3)
        ``x2^T F x1 = 0``.
    hand_pts1, hand_pts2 : array_like of shape (M, 2), optional
        Hand-taken correspondences, required when ``localise``.
    threshold : float
        Epipolar distance threshold in pixels (inclusive), in both images.
    localise, ratio : bool, float
        Apply :func:`localisation_check`, with this ``ratio``.

    Returns
    -------
    ndarray of shape (K,), bool
    """
    p1, p2 = _match_points(kpts1, kpts2, matches)
    d2, d1 = epipolar_errors(np.asarray(F, np.float64), p1, p2)  # p1, p2 validated above
    ok = np.maximum(d1, d2) <= threshold
    if localise:
        if hand_pts1 is None or hand_pts2 is None:
            raise ValueError("hand_pts1 and hand_pts2 are required for the localisation check (method D)")
        if ok.any():
            ok[ok] = localisation_check(hand_pts1, hand_pts2, p1[ok], p2[ok], threshold=threshold, ratio=ratio)
    return ok


class PiecewiseAffineMap:
    """Piecewise-affine map from the Delaunay triangulation of corresponding points ``src``, ``dst`` (M, 2).

    Each triangle of ``src`` maps affinely onto the same vertices in ``dst``; points outside the hull use the
    triangle owning the nearest hull edge. ValueError for M < 3 or a degenerate ``src``.
    """

    def __init__(self, src, dst):
        from scipy.spatial import Delaunay, QhullError

        src = as_points(src, "src")
        dst = as_points(dst, "dst", n=len(src))
        if len(src) < 3:
            raise ValueError(f"src needs at least 3 hand-taken points for a triangulation, got {len(src)}")
        try:
            self.tri = Delaunay(src)
        except QhullError as exc:
            raise ValueError(f"src points are degenerate (collinear or duplicated): {exc}") from None
        self.src, self.dst = src, dst
        simp = self.tri.simplices
        # Affine map per triangle: [x', y'] = A @ [x, y, 1], solved from its three vertices.
        S = np.concatenate([src[simp], np.ones(simp.shape + (1,))], axis=2)  # (T, 3, 3)
        D = dst[simp]  # (T, 3, 2)
        # pinv tolerates the rare sliver triangle that solve() would reject as singular.
        self.affine = np.transpose(np.linalg.pinv(S) @ D, (0, 2, 1))  # (T, 2, 3)
        edges = D[:, [1, 2, 0]] - D
        #: Longest edge of each triangle in ``dst`` (pixels).
        self.size_dst = np.linalg.norm(edges, axis=2).max(axis=1)
        #: Linear scale of each affine map, sqrt(|det A|).
        self.scale = np.sqrt(np.abs(np.linalg.det(self.affine[:, :, :2])))
        # Hull edges and the triangle owning each (neighbour -1 across the edge opposite vertex j).
        tri_idx, opp = np.nonzero(self.tri.neighbors == -1)
        a = simp[tri_idx, (opp + 1) % 3]
        b = simp[tri_idx, (opp + 2) % 3]
        self._hull = (src[a], src[b], tri_idx)

    def locate(self, pts, *, bruteforce: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Triangle used for each point and its distance (pixels) outside the hull (0 inside).

        ``bruteforce=True`` makes the triangle of a point on a shared edge independent of the batch
        (methods B and C need it)."""
        pts = as_points(pts, "pts")
        simplex = self.tri.find_simplex(pts, bruteforce=bruteforce)
        dist = np.zeros(len(pts))
        out = np.flatnonzero(simplex < 0)
        if len(out):
            a, b, owner = self._hull
            p = pts[out][:, None, :]  # (O, 1, 2)
            ab = (b - a)[None]
            t = np.clip(((p - a[None]) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
            d = np.linalg.norm(p - (a[None] + t[..., None] * ab), axis=2)  # (O, E)
            nearest = d.argmin(axis=1)
            simplex[out] = owner[nearest]
            dist[out] = d[np.arange(len(out)), nearest]
        return simplex, dist

    def __call__(self, pts) -> np.ndarray:
        """Map ``(N, 2)`` points from ``src`` to ``dst``."""
        pts = as_points(pts, "pts")
        simplex, _ = self.locate(pts)
        A = self.affine[simplex]
        return np.einsum("nij,nj->ni", A, np.c_[pts, np.ones(len(pts))])


@shared_doc
def localisation_check(hand_pts1, hand_pts2, pts1, pts2, *, threshold: float = GT_THRESHOLD_PX,
                       ratio: float = LOCALISATION_RATIO) -> np.ndarray:
    """Spatial-localisation check of method D against hand-taken correspondences (our rule).

    ``(x1, x2)`` passes when, in both directions, ``||A_T(x1) - x2|| <= max(threshold, ratio * L_T) + s_T *
    d_out``: ``A_T`` the affine map of the hand points' :class:`PiecewiseAffineMap` triangle used for ``x1``,
    ``L_T`` its longest edge in the target image, ``s_T = sqrt(|det A_T|)``, ``d_out`` the distance of ``x1``
    outside the hull. Without a triangulation every correspondence passes (D = A).

    Parameters
    ----------
    hand_pts1, hand_pts2 : array_like of shape (M, 2)
        Hand-taken corresponding points.
    %(pts)s
    threshold, ratio : float
        Minimum radius in pixels; radius as a fraction of the triangle's longest edge.

    Returns
    -------
    ndarray of shape (K,), bool
    """
    pts1 = as_points(pts1, "pts1")
    pts2 = as_points(pts2, "pts2", n=len(pts1))
    hand_pts1 = as_points(hand_pts1, "hand_pts1")
    hand_pts2 = as_points(hand_pts2, "hand_pts2", n=len(hand_pts1))
    ok = np.ones(len(pts1), bool)
    if len(pts1) == 0:
        return ok
    for src_h, dst_h, src, dst in ((hand_pts1, hand_pts2, pts1, pts2), (hand_pts2, hand_pts1, pts2, pts1)):
        try:
            pam = PiecewiseAffineMap(src_h, dst_h)
        except ValueError:
            return ok
        simplex, dist = pam.locate(src)
        mapped = np.einsum("nij,nj->ni", pam.affine[simplex], np.c_[src, np.ones(len(src))])
        radius = np.maximum(threshold, ratio * pam.size_dst[simplex]) + pam.scale[simplex] * dist
        ok &= np.linalg.norm(mapped - dst, axis=1) <= radius
    return ok


def sample_flow(flow, pts) -> np.ndarray:
    """Displacement (N, 2) of each (x, y) point read from ``flow`` (H, W, 2) at its nearest pixel.

    Pixel (row r, col c) is x = c, y = r; NaN outside the field.
    """
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must have shape (H, W, 2), got {flow.shape}")
    pts = as_points(pts, "pts")
    col = np.rint(pts[:, 0]).astype(np.int64)
    row = np.rint(pts[:, 1]).astype(np.int64)
    inside = (col >= 0) & (col < flow.shape[1]) & (row >= 0) & (row < flow.shape[0])
    out = np.full((len(pts), 2), np.nan)
    out[inside] = flow[row[inside], col[inside]]
    return out


@shared_doc
def label_flow(kpts1, kpts2, matches, flow12, flow21=None, *, threshold: float = GT_THRESHOLD_PX) -> np.ndarray:
    """Dense ground truth: correct if either direction lands within ``threshold`` (unknown: a miss).

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    flow12 : ndarray of shape (H1, W1, 2)
        Image 1 -> image 2 displacement, NaN where unknown.
    flow21 : ndarray of shape (H2, W2, 2), optional
        Image 2 -> image 1 displacement.
    threshold : float
        Pixels (inclusive).

    Returns
    -------
    ndarray of shape (K,), bool
    """
    p1, p2 = _match_points(kpts1, kpts2, matches)
    with np.errstate(invalid="ignore"):
        ok = np.linalg.norm(p1 + sample_flow(flow12, p1) - p2, axis=1) <= threshold
        if flow21 is not None:
            ok |= np.linalg.norm(p2 + sample_flow(flow21, p2) - p1, axis=1) <= threshold
    return ok
