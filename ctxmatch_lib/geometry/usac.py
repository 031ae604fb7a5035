"""Seeded robust model fitting with OpenCV's USAC, and the model steps of the evaluation.

:func:`ransac` fits ``H`` or ``F`` with OpenCV's USAC (MAGSAC++ scoring, sigma-consensus local optimisation,
uniform or PROSAC sampling), seeded so that reruns are identical. :data:`USAC_PRESETS` names the settings the
model steps use: ``ransac`` and ``prosac`` (3 px, confidence 0.999: the project's model step since issue 11)
and ``magsac``, the settings of fb82/MiHo's benchmark (``cv2.USAC_MAGSAC``, 1 px, confidence 0.9999, 100 000
iterations: ``magsac_module(px_th=1.00)`` in MiHo's ``save_bench.py`` / ``src/base_modules.py``), fixed from
that source and not tuned on the evaluation pairs. The ``essential`` step fits an essential matrix ``E`` with
the same estimator and settings on points normalised by the intrinsics (calibrated pairs; fb82/MiHo's AUC^E).
:func:`apply_model_step` runs any step by name.

Keypoints are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from .._numerics.validation import as_matches
from .models import (CONSISTENCY_THRESHOLD_PX, MIN_SAMPLE, ModelFit, ModelKind, _check_kind, _check_step, _failed,
                     _model_errors, _one_sac)
from .pose import _fundamental_from_essential, _normalise_by_intrinsics, check_intrinsics

__all__ = ["MODEL_STEPS", "ROBUST_STEPS", "UsacSettings", "USAC_PRESETS", "usac_settings", "ransac",
           "model_kind_for", "apply_model_step"]

#: Names accepted by :func:`apply_model_step`: ``none`` keeps the filter output as it is, ``1sac`` is the
#: paper's, ``ransac`` OpenCV's USAC_MAGSAC (uniform sampling, 3 px), ``prosac`` the same with PROSAC
#: sampling by the match ranking, ``magsac`` USAC_MAGSAC with fb82/MiHo's settings (1 px, 0.9999, 100 000),
#: ``essential`` the same estimator fitting ``E`` on points normalised by the intrinsics (calibrated pairs only).
MODEL_STEPS = ("none", "1sac", "ransac", "prosac", "magsac", "essential")

#: The model steps run by OpenCV's USAC (:data:`USAC_PRESETS`); their threshold, confidence and iteration cap
#: can be overridden (:func:`usac_settings`).
ROBUST_STEPS = ("ransac", "prosac", "magsac", "essential")


@dataclass(frozen=True)
class UsacSettings:
    """Settings of one USAC estimator; the defaults are the ``ransac`` model step's, and :func:`ransac`'s.

    Attributes
    ----------
    sampler : {"uniform", "prosac"}
        Uniform sampling (OpenCV's ``USAC_MAGSAC`` preset) or PROSAC by the match ranking.
    threshold : float
        USAC's noise bound in pixels (``ransacReprojThreshold``).
    confidence : float
        RANSAC confidence in (0, 1).
    max_iters : int
        Iteration cap.
    """

    sampler: str = "uniform"
    threshold: float = 3.0
    confidence: float = 0.999
    max_iters: int = 100_000


#: The USAC settings of each robust model step. ``magsac`` is fb82/MiHo's (see the module docstring); with
#: ``randomGeneratorState`` 0 it returns the same model as ``cv2.findHomography(p1, p2, cv2.USAC_MAGSAC, 1.0,
#: 0.9999, 100000)`` (checked on OpenCV 5.0.0).
USAC_PRESETS = {
    "ransac": UsacSettings(),
    "prosac": UsacSettings(sampler="prosac"),
    "magsac": UsacSettings(threshold=1.0, confidence=0.9999),
    # The threshold stays in pixels; the essential step divides it by the mean focal length.
    "essential": UsacSettings(threshold=1.0, confidence=0.9999),
}


def usac_settings(name: str, overrides: Mapping | None = None) -> UsacSettings:
    """The settings of the robust step ``name`` with ``overrides`` (``threshold``, ``confidence``,
    ``max_iters``) applied; raises ``ValueError`` naming a bad key or value.

    Examples
    --------
    >>> usac_settings("magsac", {"threshold": 0.5})
    UsacSettings(sampler='uniform', threshold=0.5, confidence=0.9999, max_iters=100000)
    """
    if name not in USAC_PRESETS:
        raise ValueError(f"{name!r} is not a USAC model step; USAC steps: {', '.join(USAC_PRESETS)}")
    overrides = dict(overrides or {})
    unknown = sorted(set(overrides) - {"threshold", "confidence", "max_iters"})
    if unknown:
        raise ValueError(f"estimator settings must be among threshold, confidence, max_iters, got {unknown}")
    s = replace(USAC_PRESETS[name], **overrides)
    if isinstance(s.threshold, bool) or not (isinstance(s.threshold, (int, float, np.number))
                                             and math.isfinite(s.threshold) and s.threshold > 0):
        raise ValueError(f"estimator threshold must be a positive number of pixels, got {s.threshold!r}")
    if isinstance(s.confidence, bool) or not (isinstance(s.confidence, (int, float, np.number))
                                              and 0 < s.confidence < 1):
        raise ValueError(f"estimator confidence must lie in (0, 1), got {s.confidence!r}")
    if isinstance(s.max_iters, bool) or not isinstance(s.max_iters, (int, np.integer)) or s.max_iters < 1:
        raise ValueError(f"estimator max_iters must be a positive integer, got {s.max_iters!r}")
    return replace(s, threshold=float(s.threshold), confidence=float(s.confidence), max_iters=int(s.max_iters))


def ransac(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    kind: ModelKind = "H",
    threshold: float = CONSISTENCY_THRESHOLD_PX,
    magsac_threshold: float = UsacSettings.threshold,
    confidence: float = UsacSettings.confidence,
    max_iters: int = UsacSettings.max_iters,
    sampler: str = UsacSettings.sampler,
    rng=None,
) -> ModelFit:
    """Seeded robust model fitting with OpenCV's USAC (MAGSAC++ scoring, sigma-consensus local optimisation).

    The model is estimated by USAC with ``magsac_threshold`` as its noise bound; the matches kept are then
    chosen with the same rule as :func:`one_sac` (error at most ``threshold`` pixels against the returned
    model), so that 1SAC and RANSAC differ only in how the model is estimated.

    Parameters
    ----------
    kpts1, kpts2, matches, scores, kind, threshold
        As in :func:`one_sac`; ``scores`` are used only by the PROSAC sampler.
    magsac_threshold : float
        USAC's threshold in pixels.
    confidence : float
        RANSAC confidence.
    max_iters : int
        Iteration cap. The default is high because blob candidates are many-to-many with inlier ratios
        near 10 %, where uniform 4-samples are all-inlier with probability ~1e-4; MAGSAC's adaptive
        termination stops far earlier on easy pairs.
    sampler : {"uniform", "prosac"}
        ``"uniform"`` is OpenCV's ``USAC_MAGSAC`` preset; ``"prosac"`` draws samples from the best-ranked
        matches first (by ``scores``), which copes far better with the ~10 % inlier ratios of many-to-many
        candidates, especially for ``F``.
    rng : None, int or numpy.random.Generator
        Seeds USAC's own generator, so results are reproducible for a given seed.

    Returns
    -------
    ModelFit
        ``sample`` holds the inliers reported by USAC.
    """
    kind, kpts1, kpts2, matches, scores = _check_step(kind, kpts1, kpts2, matches, scores, threshold)
    if sampler not in ("uniform", "prosac"):
        raise ValueError(f"sampler must be 'uniform' or 'prosac', got {sampler!r}")
    return _ransac(kpts1, kpts2, matches, scores, kind, threshold,
                   UsacSettings(sampler, magsac_threshold, confidence, max_iters), rng)


def _usac_params(settings: UsacSettings, rng, threshold: float | None = None):
    """OpenCV's ``UsacParams`` for ``settings`` (MAGSAC++ scoring, sigma-consensus local optimisation and
    polishing, one thread), seeded from ``rng``; ``threshold`` replaces ``settings.threshold`` when given."""
    import cv2

    params = cv2.UsacParams()
    params.threshold = float(settings.threshold if threshold is None else threshold)
    params.confidence = float(settings.confidence)
    params.maxIterations = int(settings.max_iters)
    params.randomGeneratorState = int(np.random.default_rng(rng).integers(0, 2**31 - 1))
    params.sampler = cv2.SAMPLING_UNIFORM if settings.sampler == "uniform" else cv2.SAMPLING_PROSAC
    params.score = cv2.SCORE_METHOD_MAGSAC
    params.loMethod = cv2.LOCAL_OPTIM_SIGMA
    params.final_polisher = cv2.MAGSAC
    params.isParallel = False
    return params


def _ransac(kpts1, kpts2, matches, scores, kind, threshold, settings: UsacSettings, rng) -> ModelFit:
    import cv2

    k = len(matches)
    q = MIN_SAMPLE[kind]
    if k == 0 or min(len(np.unique(matches[:, 0])), len(np.unique(matches[:, 1]))) < q:
        return _failed(k, kind)
    params = _usac_params(settings, rng)
    # PROSAC expects the correspondences best first; uniform sampling does not care about the order.
    order = np.argsort(scores, kind="stable")
    p1 = np.ascontiguousarray(kpts1[matches[order, 0]], np.float64)
    p2 = np.ascontiguousarray(kpts2[matches[order, 1]], np.float64)
    try:
        if kind == "H":
            model, mask = cv2.findHomography(p1, p2, params)
        else:
            model, mask = cv2.findFundamentalMat(p1, p2, params)
    except cv2.error:
        return _failed(k, kind)
    if model is None or np.asarray(model).shape != (3, 3) or not np.isfinite(model).all():
        return _failed(k, kind)
    model = np.asarray(model, np.float64)
    inl = np.flatnonzero(np.asarray(mask).reshape(-1) > 0) if mask is not None else np.empty(0, np.int64)
    err = np.empty(k)
    err[order] = _model_errors(model, kind, p1, p2)
    return ModelFit(err <= threshold, model, kind, np.sort(order[inl]).astype(np.int64), err)


def _essential(kpts1, kpts2, matches, scores, threshold, settings: UsacSettings, rng, K1, K2) -> ModelFit:
    """The ``essential`` step: ``E`` by USAC on points normalised by ``K1`` / ``K2`` (validated by the caller).

    USAC's threshold is ``settings.threshold`` pixels over the mean focal length (SuperGlue's ``estimate_pose``
    does the same, from ``K1``'s fx and ``K2``'s fy only); the matches kept are those within ``threshold``
    pixels of the epipolar lines of ``F = K2^-T E K1^-1``, the rule of :func:`ransac`.
    """
    import cv2

    k = len(matches)
    if k == 0 or min(len(np.unique(matches[:, 0])), len(np.unique(matches[:, 1]))) < MIN_SAMPLE["E"]:
        return _failed(k, "E")
    focal = np.mean([K1[0, 0], K1[1, 1], K2[0, 0], K2[1, 1]])
    params = _usac_params(settings, rng, threshold=settings.threshold / abs(focal))
    order = np.argsort(scores, kind="stable")  # best first, for PROSAC
    p1 = np.ascontiguousarray(kpts1[matches[order, 0]])
    p2 = np.ascontiguousarray(kpts2[matches[order, 1]])
    n1, n2 = _normalise_by_intrinsics(p1, K1), _normalise_by_intrinsics(p2, K2)
    eye, no_distortion = np.eye(3), np.zeros(5)
    try:
        model, mask = cv2.findEssentialMat(n1, n2, eye, eye, no_distortion, no_distortion, params)
    except cv2.error:
        return _failed(k, "E")
    if model is None or np.asarray(model).shape != (3, 3) or not np.isfinite(model).all():
        return _failed(k, "E")
    model = np.asarray(model, np.float64)
    inl = np.flatnonzero(np.asarray(mask).reshape(-1) > 0) if mask is not None else np.empty(0, np.int64)
    err = np.empty(k)
    err[order] = _model_errors(_fundamental_from_essential(model, K1, K2), "F", p1, p2)
    return ModelFit(err <= threshold, model, "E", np.sort(order[inl]).astype(np.int64), err)


def model_kind_for(pair_kind: str) -> ModelKind:
    """``"H"`` for planar pairs, ``"F"`` for non-planar, depth and calibrated pairs."""
    if pair_kind == "planar":
        return "H"
    if pair_kind in ("nonplanar", "depth", "calibrated"):
        return "F"
    raise ValueError(f"pair kind must be 'planar', 'nonplanar', 'depth' or 'calibrated', got {pair_kind!r}")


def apply_model_step(
    name: str,
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    kind: ModelKind,
    threshold: float = CONSISTENCY_THRESHOLD_PX,
    rng=None,
    estimator: Mapping | None = None,
    K1=None,
    K2=None,
) -> ModelFit:
    """Run the model step ``name`` (one of :data:`MODEL_STEPS`) on the matches.

    ``"none"`` keeps every match (``model`` is ``None``); ``"1sac"`` calls :func:`one_sac`; ``"ransac"``,
    ``"prosac"`` and ``"magsac"`` call :func:`ransac` with ``rng`` and their :data:`USAC_PRESETS`, updated by
    ``estimator`` (``threshold``, ``confidence``, ``max_iters``; see :func:`usac_settings`), which the other
    steps ignore.

    ``"essential"`` fits an essential matrix with the same USAC estimator (``cv2.findEssentialMat``, its
    five-point solver) on the points normalised by the intrinsics ``K1`` and ``K2`` (required; any ``kind``
    is accepted, the fit is of kind ``"E"``), with USAC's threshold in pixels divided by the mean focal length
    (of fx and fy of both cameras); its errors are the epipolar distances in pixels to ``F = K2^-T E K1^-1``
    (:func:`model_errors`) and it keeps the matches within ``threshold`` of them. Its pose:
    :func:`~ctxmatch_lib.geometry.pose_from_model` on its inliers (``sample``).

    Keypoints are (x, y) pixels, origin at the centre of the top-left pixel; ``K1`` and ``K2`` must use the
    same convention.

    Raises
    ------
    ValueError
        An unknown step, a malformed argument, or for ``"essential"`` a missing ``K1`` / ``K2`` or one with
        a zero focal (the message names it).

    References
    ----------
    Nistér, "An efficient solution to the five-point relative pose problem", TPAMI 2004 (the ``E`` solver);
    Barath et al., "MAGSAC++, a fast, reliable and accurate robust estimator", CVPR 2020 (the scoring).
    """
    if name not in MODEL_STEPS:
        raise ValueError(f"unknown model step {name!r}; known: {', '.join(MODEL_STEPS)}")
    if name == "none":
        k = len(as_matches(matches))
        return ModelFit(np.ones(k, bool), None, _check_kind(kind, MIN_SAMPLE), np.arange(k, dtype=np.int64),
                        np.zeros(k))
    if name == "essential":
        _check_kind(kind, MIN_SAMPLE)
        K1, K2 = check_intrinsics(K1, "K1"), check_intrinsics(K2, "K2")
        _, kpts1, kpts2, matches, scores = _check_step("F", kpts1, kpts2, matches, scores, threshold)
        return _essential(kpts1, kpts2, matches, scores, threshold, usac_settings(name, estimator), rng, K1, K2)
    kind, kpts1, kpts2, matches, scores = _check_step(kind, kpts1, kpts2, matches, scores, threshold)
    if name == "1sac":
        return _one_sac(kpts1, kpts2, matches, scores, kind, threshold)
    return _ransac(kpts1, kpts2, matches, scores, kind, threshold, usac_settings(name, estimator), rng)
