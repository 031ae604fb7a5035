"""Ground-truth labels: is each match correct? (Sec. 5.1 and Appendix "Ground truth estimation methods").

:func:`label_matches` selects one of the paper's four methods: ``"D"`` (the paper's) and ``"A"`` in
:mod:`~ctxmatch_lib.groundtruth.core`, ``"B"`` and ``"C"`` in :mod:`~ctxmatch_lib.groundtruth.regions`.
Calibrated pairs (:class:`~ctxmatch_lib.datasets.PoseGT`) follow the SUN3D rule without depth (Sec. 5.1):
the larger epipolar distance to ``gt.F`` within the threshold times ``gt.threshold_scale`` (A = D; no B, C).
"""

from __future__ import annotations

import numpy as np

from .._numerics.docstrings import shared_doc
from ..datasets.base import EpipolarGT, FlowGT, HomographyGT, PoseGT
from .core import (GT_THRESHOLD_PX, LOCALISATION_RATIO, PiecewiseAffineMap, label_epipolar, label_flow,
                   label_homography, localisation_check, sample_flow)
from .regions import (CENTRE_THRESHOLD_PX, OVERLAP_MAX, SHAPE_SCALE, RegionErrors, homography_ellipses, label_regions,
                      region_errors, region_overlap_error)

__all__ = [
    "GT_THRESHOLD_PX", "GT_METHODS", "LOCALISATION_RATIO", "OVERLAP_MAX", "CENTRE_THRESHOLD_PX", "SHAPE_SCALE",
    "label_matches", "label_homography", "label_epipolar", "label_flow", "label_regions", "localisation_check",
    "PiecewiseAffineMap", "RegionErrors", "region_errors", "region_overlap_error", "homography_ellipses",
    "sample_flow",
]

#: Ground-truth methods, the paper's choice first (module docstring).
GT_METHODS = ("D", "A", "B", "C")


@shared_doc
def label_matches(kpts1, kpts2, matches, gt, *, method: str = "D", threshold: float = GT_THRESHOLD_PX,
                  ratio: float = LOCALISATION_RATIO, shapes1=None, shapes2=None, overlap: float = OVERLAP_MAX,
                  centre_threshold: float = CENTRE_THRESHOLD_PX, shape_scale: float = SHAPE_SCALE) -> np.ndarray:
    """Correct/incorrect label of each match under the pair's ground truth (see the module docstring).

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    gt : HomographyGT, EpipolarGT, FlowGT or PoseGT
    method : {"D", "A", "B", "C"}
    threshold : float
        Pixels (15 in the paper) of methods A and D, times ``gt.threshold_scale`` on a :class:`PoseGT`.
    ratio : float
        Localisation radius ratio (:func:`localisation_check`).
    %(shapes)s
        Needed by methods B and C only.
    overlap, centre_threshold, shape_scale : float
        Methods B and C (:func:`label_regions`): largest overlap error, centre distance, factor on the shapes.

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
        return label_epipolar(kpts1, kpts2, matches, gt.F, hand_pts1=gt.pts1, hand_pts2=gt.pts2, threshold=threshold,
                              localise=method == "D", ratio=ratio)
    if isinstance(gt, FlowGT):
        return label_flow(kpts1, kpts2, matches, gt.flow12, gt.flow21, threshold=threshold)
    if isinstance(gt, PoseGT):  # Sec. 5.1, SUN3D without depth: the larger epipolar distance
        return label_epipolar(kpts1, kpts2, matches, gt.F, threshold=threshold * gt.threshold_scale,
                              localise=False)
    raise TypeError(f"gt must be HomographyGT, EpipolarGT, FlowGT or PoseGT, got {type(gt).__name__}")
