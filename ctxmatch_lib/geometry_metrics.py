"""Accuracy of an estimated two-view model against the ground truth, and its AUC over pairs.

:func:`homography_corner_error` (glue-factory's), :func:`epipolar_consistency` (the WxBS benchmark's share
of ground-truth correspondences consistent with F), :func:`pose_auc` (SuperGlue's AUC) and
:func:`geometry_table`. ``H`` maps image 1 to image 2, ``x2^T F x1 = 0``. See docs/evaluation.md.
"""

from __future__ import annotations

import numpy as np

from ._numerics.docstrings import shared_doc
from ._numerics.validation import as_points
from .datasets.base import EpipolarGT, FlowGT, HomographyGT, PoseGT
from .geometry import epipolar_distances

__all__ = [
    "EPIPOLAR_THRESHOLDS_PX",
    "CORNER_AUC_THRESHOLDS_PX",
    "POSE_AUC_THRESHOLDS_DEG",
    "FLOW_SAMPLE_POINTS",
    "image_corners",
    "homography_corner_error",
    "symmetric_epipolar_distance",
    "epipolar_consistency",
    "gt_correspondences",
    "pose_auc",
    "time_to_geometry",
    "geometry_table",
]

#: The thresholds of the epipolar consistency, in pixels: 1 ... 19 (WxBS's 0 gives 0 for any real estimate).
EPIPOLAR_THRESHOLDS_PX = np.arange(1, 20, dtype=np.float64)

#: The thresholds of the AUC of the corner error: glue-factory's HPatches ones (1, 3, 5 px) and 10 px.
CORNER_AUC_THRESHOLDS_PX = (1.0, 3.0, 5.0, 10.0)

#: The thresholds of the AUC of the pose error (degrees) that SuperGlue, LoFTR, glue-factory and fb82/MiHo report.
POSE_AUC_THRESHOLDS_DEG = (5.0, 10.0, 20.0)

#: How many correspondences :func:`gt_correspondences` samples from a dense ground truth.
FLOW_SAMPLE_POINTS = 2000


def image_corners(image_size) -> np.ndarray:
    """The four outer corners ``(4, 2)`` of a ``(width, height)`` image, clockwise from the top left.

    Examples
    --------
    >>> image_corners((4, 2))
    array([[-0.5, -0.5],
           [ 3.5, -0.5],
           [ 3.5,  1.5],
           [-0.5,  1.5]])
    """
    size = np.asarray(image_size, dtype=np.float64).reshape(-1)
    if size.shape != (2,) or not np.isfinite(size).all() or (size <= 0).any():
        raise ValueError(f"image_size must be (width, height) in pixels, got {image_size!r}")
    w, h = size
    return np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]) - 0.5


def homography_corner_error(H, H_gt, image_size) -> float:
    """Mean distance between the image-1 corners mapped by ``H`` and by ``H_gt``, in image-2 pixels.

    glue-factory's ``homography_corner_error`` (the HPatches metric) on the corners of :func:`image_corners`.

    Parameters
    ----------
    H : array_like of shape (3, 3) or None
        The estimate; ``None`` when there is no model (error ``inf``).
    H_gt : array_like of shape (3, 3)
    image_size : (int, int)
        (width, height) of image 1.

    Examples
    --------
    >>> import numpy as np
    >>> shift = np.array([[1.0, 0, 3], [0, 1, 4], [0, 0, 1]])
    >>> homography_corner_error(shift, np.eye(3), (640, 480))
    5.0
    """
    corners = image_corners(image_size)
    H_gt = _matrix(H_gt, "H_gt")
    if H is None:
        return float("inf")
    H = _matrix(H, "H")
    dx, dy = _map_by_products(H, corners) - _map_by_products(H_gt, corners)
    d = np.sqrt(dx * dx + dy * dy)
    if not np.isfinite(d).all():
        return float("inf")
    return float(d.mean())


