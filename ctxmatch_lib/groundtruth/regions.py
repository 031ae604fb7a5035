"""Ground-truth methods B and C: overlap of the keypoints' support regions (Sec. 5.1 and Appendix
"Ground truth estimation methods").

Method B (Bellavia & Colombo, IJCV 2020): overlap error ``1 - |E1' ∩ E2| / |E1' ∪ E2|`` at most 50 %, ``E1'``
the doubled image-1 support region carried into image 2 (exactly through ``H``; by the hand points'
:class:`~ctxmatch_lib.groundtruth.PiecewiseAffineMap` with its centre moved onto the epipolar line, our
choice; by the flow and its Jacobian). Method C adds the 30 px centre rule: ``C = B ∩ centre``. Where ``E1'``
is unknown or unbounded the overlap error is 1. :func:`region_overlap_error` integrates areas along rays
(compiled in :mod:`~ctxmatch_lib.groundtruth._kernels`); see docs/evaluation.md (Ground truth).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._numerics.fixedmath import sincos
from .._numerics.docstrings import shared_doc
from .._numerics.validation import as_matches, as_points
from ..blob.overlap import as_shapes, ellipse_overlap_error
from ..datasets.base import EpipolarGT, FlowGT, HomographyGT
from ..geometry import epipolar_errors, transfer_errors
from ._kernels import flow_label_kernel, flow_transfer_kernel, homography_ellipse_kernel, overlap_kernel
from .core import PiecewiseAffineMap

__all__ = [
    "OVERLAP_MAX", "CENTRE_THRESHOLD_PX", "SHAPE_SCALE", "N_ANGLES", "RegionErrors", "region_overlap_error",
    "homography_ellipses", "region_errors", "label_regions",
]

#: Method B/C: largest overlap error of a correct match (Sec. 5.1).
OVERLAP_MAX = 0.5
#: Method C: centre-distance threshold in pixels (Sec. 5.1).
CENTRE_THRESHOLD_PX = 30.0
#: Linear factor applied to the keypoints' shapes before the overlap (caption of the Appendix figure).
SHAPE_SCALE = 2.0
#: Angles of the ray integration of the intersection area.
N_ANGLES = 64

# Half the angles (each ray goes with its opposite), from _fixedmath: the same bits on any CPU.
_SIN, _COS = sincos(np.linspace(0.0, 2.0 * np.pi, N_ANGLES, endpoint=False)[: N_ANGLES // 2])
#: Margin over the threshold of the skip bound, above the integration's error (< 5e-3): labels unchanged.
_REJECT_MARGIN = 0.01


def region_overlap_error(c1, A1, c2, A2, *, reject_above: float = 1.0) -> np.ndarray:
    """Overlap error ``1 - |E1 ∩ E2| / |E1 ∪ E2|`` of ellipses ``{c + A u : |u| <= 1}``, element-wise.

    Same contract as :func:`ctxmatch_lib.blob.overlap.ellipse_overlap_error`, by ray integration.

    Parameters
    ----------
    c1, c2 : array_like of shape (P, 2)
        Centres, (x, y) pixels.
    A1, A2 : array_like of shape (P, 2, 2)
        Affine shapes (non-singular).
    reject_above : float
        Errors provably above this are returned as 1 without integration.

    Returns
    -------
    ndarray of shape (P,)
        In [0, 1]; 1 where a shape is not finite.

    Examples
    --------
    >>> import numpy as np
    >>> A = np.eye(2)[None]
    >>> err = region_overlap_error([[0.0, 0], [0, 0]], np.r_[A, A], [[0.0, 0], [5, 0]], np.r_[A * 2, A])
    >>> np.round(err, 3) + 0.0  # the unit disk inside the radius-2 disk: 1 - 1/4
    array([0.75, 1.  ])
    """
    c1 = np.ascontiguousarray(c1, dtype=np.float64).reshape(-1, 2)
    c2 = np.ascontiguousarray(c2, dtype=np.float64).reshape(-1, 2)
    A1 = np.ascontiguousarray(A1, dtype=np.float64).reshape(-1, 2, 2)
    A2 = np.ascontiguousarray(A2, dtype=np.float64).reshape(-1, 2, 2)
    if not len(c1) == len(c2) == len(A1) == len(A2):
        raise ValueError(f"c1, A1, c2, A2 must have the same length, got {len(c1)}, {len(A1)}, {len(c2)}, {len(A2)}")
    out = overlap_kernel(c1, A1, c2, A2, _COS, _SIN, float(reject_above))
    todo = np.flatnonzero(np.isnan(out))
    if len(todo):
        out[todo] = ellipse_overlap_error(c1[todo], A1[todo], c2[todo], A2[todo])
    return out


def homography_ellipses(H, centres, shapes) -> tuple[np.ndarray, np.ndarray]:
    """Exact images of ellipses ``{c + A u : |u| <= 1}`` (``centres`` (P, 2), ``shapes`` (P, 2, 2)) under ``H``.

    Returns the image centres and shapes (lower Cholesky factors), NaN where unbounded or ``H`` is singular.
    """
    H = np.asarray(H, dtype=np.float64)
    if H.shape != (3, 3):
        raise ValueError(f"H must have shape (3, 3), got {H.shape}")
    c = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 2)
    A = np.ascontiguousarray(shapes, dtype=np.float64).reshape(-1, 2, 2)
    try:
        Hinv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.full_like(c, np.nan), np.full_like(A, np.nan)
    return homography_ellipse_kernel(Hinv, c, A)


@dataclass(frozen=True)
class RegionErrors:
    """Per-match quantities of methods B and C.

    ``overlap`` (K,): overlap error of the scaled regions, 1 where unknown; ``centre`` (K,): centre distance
    of method C in pixels, inf if unknown; ``centres2``, ``shapes2`` (K, 2), (K, 2, 2): the scaled image-1
    region carried into image 2, NaN where unknown.
    """

    overlap: np.ndarray
    centre: np.ndarray
    centres2: np.ndarray
    shapes2: np.ndarray


def _flow_transfer(flow, name, c, A):
    """Regions ``c``, ``A`` carried by the flow field ``flow`` (the argument ``name``)."""
    return flow_transfer_kernel(_as_flow(flow, name), np.ascontiguousarray(c), np.ascontiguousarray(A))


def _as_flow(flow, name):
    flow = np.asarray(flow, dtype=np.float64)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"{name} must have shape (H, W, 2), got {flow.shape}")
    return flow


def _as_shapes(shapes, n, name):
    """``(N, 2, 2)`` float64 shapes (radii converted); bad shapes are not rejected but get overlap error 1."""
    arr = np.asarray(shapes, dtype=np.float64)
    if arr.ndim == 3:
        if arr.shape != (n, 2, 2):
            raise ValueError(f"{name} must have shape ({n}, 2, 2) (affine shapes) or ({n},) (radii), got {arr.shape}")
        return arr
    return as_shapes(arr, n, name)


@shared_doc
def region_errors(kpts1, kpts2, matches, gt, shapes1, shapes2, *, shape_scale: float = SHAPE_SCALE) -> RegionErrors:
    """Overlap error and centre distance of each match (methods B and C; see the module docstring).

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    gt : HomographyGT, EpipolarGT or FlowGT
    %(shapes)s
        Or ``(N,)`` radii.
    shape_scale : float
        Linear factor on the shapes (2 in the paper).

    Returns
    -------
    RegionErrors
    """
    p1, p2, A1, A2 = _matched(*_validated(kpts1, kpts2, matches, gt, shapes1, shapes2, shape_scale), shape_scale)
    q, B = _carry(gt, p1, A1)
    back = _carry_back(gt, p2, A2)
    overlap = _overlap(q, B, p2, A2, back, p1, A1)
    return RegionErrors(overlap=overlap, centre=_centre(gt, p1, p2, q, back), centres2=q, shapes2=B)


def _matched(kpts1, kpts2, S1, S2, matches, shape_scale):
    """The matched centres and scaled shapes ``p1, p2, A1, A2`` of validated arrays."""
    i, j = matches[:, 0], matches[:, 1]
    return kpts1[i], kpts2[j], S1[i] * shape_scale, S2[j] * shape_scale


def _validated(kpts1, kpts2, matches, gt, shapes1, shapes2, shape_scale):
    """Validated ``kpts1, kpts2, shapes1, shapes2`` (unscaled) and ``matches``."""
    if shapes1 is None or shapes2 is None:
        raise ValueError("shapes1 and shapes2 (the keypoints' affine shapes) are required by methods B and C")
    if not shape_scale > 0:
        raise ValueError(f"shape_scale must be positive, got {shape_scale}")
    kpts1 = as_points(kpts1, "kpts1")
    kpts2 = as_points(kpts2, "kpts2")
    S1 = _as_shapes(shapes1, len(kpts1), "shapes1")
    S2 = _as_shapes(shapes2, len(kpts2), "shapes2")
    matches = as_matches(matches, len(kpts1), len(kpts2))
    if not isinstance(gt, (HomographyGT, EpipolarGT, FlowGT)):
        raise TypeError(f"gt must be HomographyGT, EpipolarGT or FlowGT, got {type(gt).__name__}")
    return kpts1, kpts2, S1, S2, matches


def _carry(gt, p1, A1):
    """Regions of image 1 carried into image 2: centres (K, 2) and shapes (K, 2, 2), NaN where unknown."""
    K = len(p1)
    if isinstance(gt, HomographyGT):
        return homography_ellipses(np.asarray(gt.H, float), p1, A1)
    if isinstance(gt, FlowGT):
        return _flow_transfer(gt.flow12, "gt.flow12", p1, A1)
    q, B = np.full((K, 2), np.nan), np.full((K, 2, 2), np.nan)
    try:
        pam = PiecewiseAffineMap(gt.pts1, gt.pts2)
    except ValueError:
        return q, B
    if not K:
        return q, B
    simplex, _ = pam.locate(p1, bruteforce=True)
    aff = pam.affine[simplex]  # (K, 2, 3)
    q = np.einsum("kij,kj->ki", aff[:, :, :2], p1) + aff[:, :, 2]
    B = aff[:, :, :2] @ A1
    # The true position lies on the epipolar line: keep only the along-line part of the coarse map.
    line = np.c_[p1, np.ones(K)] @ np.asarray(gt.F, float).T
    with np.errstate(invalid="ignore", divide="ignore"):
        t = ((np.c_[q, np.ones(K)] * line).sum(1) / (line[:, :2] ** 2).sum(1))[:, None]
    onto = q - t * line[:, :2]
    return np.where(np.isfinite(onto).all(1, keepdims=True), onto, q), B


def _carry_back(gt, p2, A2):
    """Regions of image 2 carried into image 1 (flow pairs with ``flow21`` only), else None."""
    if isinstance(gt, FlowGT) and gt.flow21 is not None:
        return _flow_transfer(gt.flow21, "gt.flow21", p2, A2)
    return None


def _overlap(q, B, p2, A2, back, p1, A1, reject_above=1.0):
    overlap = region_overlap_error(q, B, p2, A2, reject_above=reject_above)
    if back is not None:
        overlap = np.minimum(overlap, region_overlap_error(back[0], back[1], p1, A1, reject_above=reject_above))
    return overlap


def _centre(gt, p1, p2, q=None, back=None):
    """Centre distance of method C (pixels, inf if unknown); flow pairs read it off the carried centres."""
    if isinstance(gt, HomographyGT):
        return np.maximum(*transfer_errors(np.asarray(gt.H, float), p1, p2))
    if isinstance(gt, EpipolarGT):
        return np.maximum(*epipolar_errors(np.asarray(gt.F, float), p1, p2))
    with np.errstate(invalid="ignore"):
        centre = np.linalg.norm(q - p2, axis=1)
        if back is not None:
            centre = np.fmin(centre, np.linalg.norm(back[0] - p1, axis=1))
    return np.where(np.isnan(centre), np.inf, centre)


def label_regions(kpts1, kpts2, matches, gt, shapes1, shapes2, *, method: str = "C", overlap: float = OVERLAP_MAX,
                  centre_threshold: float = CENTRE_THRESHOLD_PX, shape_scale: float = SHAPE_SCALE) -> np.ndarray:
    """Method B (overlap error at most ``overlap``) or C (B and centre distance at most ``centre_threshold``).

    Parameters are those of :func:`region_errors`, plus ``method`` ("B" or "C"), ``overlap`` (0.5 in the
    paper) and ``centre_threshold`` (30 px in the paper, inclusive). Returns a (K,) bool array.
    """
    if method not in ("B", "C"):
        raise ValueError(f"method must be 'B' or 'C', got {method!r}")
    if not 0 <= overlap <= 1:
        raise ValueError(f"overlap must be in [0, 1], got {overlap}")
    if not centre_threshold > 0:
        raise ValueError(f"centre_threshold must be positive, got {centre_threshold}")
    rej = overlap + _REJECT_MARGIN
    if isinstance(gt, FlowGT):
        return _label_flow(kpts1, kpts2, matches, gt, shapes1, shapes2, shape_scale, method, overlap,
                           centre_threshold, rej)
    p1, p2, A1, A2 = _matched(*_validated(kpts1, kpts2, matches, gt, shapes1, shapes2, shape_scale), shape_scale)
    if method == "B":
        return _overlap(*_carry(gt, p1, A1), p2, A2, _carry_back(gt, p2, A2), p1, A1, rej) <= overlap
    # C: the centre constraint first, the overlap only where it holds (same labels, less work).
    ok = _centre(gt, p1, p2) <= centre_threshold
    i = np.flatnonzero(ok)
    ok[i] = _overlap(*_carry(gt, p1[i], A1[i]), p2[i], A2[i], None, p1[i], A1[i], rej) <= overlap
    return ok


def _label_flow(kpts1, kpts2, matches, gt, shapes1, shapes2, shape_scale, method, overlap, centre_threshold, rej):
    """:func:`label_regions` on a flow pair in one compiled pass, plus the polygon fallback."""
    kpts1, kpts2, S1, S2, matches = _validated(kpts1, kpts2, matches, gt, shapes1, shapes2, shape_scale)
    flow12 = _as_flow(gt.flow12, "gt.flow12")
    flow21 = np.empty((0, 0, 2)) if gt.flow21 is None else _as_flow(gt.flow21, "gt.flow21")
    cmax = centre_threshold if method == "C" else np.inf
    err, centre = flow_label_kernel(flow12, flow21, kpts1, kpts2, S1, S2, matches[:, 0], matches[:, 1],
                                    float(shape_scale), float(cmax), _COS, _SIN, float(rej))
    todo = np.flatnonzero(np.isnan(err))
    if len(todo):
        p1, p2, A1, A2 = _matched(kpts1, kpts2, S1, S2, matches[todo], shape_scale)
        err[todo] = _overlap(*_carry(gt, p1, A1), p2, A2, _carry_back(gt, p2, A2), p1, A1, rej)
    ok = err <= overlap
    if method == "C":
        ok &= centre <= centre_threshold
    return ok
