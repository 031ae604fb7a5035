"""PoseLib's LO-RANSAC as the second estimator, beside OpenCV's USAC: the ``poselib`` step fits ``H`` (planar
pairs) or ``F`` (the others), ``poselib_essential`` the relative pose of a calibrated pair (``E`` by the
five-point solver on the intrinsics' cameras). PoseLib (V. Larsson and contributors, pinned at 2.0.5) is the
estimator of glue-factory's pose evaluation and of fb82/MiHo's RANSAC ablation.

Settings: the noise bound in pixels, the success probability and the iteration cap of
:data:`~ctxmatch_lib.geometry.usac.USAC_PRESETS` (``threshold``, ``confidence``, ``max_iters``; the same as
MAGSAC's, 1 px, 0.9999, 100 000, so that the estimator is the only difference); PoseLib's own defaults for
the rest (1000 iterations at least, its non-linear refinement with a Cauchy loss). For ``H`` the bound is
PoseLib's ``max_reproj_error``, for ``F`` and ``E`` its ``max_epipolar_error`` (fb82/MiHo's module passes
the latter to ``estimate_homography`` too, which ignores it and keeps its default of 12 px). The seed of
each call comes from ``rng``; PoseLib runs on one thread.
"""

from __future__ import annotations

import numpy as np

from .models import MIN_SAMPLE, ModelFit, _failed, _model_errors, _too_few_distinct
from .pose import _fundamental_from_essential

__all__ = ["POSELIB_STEPS", "poselib_fit"]

#: The model steps run by PoseLib.
POSELIB_STEPS = ("poselib", "poselib_essential")


def poselib_fit(step: str, kpts1: np.ndarray, kpts2: np.ndarray, matches: np.ndarray, *, kind: str,
                threshold: float, settings, rng, K1=None, K2=None) -> ModelFit:
    """Fit the model of ``step`` (:data:`POSELIB_STEPS`) with PoseLib on validated inputs.

    Parameters
    ----------
    step : {"poselib", "poselib_essential"}
        ``H`` or ``F`` by ``kind``, or ``E`` with the intrinsics ``K1``, ``K2``.
    kpts1, kpts2, matches
        Validated keypoints and (K, 2) matches (:func:`~ctxmatch_lib.geometry.apply_model_step` checks them).
    kind : {"H", "F"}
        The model of the ``poselib`` step.
    threshold : float
        The consistency threshold in pixels that decides :attr:`ModelFit.keep` (as for every step).
    settings : UsacSettings
        PoseLib's noise bound (``threshold``, pixels), success probability and iteration cap.
    rng : None, int or numpy.random.Generator
        Seeds PoseLib's sampler.

    Returns
    -------
    ModelFit
        ``sample`` holds PoseLib's inliers; a failed fit has no model.
    """
    import poselib

    kind = "E" if step == "poselib_essential" else kind
    k = len(matches)
    if k == 0 or _too_few_distinct(matches, MIN_SAMPLE[kind]):
        return _failed(k, kind)
    p1 = np.ascontiguousarray(kpts1[matches[:, 0]], np.float64)
    p2 = np.ascontiguousarray(kpts2[matches[:, 1]], np.float64)
    opt = {"max_iterations": settings.max_iters, "min_iterations": min(1000, settings.max_iters),
           "success_prob": settings.confidence, "seed": int(np.random.default_rng(rng).integers(0, 2**31 - 1))}
    if kind == "H":
        model, info = poselib.estimate_homography(p1, p2, {**opt, "max_reproj_error": settings.threshold}, {})
    elif kind == "F":
        model, info = poselib.estimate_fundamental(p1, p2, {**opt, "max_epipolar_error": settings.threshold}, {})
    else:
        cam1, cam2 = ({"model": "PINHOLE", "width": 0, "height": 0, "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]}
                      for K in (K1, K2))
        pose, info = poselib.estimate_relative_pose(p1, p2, cam1, cam2,
                                                    {**opt, "max_epipolar_error": settings.threshold}, {})
        tx = np.array([[0.0, -pose.t[2], pose.t[1]], [pose.t[2], 0.0, -pose.t[0]], [-pose.t[1], pose.t[0], 0.0]])
        model = tx @ pose.R
    model = np.asarray(model, np.float64)
    inliers = np.flatnonzero(np.asarray(info.get("inliers", []), bool))
    if model.shape != (3, 3) or not np.isfinite(model).all() or not np.any(model) or len(inliers) == 0:
        return _failed(k, kind)
    err = _model_errors(_fundamental_from_essential(model, K1, K2) if kind == "E" else model,
                        "H" if kind == "H" else "F", p1, p2)
    return ModelFit(err <= threshold, model, kind, inliers.astype(np.int64), err)