def _map_by_products(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """``(2, N)`` points mapped by ``H``, one rounding per product and sum: a BLAS product's multiply-adds round
    by CPU (its kernel), and the corner error is a committed number. ``inf`` where a point maps to infinity."""
    x, y = pts[:, 0], pts[:, 1]
    u, v, w = (H[i, 0] * x + H[i, 1] * y + H[i, 2] for i in range(3))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.stack([u / w, v / w])
    out[:, ~np.isfinite(out).all(axis=0) | (np.abs(w) < 1e-12)] = np.inf
    return out


def _matrix(M, name: str) -> np.ndarray:
    M = np.asarray(M, dtype=np.float64)
    if M.shape != (3, 3):
        raise ValueError(f"{name} must be a 3x3 matrix, got shape {M.shape}")
    return M


@shared_doc
def symmetric_epipolar_distance(F, pts1, pts2) -> np.ndarray:
    """``sqrt(d1^2 + d2^2)`` of the two point-to-epipolar-line distances (``inf`` at an epipole).

    kornia's ``symmetrical_epipolar_distance(..., squared=False)``.

    Parameters
    ----------
    F : array_like of shape (3, 3)
    %(pts)s

    Examples
    --------
    >>> import numpy as np
    >>> F = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # a horizontal translation: lines y' = y
    >>> symmetric_epipolar_distance(F, [[0.0, 0.0], [5.0, 2.0]], [[3.0, 0.0], [1.0, 5.0]])
    array([0.        , 4.24264069])
    """
    d2, d1 = epipolar_distances(_matrix(F, "F"), pts1, pts2)
    return np.hypot(d1, d2)


@shared_doc
def epipolar_consistency(F, pts1, pts2, thresholds=EPIPOLAR_THRESHOLDS_PX) -> np.ndarray:
    """Share of ground-truth correspondences within each threshold of ``F``'s epipolar lines (WxBS's score);
    NaN without correspondences.

    Parameters
    ----------
    F : array_like of shape (3, 3) or None
        The estimate; ``None`` when there is no model (every share 0).
    %(pts)s
    thresholds : array_like of shape (T,)
        In pixels.

    Examples
    --------
    >>> import numpy as np
    >>> F = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    >>> epipolar_consistency(F, [[0, 0], [5, 2]], [[3, 0], [1, 5]], thresholds=[1, 5])
    array([0.5, 1. ])
    """
    pts1 = as_points(pts1, "pts1")
    pts2 = as_points(pts2, "pts2", n=len(pts1))
    th = np.asarray(thresholds, dtype=np.float64).reshape(-1)
    if len(pts1) == 0:
        return np.full(len(th), np.nan)
    if F is None:
        return np.zeros(len(th))
    d = symmetric_epipolar_distance(F, pts1, pts2)
    return (d[:, None] <= th[None, :]).mean(axis=0)


def gt_correspondences(gt, *, max_points: int = FLOW_SAMPLE_POINTS):
    """Ground-truth correspondences to score F on: ``EpipolarGT``'s points, up to ``max_points`` evenly spaced
    known pixels of a ``FlowGT`` and their targets, or ``None`` (``HomographyGT``, ``PoseGT``)."""
    if isinstance(gt, EpipolarGT):
        return np.asarray(gt.pts1, np.float64), np.asarray(gt.pts2, np.float64)
    if isinstance(gt, (HomographyGT, PoseGT)):
        return None
    if not isinstance(gt, FlowGT):
        raise TypeError(f"gt must be HomographyGT, EpipolarGT or FlowGT, got {type(gt).__name__}")
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) or max_points < 1:
        raise ValueError(f"max_points must be a positive integer, got {max_points!r}")
    flow = np.asarray(gt.flow12, np.float64)
    known = np.flatnonzero(np.isfinite(flow).all(axis=2).reshape(-1))
    if len(known) > max_points:
        known = known[np.unique(np.round(np.linspace(0, len(known) - 1, int(max_points))).astype(np.int64))]
    row, col = np.divmod(known, flow.shape[1])
    pts1 = np.c_[col, row].astype(np.float64)
    return pts1, pts1 + flow.reshape(-1, 2)[known]


