"""Seeded robust model fitting with OpenCV's USAC (:func:`ransac`), and the model steps of the evaluation
(:func:`apply_model_step`). ``magsac`` takes fb82/MiHo's settings (``magsac_module(px_th=1.00)``), untuned;
the ``poselib`` steps run PoseLib with the same settings (:mod:`.poselib_steps`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from .._numerics.validation import as_matches
from .models import (CONSISTENCY_THRESHOLD_PX, MIN_SAMPLE, ModelFit, ModelKind, _check_kind, _check_step, _failed,
                     _model_errors, _one_sac, _too_few_distinct)
from .pose import _fundamental_from_essential, _normalise_by_intrinsics, check_intrinsics
from .poselib_steps import POSELIB_STEPS, poselib_fit

__all__ = ["MODEL_STEPS", "ROBUST_STEPS", "UsacSettings", "USAC_PRESETS", "usac_settings", "ransac",
           "model_kind_for", "apply_model_step"]

#: Names accepted by :func:`apply_model_step` (see there).
MODEL_STEPS = ("none", "1sac", "ransac", "prosac", "magsac", "essential", *POSELIB_STEPS)

#: The random model steps (USAC's and PoseLib's), with settings in :data:`USAC_PRESETS`.
ROBUST_STEPS = ("ransac", "prosac", "magsac", "essential", *POSELIB_STEPS)


@dataclass(frozen=True)
class UsacSettings:
    """Settings of one USAC estimator (defaults: the ``ransac`` step's): ``sampler`` (``"uniform"`` or
    ``"prosac"``), ``threshold`` (noise bound in pixels), ``confidence`` in (0, 1), ``max_iters``."""

    sampler: str = "uniform"
    threshold: float = 3.0
    confidence: float = 0.999
    max_iters: int = 100_000


#: The settings of each robust model step (``magsac``: fb82/MiHo's; the PoseLib steps take MAGSAC's, so that
#: the estimator is the only difference).
USAC_PRESETS = {
    "ransac": UsacSettings(),
    "prosac": UsacSettings(sampler="prosac"),
    "magsac": UsacSettings(threshold=1.0, confidence=0.9999),
    # The threshold stays in pixels; the essential step divides it by the mean focal length.
    "essential": UsacSettings(threshold=1.0, confidence=0.9999),
    "poselib": UsacSettings(threshold=1.0, confidence=0.9999),
    "poselib_essential": UsacSettings(threshold=1.0, confidence=0.9999),
}


def usac_settings(name: str, overrides: Mapping | None = None) -> UsacSettings:
    """The settings of the robust step ``name`` with ``overrides`` (``threshold``, ``confidence``,
    ``max_iters``); ``ValueError`` names a bad key or value.

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


def ransac(kpts1, kpts2, matches, scores=None, *, kind: ModelKind = "H", threshold: float = CONSISTENCY_THRESHOLD_PX,
           magsac_threshold: float = UsacSettings.threshold, confidence: float = UsacSettings.confidence,
           max_iters: int = UsacSettings.max_iters, sampler: str = UsacSettings.sampler, rng=None) -> ModelFit:
    """Seeded robust model fitting with OpenCV's USAC (MAGSAC++ scoring, sigma-consensus local optimisation).

    The :class:`ModelFit` keeps the matches within ``threshold`` pixels (:func:`one_sac`'s rule); its
    ``sample`` is USAC's inliers.

    Parameters
    ----------
    kpts1, kpts2, matches, scores, kind, threshold
        As in :func:`one_sac`; ``scores`` only rank the PROSAC samples.
    magsac_threshold, confidence, max_iters
        USAC's noise bound in pixels, confidence and iteration cap.
    sampler : {"uniform", "prosac"}
        Uniform (OpenCV's ``USAC_MAGSAC`` preset) or best-ranked first.
    rng : None, int or numpy.random.Generator
        Seeds USAC's generator.
    """
    kind, kpts1, kpts2, matches, scores = _check_step(kind, kpts1, kpts2, matches, scores, threshold)
    if sampler not in ("uniform", "prosac"):
        raise ValueError(f"sampler must be 'uniform' or 'prosac', got {sampler!r}")
    return _ransac(kpts1, kpts2, matches, scores, kind, threshold,
                   UsacSettings(sampler, magsac_threshold, confidence, max_iters), rng)


def _usac_params(settings: UsacSettings, rng, threshold: float | None = None):
    """OpenCV's ``UsacParams`` for ``settings``, one thread, seeded from ``rng``; ``threshold`` overrides."""
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


def _usac_fit(kind: str, kpts1, kpts2, matches, scores, threshold, estimate, errors) -> ModelFit:
    """A USAC model step: ``estimate(p1, p2)``, OpenCV's ``(model, mask)`` on the matched points best first
    (PROSAC expects that order; uniform sampling ignores it), then ``errors(model, p1, p2)`` of the matches."""
    import cv2

    k = len(matches)
    if _too_few_distinct(matches, MIN_SAMPLE[kind]):
        return _failed(k, kind)
    order = np.argsort(scores, kind="stable")
    p1 = np.ascontiguousarray(kpts1[matches[order, 0]], np.float64)
    p2 = np.ascontiguousarray(kpts2[matches[order, 1]], np.float64)
    try:
        model, mask = estimate(p1, p2)
    except cv2.error:
        return _failed(k, kind)
    if model is None or np.asarray(model).shape != (3, 3) or not np.isfinite(model).all():
        return _failed(k, kind)
    model = np.asarray(model, np.float64)
    inl = np.flatnonzero(np.asarray(mask).reshape(-1) > 0) if mask is not None else np.empty(0, np.int64)
    err = np.empty(k)
    err[order] = errors(model, p1, p2)
    return ModelFit(err <= threshold, model, kind, np.sort(order[inl]).astype(np.int64), err)


