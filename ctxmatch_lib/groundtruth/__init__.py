"""Ground-truth labels: is each match correct? (Sec. 5.1 and Appendix "Ground truth estimation methods").

The four methods the paper compares, all selected by :func:`label_matches` (``method=``):

* ``"D"`` (the paper's choice): centre distance at most 15 px, plus the localisation check on non-planar
  pairs (:mod:`~ctxmatch_lib.groundtruth.core`);
* ``"A"``: the epipolar distance alone (the Appendix figure uses 7 px; pass ``threshold=7``);
* ``"B"``: overlap error of the doubled support regions at most 50 %, true overlap through the homography,
  approximated through the local affine map of the hand-taken correspondences or of the dense flow
  (:mod:`~ctxmatch_lib.groundtruth.regions`);
* ``"C"``: B and the centre distance (reprojection, epipolar or flow transfer) at most 30 px.

Calibrated pairs (:class:`~ctxmatch_lib.datasets.PoseGT`) follow the paper's SUN3D rule when no depth is
available (Sec. 5.1, end of "Ground truth"): a match is correct when the larger of its two epipolar
distances, to the lines of the ground-truth ``F = K2^-T [t]x R K1^-1``, is at most the threshold times the
pair's ``threshold_scale``; methods A and D coincide there (no hand-taken points to localise against), and
B and C are refused (no local affine map without depth).

Keypoints everywhere are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left
pixel; ``matches`` is ``(K, 2)`` int64 into them.
"""

from __future__ import annotations

import numpy as np

from ..datasets.base import EpipolarGT, FlowGT, HomographyGT, PoseGT
from .core import (
    GT_THRESHOLD_PX,
    LOCALISATION_RATIO,
    PiecewiseAffineMap,
    label_epipolar,
    label_flow,
    label_homography,
    localisation_check,
    sample_flow,
)
from .regions import (
    CENTRE_THRESHOLD_PX,
    OVERLAP_MAX,
    SHAPE_SCALE,
    RegionErrors,
    homography_ellipses,
    label_regions,
    region_errors,
    region_overlap_error,
)

__all__ = [
    "GT_THRESHOLD_PX",
    "GT_METHODS",
    "LOCALISATION_RATIO",
    "OVERLAP_MAX",
    "CENTRE_THRESHOLD_PX",
    "SHAPE_SCALE",
    "label_matches",
    "label_homography",
    "label_epipolar",
    "label_flow",
    "label_regions",
    "localisation_check",
    "PiecewiseAffineMap",
    "RegionErrors",
    "region_errors",
    "region_overlap_error",
    "homography_ellipses",
    "sample_flow",
]

#: Ground-truth methods: "D" (the paper's choice), "A" (epipolar distance only), "B" (region overlap) and
#: "C" (region overlap and centre distance).
GT_METHODS = ("D", "A", "B", "C")


def label_matches(
    kpts1,
    kpts2,
    matches,
    gt,
    *,
    method: str = "D",
    threshold: float = GT_THRESHOLD_PX,
    ratio: float = LOCALISATION_RATIO,
    shapes1=None,
    shapes2=None,
    overlap: float = OVERLAP_MAX,
    centre_threshold: float = CENTRE_THRESHOLD_PX,
    shape_scale: float = SHAPE_SCALE,
) -> np.ndarray:
    """Correct/incorrect label of each match under the pair's ground truth.

    Dispatches on the method and the ground-truth type (rules in :mod:`~ctxmatch_lib.groundtruth.core` for
    A and D, :mod:`~ctxmatch_lib.groundtruth.regions` for B and C).

    Parameters
    ----------
    kpts1, kpts2 : array_like of shape (N1, 2), (N2, 2)
        (x, y) pixels, origin at the centre of the top-left pixel.
    matches : array_like of shape (K, 2), int
        Indices into ``kpts1``/``kpts2`` (many-to-many allowed).
    gt : HomographyGT, EpipolarGT, FlowGT or PoseGT
        The pair's ground truth.
    method : {"D", "A", "B", "C"}
        Method D (the paper's), A (epipolar distance only, for ``EpipolarGT``), B (overlap of the support
        regions) or C (B and centre distance).
    threshold : float
        Pixels (15 in the paper) of methods A and D; B and C ignore it (see ``centre_threshold``). On a
        :class:`PoseGT` it is multiplied by ``gt.threshold_scale`` (the pair's image size relative to the
        paper's, e.g. 3 for the 3072 px Strecha views).
    ratio : float
        Localisation radius ratio (:func:`localisation_check`).
    shapes1, shapes2 : array_like of shape (N1, 2, 2), (N2, 2, 2), optional
        Affine shapes of the keypoints' support regions (the patch of keypoint k is
        ``{kpts[k] + A[k] u : |u| <= 1}``); methods B and C need them, methods A and D ignore them.
    overlap : float
        Methods B and C: largest overlap error (0.5 in the paper).
    centre_threshold : float
        Method C: largest centre distance in pixels (30 in the paper).
    shape_scale : float
        Methods B and C: linear factor on the shapes (2, the Appendix figure's caption).

    Returns
    -------
    ndarray of shape (K,), bool
    """
    if method not in GT_METHODS:
        raise ValueError(f"method must be one of {GT_METHODS}, got {method!r}")
    if threshold <= 0:
        raise ValueError(f"threshold must be positive, got {threshold}")
    if method in ("B", "C") and isinstance(gt, PoseGT):
        raise ValueError(f"method {method!r} needs a local affine map between the images (a homography, "
                         "hand-taken points or a dense flow); a calibrated pair (PoseGT) has none without "
                         "depth: use method 'D' (or 'A', the same rule there)")
    if method in ("B", "C"):
        return label_regions(kpts1, kpts2, matches, gt, shapes1, shapes2, method=method, overlap=overlap,
                             centre_threshold=centre_threshold, shape_scale=shape_scale)
    if isinstance(gt, HomographyGT):
        return label_homography(kpts1, kpts2, matches, gt.H, threshold=threshold)
    if isinstance(gt, EpipolarGT):
        return label_epipolar(
            kpts1,
            kpts2,
            matches,
            gt.F,
            hand_pts1=gt.pts1,
            hand_pts2=gt.pts2,
            threshold=threshold,
            localise=method == "D",
            ratio=ratio,
        )
    if isinstance(gt, FlowGT):
        return label_flow(kpts1, kpts2, matches, gt.flow12, gt.flow21, threshold=threshold)
    if isinstance(gt, PoseGT):  # Sec. 5.1, SUN3D without depth: the larger epipolar distance
        return label_epipolar(kpts1, kpts2, matches, gt.F, threshold=threshold * gt.threshold_scale,
                              localise=False)
    raise TypeError(f"gt must be HomographyGT, EpipolarGT, FlowGT or PoseGT, got {type(gt).__name__}")
