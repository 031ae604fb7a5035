"""Relative camera pose from two calibrated views, and its error against the ground truth.

The pose accuracy of a calibrated pair (issue 44, item 3), as the field reports it after a robust estimator
(SuperGlue, LoFTR, glue-factory, fb82/MiHo):

* an essential matrix ``E`` -- fitted on points normalised by the intrinsics (the ``essential`` model step,
  :func:`~ctxmatch_lib.geometry.apply_model_step`), or ``E = K2^T F K1`` from a fundamental matrix fitted on
  pixels (:func:`essential_from_fundamental`) -- is decomposed into its four ``(R, t)`` candidates and the one
  with the most points in front of both cameras is kept (:func:`recover_relative_pose`,
  :func:`pose_from_model`);
* the **rotation error** is the angle of ``R_est^T R_gt``, the **translation error** the angle between the
  two translation directions, folded to ``min(e, 180 - e)`` because an essential matrix fixes ``t`` only up
  to sign, and the **pose error** is the larger of the two (:func:`relative_pose_error`, :func:`pose_error`;
  SuperGlue's ``compute_pose_error``, ``models/utils.py`` of magicleap/SuperGluePretrainedNetwork). A pair
  without an estimate has both errors at :data:`POSE_FAILURE_DEG` (180 degrees), so it stays in the
  denominator of :func:`~ctxmatch_lib.geometry_metrics.pose_auc` below every threshold, as SuperGlue's
  ``inf`` does.

The relative pose follows SuperGlue's ``T_0to1``: a point ``X1`` in camera-1 coordinates is
``X2 = R @ X1 + t`` in camera-2 coordinates, pixels are ``x ~ K @ X``; ``E = [t]x R`` satisfies
``x2n^T E x1n = 0`` on normalised points and ``F = K2^-T E K1^-1`` satisfies ``x2^T F x1 = 0`` on pixels.
Keypoints are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel, and the
intrinsics ``K`` must use the same convention (principal point measured from that centre).
"""

from __future__ import annotations

import numpy as np

from .._numerics.validation import as_intrinsics, as_matrix3, as_points, as_vector3

__all__ = [
    "POSE_FAILURE_DEG",
    "POSE_MIN_POINTS",
    "check_intrinsics",
    "normalise_by_intrinsics",
    "essential_from_fundamental",
    "fundamental_from_essential",
    "recover_relative_pose",
    "pose_from_model",
    "relative_pose_error",
    "pose_error",
]

#: The rotation and translation errors, in degrees, of a pair without an estimated pose. Any threshold of the
#: pose AUC (5, 10, 20 degrees) counts it as a failure, as SuperGlue's ``inf`` does, while the rows stay finite.
POSE_FAILURE_DEG = 180.0

#: Fewest correspondences from which a pose is recovered: the five-point solver's minimal sample. Below it the
#: essential matrix is not determined and the chirality vote of :func:`recover_relative_pose` would rest on at
#: most four points.
POSE_MIN_POINTS = 5

# OpenCV's recoverPose counts a triangulated point as in front only when its depth is under distanceThresh
# (in units of the baseline, |t| = 1); its default of 50 drops the far points of narrow baselines from the
# vote. SuperGlue passes 1e9 to disable the cut and so do we.
_DISTANCE_THRESH = 1e9


def check_intrinsics(K, name: str = "K") -> np.ndarray:
    """``K`` as a float64 ``(3, 3)`` intrinsic matrix, divided by ``K[2, 2]``.

    Parameters
    ----------
    K : array_like of shape (3, 3)
        Upper-triangular intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in the package's pixel
        convention (origin at the centre of the top-left pixel).
    name : str
        Named in the error messages (``"K1"``, ``"K2"``).

    Returns
    -------
    ndarray of shape (3, 3)

    Raises
    ------
    ValueError
        ``K`` is missing, of the wrong shape, not finite, not upper triangular or has a zero focal; the
        message names ``name``.

    Examples
    --------
    >>> check_intrinsics([[500, 0, 320], [0, 500, 240], [0, 0, 1]], "K1")[0].tolist()
    [500.0, 0.0, 320.0]
    """
    return as_intrinsics(K, name)