def pose_auc(errors, thresholds) -> np.ndarray:
    """Area under the cumulative error curve up to each threshold, divided by the threshold.

    SuperGlue's ``pose_auc``: every pair stays in the denominator (NaN counts as ``inf``); NaN without pairs.

    Parameters
    ----------
    errors : array_like of shape (N,)
        Non-negative, one per pair (``inf`` for a failure).
    thresholds : array_like of shape (T,)
        Positive.

    Examples
    --------
    >>> pose_auc([0.0, 2.0, float("inf"), 1.0], [1.0, 2.0])
    array([0.25  , 0.4375])
    """
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    th = np.asarray(thresholds, dtype=np.float64).reshape(-1)
    if (th <= 0).any() or not np.isfinite(th).all():
        raise ValueError(f"thresholds must be positive and finite, got {th.tolist()}")
    if (e < 0).any():
        raise ValueError("errors must be non-negative (inf or NaN for a pair without a model)")
    n = len(e)
    if n == 0:
        return np.full(len(th), np.nan)
    e = np.sort(np.where(np.isnan(e), np.inf, e))
    out = np.empty(len(th))
    for i, t in enumerate(th):
        k = int(np.searchsorted(e, t, side="left"))  # pairs with an error below t
        x = np.r_[0.0, e[:k], t]
        r = np.r_[0.0, np.arange(1, k + 1) / n, k / n]
        out[i] = np.sum(np.diff(x) * (r[1:] + r[:-1])) / 2.0 / t
    return out


def time_to_geometry(rows, *, standalone=("blob", "opencv_ratio", "opencv_mnn")):
    """Seconds from the features to the model per row: ``time_s + model_time_s``, plus the ``blob`` row's
    ``time_s`` for a filter (not for ``standalone`` methods); NaN for model ``none``."""
    keys = ["dataset", "pair_id", "features", "blob"]
    blob_time = rows[rows["method"] == "blob"].groupby(keys)["time_s"].first().rename("_blob_time_s")
    base = rows[keys].join(blob_time, on=keys)["_blob_time_s"].where(~rows["method"].isin(standalone), 0.0)
    total = rows["time_s"] + rows["model_time_s"] + base
    return total.where(rows["model"] != "none")


def geometry_table(rows, *, by=("kind", "blob", "method", "model"), thresholds=CORNER_AUC_THRESHOLDS_PX,
                   pose_thresholds=POSE_AUC_THRESHOLDS_DEG):
    """The model's accuracy over pairs, per group of ``by`` columns.

    Parameters
    ----------
    rows : pandas.DataFrame
        Evaluation rows; those with model ``none`` or an ``error`` are left out.
    by : sequence of str
    thresholds : sequence of float
        Of the AUC of the corner error, in pixels.
    pose_thresholds : sequence of float
        Of the AUC of the pose error, in degrees.

    Returns
    -------
    pandas.DataFrame
        Indexed by ``by``: ``pairs``, ``auc_<t>px_pct`` (planar), ``epi_share_*_pct`` (other kinds),
        ``auc_<t>deg_pct`` (calibrated), ``no_model``, mean and median :func:`time_to_geometry`; in %.
    """
    import pandas as pd

    by = list(by)
    ok = rows[(rows["model"] != "none") & (rows["error"] == "")].copy()
    ok["_t"] = time_to_geometry(rows).loc[ok.index]
    share_cols = [c for c in ok.columns if c.startswith("epi_share_")]
    out = []
    for key, g in ok.groupby(by, sort=False):
        rec = dict(zip(by, key if isinstance(key, tuple) else (key,)))
        planar = g["corner_error"].notna()
        rec["pairs"] = len(g)
        aucs = pose_auc(g.loc[planar, "corner_error"].to_numpy(), thresholds) if planar.any() else \
            np.full(len(thresholds), np.nan)
        rec.update({f"auc_{t:g}px_pct": 100 * a for t, a in zip(thresholds, aucs)})
        rec.update({f"{c}_pct": 100 * g.loc[~planar, c].mean() for c in share_cols})
        posed = g["pose_err"].notna() if "pose_err" in g.columns else pd.Series(False, index=g.index)
        aucs = pose_auc(g.loc[posed, "pose_err"].to_numpy(), pose_thresholds) if posed.any() else \
            np.full(len(pose_thresholds), np.nan)
        rec.update({f"auc_{t:g}deg_pct": 100 * a for t, a in zip(pose_thresholds, aucs)})
        rec["no_model"] = int((g["model_inliers"] == 0).sum())
        rec["geometry_time_s"] = g["_t"].mean()
        rec["geometry_time_median_s"] = g["_t"].median()
        out.append(rec)
    cols = [*by, "pairs", *(f"auc_{t:g}px_pct" for t in thresholds), *(f"{c}_pct" for c in share_cols),
            *(f"auc_{t:g}deg_pct" for t in pose_thresholds), "no_model",
            "geometry_time_s", "geometry_time_median_s"]
    return pd.DataFrame(out, columns=cols).set_index(by)
