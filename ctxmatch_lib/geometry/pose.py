"""Relative camera pose of a calibrated pair (:func:`pose_from_model`) and its error, as SuperGlue reports it.

SuperGlue's ``T_0to1``: ``X2 = R @ X1 + t``, pixels ``x ~ K @ X``, ``E = [t]x R`` with ``x2n^T E x1n = 0``;
``K``'s principal point is measured from the centre of the top-left pixel, like the keypoints.
"""

from __future__ import annotations

import numpy as np

from .._numerics.fixedmath import acos
from .._numerics.validation import as_intrinsics, as_matrix3, as_points, as_vector3

__all__ = [
    "POSE_FAILURE_DEG", "POSE_MIN_POINTS", "check_intrinsics", "normalise_by_intrinsics", "essential_from_fundamental",
    "fundamental_from_essential", "recover_relative_pose", "pose_from_model", "relative_pose_error", "pose_error",
]

#: Rotation and translation errors (degrees) of a pair without a pose: a failure at every AUC threshold, as
#: SuperGlue's ``inf``, while the rows stay finite.
POSE_FAILURE_DEG = 180.0

#: Fewest correspondences a pose is recovered from: the five-point solver's minimal sample.
POSE_MIN_POINTS = 5

# recoverPose's depth cut, in baselines: its default of 50 drops the far points of narrow baselines from the
# vote; SuperGlue disables it with 1e9.
_DISTANCE_THRESH = 1e9


def check_intrinsics(K, name: str = "K") -> np.ndarray:
    """``K`` (``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``) as float64 (3, 3) divided by ``K[2, 2]``; a malformed
    one (missing, not finite, not upper triangular, zero focal) raises a ``ValueError`` naming ``name``."""
    return as_intrinsics(K, name)


def normalise_by_intrinsics(pts, K) -> np.ndarray:
    """``(N, 2)`` pixels to normalised camera coordinates, ``K^-1 [x, y, 1]^T`` dehomogenised (skew honoured).

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
    """The essential matrix ``E = K2^T F K1`` (Hartley & Zisserman, 2nd ed., Eq. 9.12), ``F``'s scale."""
    F = as_matrix3(F, "F")
    return check_intrinsics(K2, "K2").T @ F @ check_intrinsics(K1, "K1")


def fundamental_from_essential(E, K1, K2) -> np.ndarray:
    """The fundamental matrix ``F = K2^-T E K1^-1``, unit Frobenius norm (zero for a zero ``E``): the
    inverse of :func:`essential_from_fundamental` up to scale, which an ``E`` fit's errors are measured by."""
    return _fundamental_from_essential(as_matrix3(E, "E"), check_intrinsics(K1, "K1"),
                                       check_intrinsics(K2, "K2"))


def _fundamental_from_essential(E: np.ndarray, K1: np.ndarray, K2: np.ndarray) -> np.ndarray:
    F = np.linalg.solve(K2.T, E) @ np.linalg.inv(K1)
    n = np.linalg.norm(F)
    return F / n if n > 0 else F


def recover_relative_pose(E, pts1, pts2, K1, K2) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The pose among the four decompositions of ``E`` with the most points in front of both cameras.

    ``cv2.recoverPose`` on the inliers ``pts1``, ``pts2`` (pixels; Hartley & Zisserman, Result 9.19), the first
    candidate on ties. Returns ``(R, t, n_in_front)`` with ``|t| = 1``, or ``None`` below
    :data:`POSE_MIN_POINTS` points, for an ``E`` of rank below 2 or with no point in front.

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
        # By keyword: a positional 1e9 (SuperGlue's call) picks, on OpenCV 5, the overload without it.
        n, R, t, _, _ = cv2.recoverPose(E, n1, n2, np.eye(3), distanceThresh=_DISTANCE_THRESH)
    except cv2.error:
        return None
    if n <= 0:
        return None
    return np.asarray(R, np.float64), np.asarray(t, np.float64).reshape(3), int(n)


def pose_from_model(model, kind: str, pts1, pts2, K1, K2) -> tuple[np.ndarray, np.ndarray] | None:
    """The relative pose ``(R, t)`` of a model step's ``F`` or ``E`` on its inliers, or ``None``.

    MiHo's ``AUC^F`` route (``E = K2^T F K1``) or ``AUC^E`` route, then :func:`recover_relative_pose`."""
    if kind not in ("F", "E"):
        raise ValueError(f"kind must be 'F' or 'E' (a homography has no unique relative pose), got {kind!r}")
    if model is None:
        return None
    E = essential_from_fundamental(model, K1, K2) if kind == "F" else as_matrix3(model, "model")
    pose = recover_relative_pose(E, pts1, pts2, K1, K2)
    return None if pose is None else pose[:2]


def _angle_deg(cos) -> float:
    # SuperGlue's arccos (of the trace for R), so the errors are the field's (an atan2 would be less sensitive
    # to a ground truth that is a rotation only to its printed digits); fixedmath's, the same bits on any CPU.
    return float(np.degrees(acos(np.clip(cos, -1.0, 1.0))))


def relative_pose_error(R_est, t_est, R_gt, t_gt) -> tuple[float, float]:
    """Rotation and translation-direction errors of an estimated relative pose, in degrees.

    SuperGlue's ``compute_pose_error`` (Sarlin et al., CVPR 2020): the angle of ``R_est^T R_gt`` and
    ``min(e, 180 - e)``, ``e`` the angle between the ``t``'s (``E`` fixes ``t`` up to sign).
    :data:`POSE_FAILURE_DEG` without an estimate (and for ``err_t`` of a zero ``t_est``).

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
    err_R = _angle_deg((np.trace(R_est.T @ R_gt) - 1.0) / 2.0)
    if not np.any(t_est):
        return err_R, POSE_FAILURE_DEG
    e = _angle_deg(float(t_est @ t_gt) / (np.linalg.norm(t_est) * np.linalg.norm(t_gt)))
    return err_R, min(e, 180.0 - e)


def pose_error(R_est, t_est, R_gt, t_gt) -> float:
    """The pose error of SuperGlue's and MiHo's AUC: the larger of :func:`relative_pose_error`'s angles.

    Examples
    --------
    >>> pose_error(None, None, [[1, 0, 0], [0, 1, 0], [0, 0, 1]], [0, 0, 1])
    180.0
    """
    return max(relative_pose_error(R_est, t_est, R_gt, t_gt))