def normalise_by_intrinsics(pts, K) -> np.ndarray:
    """Pixels to normalised camera coordinates: ``K^-1 [x, y, 1]^T``, dehomogenised.

    Parameters
    ----------
    pts : array_like of shape (N, 2)
        (x, y) pixels, origin at the centre of the top-left pixel.
    K : array_like of shape (3, 3)
        Intrinsics in the same convention (:func:`check_intrinsics`); a skew term is honoured.

    Returns
    -------
    ndarray of shape (N, 2)
        ``((x - cx - s (y - cy) / fy) / fx, (y - cy) / fy)``.

    Examples
    --------
    >>> normalise_by_intrinsics([[820.0, 240.0]], [[500, 0, 320], [0, 500, 240], [0, 0, 1]]).tolist()
    [[1.0, 0.0]]
    """
    return _normalise_by_intrinsics(as_points(pts, "pts"), check_intrinsics(K, "K"))


def _normalise_by_intrinsics(pts: np.ndarray, K: np.ndarray) -> np.ndarray:
    y = (pts[:, 1] - K[1, 2]) / K[1, 1]
    x = (pts[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.ascontiguousarray(np.c_[x, y])


def essential_from_fundamental(F, K1, K2) -> np.ndarray:
    """The essential matrix ``E = K2^T F K1`` of a fundamental matrix fitted on pixels.

    Parameters
    ----------
    F : array_like of shape (3, 3)
        ``x2^T F x1 = 0`` on (x, y) pixels, origin at the centre of the top-left pixel.
    K1, K2 : array_like of shape (3, 3)
        Intrinsics of images 1 and 2 in the same convention.

    Returns
    -------
    ndarray of shape (3, 3)
        ``x2n^T E x1n = 0`` on points normalised by :func:`normalise_by_intrinsics`; its scale is ``F``'s
        (an essential matrix is defined up to scale, and :func:`recover_relative_pose` ignores it).

    References
    ----------
    Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., Eq. (9.12).
    """
    F = as_matrix3(F, "F")
    return check_intrinsics(K2, "K2").T @ F @ check_intrinsics(K1, "K1")


def fundamental_from_essential(E, K1, K2) -> np.ndarray:
    """The fundamental matrix ``F = K2^-T E K1^-1`` on pixels, scaled to unit Frobenius norm.

    The inverse of :func:`essential_from_fundamental` up to scale; the model errors of an ``E`` fit are the
    epipolar distances, in pixels, to this ``F``.

    Parameters
    ----------
    E : array_like of shape (3, 3)
        ``x2n^T E x1n = 0`` on normalised camera coordinates.
    K1, K2 : array_like of shape (3, 3)
        Intrinsics of images 1 and 2 ((x, y) pixels, origin at the centre of the top-left pixel).

    Returns
    -------
    ndarray of shape (3, 3)
        Unit Frobenius norm (all zeros when ``E`` is).
    """
    return _fundamental_from_essential(as_matrix3(E, "E"), check_intrinsics(K1, "K1"),
                                       check_intrinsics(K2, "K2"))


def _fundamental_from_essential(E: np.ndarray, K1: np.ndarray, K2: np.ndarray) -> np.ndarray:
    F = np.linalg.solve(K2.T, E) @ np.linalg.inv(K1)
    n = np.linalg.norm(F)
    return F / n if n > 0 else F


def recover_relative_pose(E, pts1, pts2, K1, K2) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The pose among the four decompositions of ``E`` with the most points in front of both cameras.

    The points are normalised by their intrinsics and handed to ``cv2.recoverPose`` with the identity camera
    matrix, which decomposes ``E`` (``cv2.decomposeEssentialMat``: ``R1``, ``R2`` and ``+-t``), triangulates
    every correspondence under each candidate and keeps the candidate with the most points of positive depth
    in both cameras (ties: the first of ``(R1, t)``, ``(R2, t)``, ``(R1, -t)``, ``(R2, -t)``). Points at any
    distance vote: OpenCV's default ``distanceThresh`` of 50 baselines would drop the far points of narrow
    baselines, so ``1e9`` is passed, as SuperGlue's ``estimate_pose`` means to. (On OpenCV 5 its positional
    ``recoverPose(E, p1, p2, I, 1e9, mask=mask)`` resolves to the overload without ``distanceThresh`` and keeps
    the cut at 50; the keyword here does not.)

    Parameters
    ----------
    E : array_like of shape (3, 3)
        Essential matrix on normalised coordinates (``x2n^T E x1n = 0``), any scale.
    pts1, pts2 : array_like of shape (N, 2)
        Corresponding (x, y) pixels, origin at the centre of the top-left pixel: the inliers of the model
        ``E`` comes from.
    K1, K2 : array_like of shape (3, 3)
        Intrinsics of images 1 and 2 in the same convention.

    Returns
    -------
    (R, t, n_in_front) or None
        ``R`` ndarray of shape (3, 3), ``t`` ndarray of shape (3,) with unit norm (``X2 = R X1 + t``, scale
        unknown), ``n_in_front`` the number of points in front of both cameras under it. ``None`` for fewer
        than :data:`POSE_MIN_POINTS` correspondences, an ``E`` of rank below 2 (no unique decomposition) or
        no point in front under any candidate.

    References
    ----------
    Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., Sec. 9.6.2 (Result 9.19, the four solutions);
    Nistér, "An efficient solution to the five-point relative pose problem", TPAMI 2004, Sec. 3.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform([-1, -1, 4], [1, 1, 8], (20, 3))
    >>> K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    >>> t = np.array([1.0, 0.0, 0.0])
    >>> E = np.array([[0, 0, 0], [0, 0, -1.0], [0, 1, 0]])  # [t]x R with R = I
    >>> x1 = X @ K.T; x2 = (X + t) @ K.T
    >>> R, t_est, n = recover_relative_pose(E, x1[:, :2] / x1[:, 2:], x2[:, :2] / x2[:, 2:], K, K)
    >>> np.allclose(R, np.eye(3)), np.allclose(t_est, t), n
    (True, True, 20)
    """
    E = as_matrix3(E, "E")
    pts1 = as_points(pts1, "pts1")
    pts2 = as_points(pts2, "pts2", n=len(pts1))
    K1 = check_intrinsics(K1, "K1")
    K2 = check_intrinsics(K2, "K2")
    return _recover_relative_pose(E, _normalise_by_intrinsics(pts1, K1), _normalise_by_intrinsics(pts2, K2))


def _recover_relative_pose(E: np.ndarray, n1: np.ndarray, n2: np.ndarray):
    import cv2

    if len(n1) < POSE_MIN_POINTS:
        return None
    s = np.linalg.svd(E, compute_uv=False)
    if s[0] == 0 or s[1] <= 1e-9 * s[0]:
        return None
    try:
        n, R, t, _, _ = cv2.recoverPose(E, n1, n2, np.eye(3), distanceThresh=_DISTANCE_THRESH)
    except cv2.error:
        return None
    if n <= 0:
        return None
    return np.asarray(R, np.float64), np.asarray(t, np.float64).reshape(3), int(n)


def pose_from_model(model, kind: str, pts1, pts2, K1, K2) -> tuple[np.ndarray, np.ndarray] | None:
    """The relative pose of a fitted two-view model: MiHo's ``AUC^F`` (kind ``"F"``) and ``AUC^E`` (``"E"``)
    routes.

    ``"F"``: ``E = K2^T F K1`` (:func:`essential_from_fundamental`), then :func:`recover_relative_pose`;
    ``"E"``: :func:`recover_relative_pose` directly.

    Parameters
    ----------
    model : array_like of shape (3, 3) or None
        A model step's ``ModelFit.model``; ``None`` (no model) gives ``None``.
    kind : {"F", "E"}
        ``ModelFit.kind``.
    pts1, pts2 : array_like of shape (N, 2)
        The model's inlier correspondences, (x, y) pixels, origin at the centre of the top-left pixel.
    K1, K2 : array_like of shape (3, 3)
        Intrinsics of images 1 and 2 in the same convention.

    Returns
    -------
    (R, t) or None
        ``R`` of shape (3, 3), ``t`` of shape (3,), unit norm; ``None`` when there is no model or
        :func:`recover_relative_pose` finds no pose.

    Raises
    ------
    ValueError
        ``kind`` is not ``"F"`` or ``"E"``, or an argument is malformed (the message names it).
    """
    if kind not in ("F", "E"):
        raise ValueError(f"kind must be 'F' or 'E' (a homography has no unique relative pose), got {kind!r}")
    if model is None:
        return None
    E = essential_from_fundamental(model, K1, K2) if kind == "F" else as_matrix3(model, "model")
    pose = recover_relative_pose(E, pts1, pts2, K1, K2)
    return None if pose is None else pose[:2]


def _rotation_angle_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    # SuperGlue's formula, kept so that the errors (and the AUC) are the field's to the last digit. Its arccos
    # of the trace is sensitive to a ground truth that is a rotation only to its printed digits: Strecha's R,
    # orthonormal to ~1e-6, moves a 0.05 degree error by up to 0.03 degree (an atan2 of the sine and cosine
    # would not), far below the 5 degree step of the AUC.
    cos = np.clip((np.trace(R_est.T @ R_gt) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)))


def _direction_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = np.clip(float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)))


def relative_pose_error(R_est, t_est, R_gt, t_gt) -> tuple[float, float]:
    """Rotation and translation-direction errors of an estimated relative pose, in degrees.

    SuperGlue's ``compute_pose_error``: the rotation error is the angle of ``R_est^T R_gt``; the translation
    error is the angle ``e`` between ``t_est`` and ``t_gt``, reported as ``min(e, 180 - e)`` since an essential
    matrix fixes ``t`` only up to sign (so it lies in [0, 90]). Both angles are SuperGlue's arccos of the
    clipped cosine (``(trace(R_est^T R_gt) - 1) / 2`` and the normalised dot product), so the errors equal its
    own on the same inputs; a ground-truth ``R`` that is orthonormal only to a few digits biases the smallest
    rotation errors by about the square root of that residual (radians).

    Parameters
    ----------
    R_est : array_like of shape (3, 3) or None
        Estimated rotation (``X2 = R X1 + t``); ``None`` when there is no estimate.
    t_est : array_like of shape (3,) or None
        Estimated translation, any scale; ``None`` when there is no estimate.
    R_gt : array_like of shape (3, 3)
        Ground-truth rotation.
    t_gt : array_like of shape (3,)
        Ground-truth translation, non-zero.

    Returns
    -------
    err_R, err_t : float
        Degrees. Without an estimate (``None``, non-finite values) both are :data:`POSE_FAILURE_DEG`; a zero
        ``t_est`` has no direction, and its ``err_t`` is :data:`POSE_FAILURE_DEG`.

    Raises
    ------
    ValueError
        ``R_gt`` or ``t_gt`` malformed, or ``t_gt`` zero (a pure rotation has no translation direction).

    References
    ----------
    Sarlin et al., "SuperGlue: Learning feature matching with graph neural networks", CVPR 2020, Sec. 5.2
    (``compute_pose_error`` in ``models/utils.py`` of magicleap/SuperGluePretrainedNetwork).

    Examples
    --------
    >>> import numpy as np
    >>> c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
    >>> Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    >>> [round(e, 9) for e in relative_pose_error(Rz, [-2.0, 0, 0], np.eye(3), [1.0, 0, 0])]
    [10.0, 0.0]
    """
    R_gt = as_matrix3(R_gt, "R_gt")
    t_gt = as_vector3(t_gt, "t_gt")
    if not np.any(t_gt):
        raise ValueError("t_gt is zero: a pure rotation has no translation direction")
    if R_est is None or t_est is None:
        return POSE_FAILURE_DEG, POSE_FAILURE_DEG
    R_est = np.asarray(R_est, np.float64)
    t_est = np.asarray(t_est, np.float64)
    if R_est.shape != (3, 3):
        raise ValueError(f"R_est must have shape (3, 3), got {R_est.shape}")
    if t_est.shape not in ((3,), (3, 1)):
        raise ValueError(f"t_est must have shape (3,), got {t_est.shape}")
    t_est = t_est.reshape(3)
    if not (np.isfinite(R_est).all() and np.isfinite(t_est).all()):
        return POSE_FAILURE_DEG, POSE_FAILURE_DEG
    err_R = _rotation_angle_deg(R_est, R_gt)
    if not np.any(t_est):
        return err_R, POSE_FAILURE_DEG
    e = _direction_angle_deg(t_est, t_gt)
    return err_R, min(e, 180.0 - e)


def pose_error(R_est, t_est, R_gt, t_gt) -> float:
    """The pose error of SuperGlue's and MiHo's AUC: the larger of :func:`relative_pose_error`'s two angles,
    in degrees (:data:`POSE_FAILURE_DEG` without an estimate).

    Examples
    --------
    >>> pose_error(None, None, [[1, 0, 0], [0, 1, 0], [0, 0, 1]], [0, 0, 1])
    180.0
    """
    return max(relative_pose_error(R_est, t_est, R_gt, t_gt))