def _ransac(kpts1, kpts2, matches, scores, kind, threshold, settings: UsacSettings, rng) -> ModelFit:
    import cv2

    def estimate(p1, p2):
        find = cv2.findHomography if kind == "H" else cv2.findFundamentalMat
        return find(p1, p2, _usac_params(settings, rng))

    def errors(model, p1, p2):
        return _model_errors(model, kind, p1, p2)

    return _usac_fit(kind, kpts1, kpts2, matches, scores, threshold, estimate, errors)


def _essential(kpts1, kpts2, matches, scores, threshold, settings: UsacSettings, rng, K1, K2) -> ModelFit:
    """The ``essential`` step (see :func:`apply_model_step`); ``K1``, ``K2`` validated by the caller."""
    import cv2

    def estimate(p1, p2):
        focal = np.mean([K1[0, 0], K1[1, 1], K2[0, 0], K2[1, 1]])
        params = _usac_params(settings, rng, threshold=settings.threshold / abs(focal))
        eye, no_distortion = np.eye(3), np.zeros(5)
        return cv2.findEssentialMat(_normalise_by_intrinsics(p1, K1), _normalise_by_intrinsics(p2, K2), eye, eye,
                                    no_distortion, no_distortion, params)

    def errors(model, p1, p2):
        return _model_errors(_fundamental_from_essential(model, K1, K2), "F", p1, p2)

    return _usac_fit("E", kpts1, kpts2, matches, scores, threshold, estimate, errors)


def model_kind_for(pair_kind: str) -> ModelKind:
    """``"H"`` for planar pairs, ``"F"`` for non-planar, depth and calibrated pairs."""
    if pair_kind == "planar":
        return "H"
    if pair_kind in ("nonplanar", "depth", "calibrated"):
        return "F"
    raise ValueError(f"pair kind must be 'planar', 'nonplanar', 'depth' or 'calibrated', got {pair_kind!r}")


def apply_model_step(name: str, kpts1, kpts2, matches, scores=None, *, kind: ModelKind,
                     threshold: float = CONSISTENCY_THRESHOLD_PX, rng=None, estimator: Mapping | None = None, K1=None,
                     K2=None) -> ModelFit:
    """Run the model step ``name`` (one of :data:`MODEL_STEPS`) on the matches.

    ``"none"`` keeps every match; ``"1sac"`` is :func:`one_sac`; ``"ransac"``, ``"prosac"``, ``"magsac"`` are
    :func:`ransac` with their :data:`USAC_PRESETS` updated by ``estimator``. ``"essential"`` (calibrated
    pairs) fits ``E`` by ``cv2.findEssentialMat``'s USAC (Nistér's five-point solver, TPAMI 2004) on points
    normalised by ``K1``, ``K2`` (threshold divided by the mean focal length) and keeps the matches within
    ``threshold`` pixels of the epipolar lines of ``F = K2^-T E K1^-1``; see docs/evaluation.md (Model steps).
    ``"poselib"`` and ``"poselib_essential"`` are the same two fits by PoseLib's LO-RANSAC
    (:func:`~ctxmatch_lib.geometry.poselib_steps.poselib_fit`).
    """
    if name not in MODEL_STEPS:
        raise ValueError(f"unknown model step {name!r}; known: {', '.join(MODEL_STEPS)}")
    if name == "none":
        k = len(as_matches(matches))
        return ModelFit(np.ones(k, bool), None, _check_kind(kind, MIN_SAMPLE), np.arange(k, dtype=np.int64),
                        np.zeros(k))
    if name in ("essential", "poselib_essential"):
        _check_kind(kind, MIN_SAMPLE)
        K1, K2 = check_intrinsics(K1, "K1"), check_intrinsics(K2, "K2")
        _, kpts1, kpts2, matches, scores = _check_step("F", kpts1, kpts2, matches, scores, threshold)
        settings = usac_settings(name, estimator)
        if name == "poselib_essential":
            return poselib_fit(name, kpts1, kpts2, matches, kind="E", threshold=threshold, settings=settings,
                               rng=rng, K1=K1, K2=K2)
        return _essential(kpts1, kpts2, matches, scores, threshold, settings, rng, K1, K2)
    kind, kpts1, kpts2, matches, scores = _check_step(kind, kpts1, kpts2, matches, scores, threshold)
    if name == "1sac":
        return _one_sac(kpts1, kpts2, matches, scores, kind, threshold)
    if name == "poselib":
        return poselib_fit(name, kpts1, kpts2, matches, kind=kind, threshold=threshold,
                           settings=usac_settings(name, estimator), rng=rng)
    return _ransac(kpts1, kpts2, matches, scores, kind, threshold, usac_settings(name, estimator), rng)
