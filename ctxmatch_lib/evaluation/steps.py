"""The per-pair steps of Sec. 5.1 (features -> blob -> filters -> model -> ground truth) and the argument
checks shared with the command line; the bottom layer of the engine, above the method modules only.
"""

from __future__ import annotations

import functools
import time
import zlib
from collections.abc import Callable, Iterable, Mapping

import numpy as np

from .._numerics.scores import nnr_scores, score_ratio
from ..datasets.base import Pair, PoseGT
from ..features import FeatureConfig, Features, extract_features
from ..geometry import (CONSISTENCY_THRESHOLD_PX, MODEL_STEPS, ROBUST_STEPS, ModelFit, apply_model_step, model_kind_for,
                        pose_from_model, relative_pose_error)
from ..geometry_metrics import EPIPOLAR_THRESHOLDS_PX, epipolar_consistency, homography_corner_error
from ..groundtruth import GT_THRESHOLD_PX, label_matches

__all__ = ["BLOB_METHOD", "PAPER_FILTER_ORDER", "resolve_blobs", "resolve_filters", "check_filters", "check_models",
           "check_matchers", "check_estimator", "check_pair_keypoints", "pair_seed", "run_seed", "pair_features",
           "blob_candidates", "run_filter", "run_model", "run_matcher", "model_accuracy", "EPI_SHARE_AT_PX",
           "POSE_COLUMNS", "label_candidates"]

#: Thresholds (px) with their own ``epi_share_<t>`` column, beside the mean over 1 ... 19 px.
EPI_SHARE_AT_PX = (1, 3, 5, 10)

#: Pose errors of a calibrated pair (degrees): rotation, translation direction, their maximum (SuperGlue's).
POSE_COLUMNS = ("pose_err_R", "pose_err_t", "pose_err")

#: Method name of the unfiltered blob candidates.
BLOB_METHOD = "blob"

#: Filters in the row order of the paper's Tables 1-3 (those not implemented here are skipped).
PAPER_FILTER_ORDER = ("th", "dtm1", "dtm2", "lmr", "lpm", "glpm", "gms", "vfc", "llt", "rfm_scan", "adalam",
                      "oanet", "acne", "pfm", "pgm", "scv", "bm")


# ------------------------------------------------------------------------------------------ arguments


def resolve_blobs(blobs) -> dict:
    """Named blob setups (``{name: BlobConfig}``, in order) from a preset name, a ``BlobConfig``, a list of
    them or a dict; a bare ``BlobConfig`` is named by its ``label``."""
    from ..blob import BLOB_PRESETS, BlobConfig

    return named_configs(blobs, BLOB_PRESETS, BlobConfig, argument="blobs", kind="blob", noun="blob setup",
                         default_name=lambda b: b.label)


def named_configs(configs, presets: Mapping, cls: type, *, argument: str, kind: str, noun: str,
                  default_name: Callable) -> dict:
    """The rule of :func:`resolve_blobs`: presets named by their key, bare configs by ``default_name``;
    errors name ``argument``."""
    if isinstance(configs, (str, cls)):
        configs = [configs]
    items = configs.items() if isinstance(configs, Mapping) else [(None, c) for c in configs]
    out = {}
    for name, c in items:
        if isinstance(c, str):
            if c not in presets:
                raise ValueError(f"unknown {kind} preset {c!r}; known presets: {', '.join(presets)}")
            name, c = name or c, presets[c]
        elif not isinstance(c, cls):
            raise ValueError(f"{argument} must hold preset names or {cls.__name__}, got {type(c).__name__}")
        out[name or default_name(c)] = c
    if not out:
        raise ValueError(f"{argument} must name at least one {noun}")
    return out


def check_filters(filters: Iterable[str]) -> tuple[str, ...]:
    """Validate filter names against the registry (``dtm1`` and ``dtm2`` included); raises ``ValueError``
    listing the known ones."""
    from ..filters import FILTERS

    if isinstance(filters, str):
        filters = [filters]
    names = tuple(filters)
    for name in names:
        if name == BLOB_METHOD:
            raise ValueError(f"{BLOB_METHOD!r} is always evaluated (the unfiltered candidates); not a filter name")
        try:
            FILTERS[name]
        except KeyError:
            raise ValueError(f"unknown filter {name!r}; known filters: {', '.join(sorted(FILTERS))}") from None
    if len(set(names)) != len(names):
        raise ValueError(f"filters are repeated: {names}")
    return names


def check_models(models: Iterable[str]) -> tuple[str, ...]:
    """Validate model-step names (:data:`~ctxmatch_lib.geometry.MODEL_STEPS`)."""
    names = tuple(models)
    for name in names:
        if name not in MODEL_STEPS:
            raise ValueError(f"unknown model {name!r}; known models: {', '.join(MODEL_STEPS)}")
    if not names:
        raise ValueError(f"models must name at least one of {', '.join(MODEL_STEPS)}")
    if len(set(names)) != len(names):
        raise ValueError(f"models are repeated: {names}")
    return names


def check_matchers(matchers) -> tuple[str, ...]:
    """Validate alternative matcher names (:data:`~ctxmatch_lib.opencv_matchers.OPENCV_MATCHERS`)."""
    from ..opencv_matchers import OPENCV_MATCHERS

    names = (matchers,) if isinstance(matchers, str) else tuple(matchers or ())
    for name in names:
        if name not in OPENCV_MATCHERS:
            raise ValueError(f"unknown matcher {name!r}; known matchers: {', '.join(OPENCV_MATCHERS)}")
    if len(set(names)) != len(names):
        raise ValueError(f"matchers are repeated: {names}")
    return names


def check_estimator(estimator) -> tuple:
    """USAC overrides (``threshold``, ``confidence``, ``max_iters``) as sorted, validated ``(key, value)``
    pairs (:func:`~ctxmatch_lib.geometry.usac_settings`); ``None``: the presets' own."""
    from ..geometry import usac_settings

    items = dict(estimator or {})
    usac_settings("ransac", items)  # raises naming a bad key or value
    return tuple(sorted((k, int(v) if k == "max_iters" else float(v)) for k, v in items.items()))


def resolve_filters(filters="all") -> tuple[str, ...]:
    """Filter names to evaluate: ``"all"`` is every registered filter (``dtm`` as ``dtm1`` and ``dtm2``) but
    :data:`~ctxmatch_lib.filters.NOT_IN_ALL`, in :data:`PAPER_FILTER_ORDER`, then the others alphabetically; a
    list is validated and kept.

    Examples
    --------
    >>> resolve_filters(["th", "dtm2"])
    ('th', 'dtm2')
    """
    from ..filters import FILTERS, NOT_IN_ALL

    if isinstance(filters, str) and filters == "all":
        names = [n for n in FILTERS if n != "dtm" and n not in NOT_IN_ALL]
        rank = {n: i for i, n in enumerate(PAPER_FILTER_ORDER)}
        return tuple(sorted(names, key=lambda n: (rank.get(n, len(rank)), n)))
    return check_filters(filters)


def check_pair_keypoints(pair: Pair, f1: Features, f2: Features) -> None:
    """Raise ``ValueError`` when keypoints fall outside ``pair.image_size1`` / ``image_size2`` (width,
    height; :func:`ctxmatch_lib._numerics.validation.check_inside`)."""
    from .._numerics.validation import check_inside

    check_inside(f1.kpts, pair.image_size1, f"keypoints of image1 of pair {pair.pair_id!r}")
    check_inside(f2.kpts, pair.image_size2, f"keypoints of image2 of pair {pair.pair_id!r}")


def pair_seed(seed: int, pair_id: str) -> int:
    """Per-pair seed independent of the order pairs are run in (so sweeps can cache per pair)."""
    return int(np.random.SeedSequence([int(seed), zlib.crc32(pair_id.encode())]).generate_state(1)[0])


def run_seed(pair_seed_: int, method: str, model: str, run: int) -> int:
    """The seed of run ``run`` of a random model step on ``method``'s output: run 0 takes the pair's seed (a
    single run's), run ``r > 0`` one derived from the pair's seed, the method, the step and ``r``.

    Examples
    --------
    >>> run_seed(7, "dtm2", "magsac", 0)
    7
    >>> run_seed(7, "dtm2", "magsac", 1) != run_seed(7, "th", "magsac", 1)
    True
    """
    if run == 0:
        return int(pair_seed_)
    words = [int(pair_seed_), zlib.crc32(method.encode()), zlib.crc32(model.encode()), int(run)]
    return int(np.random.SeedSequence(words).generate_state(1)[0])


# ------------------------------------------------------------------------------------------------ steps


def pair_features(pair: Pair, config: FeatureConfig = FeatureConfig(), *, cache_dir=None) -> tuple[Features, Features]:
    """Features of both images of ``pair`` (disk-cached by :func:`~ctxmatch_lib.features.extract_features`)."""
    return (
        extract_features(pair.image1, config, cache_dir=cache_dir),
        extract_features(pair.image2, config, cache_dir=cache_dir),
    )


def blob_candidates(f1: Features, f2: Features, config) -> tuple[np.ndarray, np.ndarray, float]:
    """Blob matching of two feature sets: matches (K, 2) int64, sorted scores (lower is better, carrying the
    blob ratio, as ``BlobMatches.scores``) and the wall time."""
    from ..blob import blob_matching

    t0 = time.perf_counter()
    if len(f1) == 0 or len(f2) == 0:
        return np.empty((0, 2), np.int64), np.empty(0), time.perf_counter() - t0
    bm = blob_matching(f1.desc, f2.desc, kpts1=f1.kpts, kpts2=f2.kpts, shapes1=f1.shapes, shapes2=f2.shapes,
                       distance=f1.distance(), **config.kwargs())
    # asanyarray keeps the scores' blob ratio (their scale, read by the filters' thresholds).
    return np.asarray(bm.matches, np.int64), np.asanyarray(bm.scores, np.float64), time.perf_counter() - t0


#: (name, function) of the filters already called by :func:`run_filter` in this process.
_WARM: set[tuple[str, Callable]] = set()


def run_filter(
    name: str,
    f1: Features,
    f2: Features,
    matches: np.ndarray,
    scores: np.ndarray,
    *,
    image_size1,
    image_size2,
    blob_ratio: str | None = None,
    **params,
) -> tuple[np.ndarray, float]:
    """Run the registered filter ``name`` on candidate matches.

    ``blob_ratio`` is passed as ``ratio=`` to filters with ``uses_blob_ratio`` and tags the scores of filters
    with ``nnr_thresholds``. The first call of a filter in a process runs once untimed, so that compiling its
    kernels is not charged to a pair. Returns ``(keep, time_s)``: a (K,) bool mask and the call's wall time.
    """
    from ..filters import FILTERS

    func: Callable = FILTERS[name]
    if blob_ratio is not None and getattr(func, "uses_blob_ratio", False):
        params.setdefault("ratio", blob_ratio)
    if blob_ratio is not None and getattr(func, "nnr_thresholds", None) and score_ratio(scores) is None:
        scores = nnr_scores(scores, blob_ratio)
    k = len(matches)
    if k == 0:
        return np.zeros(0, bool), 0.0
    call = functools.partial(func, f1.kpts, f2.kpts, matches, scores, image_size1=tuple(image_size1),
                             image_size2=tuple(image_size2), shapes1=f1.shapes, shapes2=f2.shapes, **params)
    if (name, func) not in _WARM:  # compile / load the filter's kernels outside the timing
        call()
        _WARM.add((name, func))
    t0 = time.perf_counter()
    out = call()
    elapsed = time.perf_counter() - t0
    keep = np.asarray(getattr(out, "keep", out))
    if keep.shape != (k,) or keep.dtype != bool:
        raise ValueError(f"filter {name!r} must return a ({k},) bool mask, got {keep.dtype} {keep.shape}")
    return keep, elapsed


def run_model(
    name: str,
    f1: Features,
    f2: Features,
    matches: np.ndarray,
    scores: np.ndarray,
    *,
    pair_kind: str,
    threshold: float = CONSISTENCY_THRESHOLD_PX,
    rng=None,
    estimator=None,
    intrinsics=None,
) -> tuple[ModelFit, float]:
    """Model step ``name`` (:data:`~ctxmatch_lib.geometry.MODEL_STEPS`) on a match set, with its wall time.

    ``H`` for planar pairs, ``F`` for the others (:func:`~ctxmatch_lib.geometry.model_kind_for`), ``E`` for
    the ``essential`` step, which needs ``intrinsics`` = ``(K1, K2)``; ``estimator``: :func:`check_estimator`.
    """
    extra = {} if intrinsics is None else {"K1": intrinsics[0], "K2": intrinsics[1]}
    t0 = time.perf_counter()
    fit = apply_model_step(name, f1.kpts, f2.kpts, matches, scores, kind=model_kind_for(pair_kind),
                           threshold=threshold, rng=rng, estimator=dict(estimator or ()), **extra)
    return fit, time.perf_counter() - t0


def run_matcher(name: str, f1: Features, f2: Features) -> tuple[np.ndarray, np.ndarray, float]:
    """The alternative matcher ``name`` (:data:`~ctxmatch_lib.opencv_matchers.OPENCV_MATCHERS`) on the
    descriptors of both images: matches (K, 2) int64, scores (K,) lower is better, and its wall time."""
    from ..opencv_matchers import OPENCV_MATCHERS

    t0 = time.perf_counter()
    matches, scores = OPENCV_MATCHERS[name](f1.desc, f2.desc)
    return matches, scores, time.perf_counter() - t0


def model_accuracy(model: str, fit: ModelFit | None, pair: Pair, corr, pts=None) -> dict:
    """The geometry columns of a row (NaN where one does not apply): ``model_inliers``, ``corner_error``
    (planar), ``epi_share_*`` (against the ground-truth correspondences ``corr``) or :data:`POSE_COLUMNS`
    (calibrated, from the inliers of ``pts = (pts1, pts2)``); see docs/evaluation.md (Geometry after the
    model step)."""
    nan = float("nan")
    out = {"model_inliers": nan, "corner_error": nan, "epi_share_mean": nan,
           **{f"epi_share_{t}": nan for t in EPI_SHARE_AT_PX}, **{c: nan for c in POSE_COLUMNS}}
    if model == "none" or fit is None:
        return out
    if fit.model is not None:
        inliers = fit.sample if model in ROBUST_STEPS else np.flatnonzero(fit.keep)
        out["model_inliers"] = float(len(inliers))
    else:
        inliers = np.empty(0, np.int64)
        out["model_inliers"] = 0.0
    if isinstance(pair.gt, PoseGT):
        out.update(_pose_columns(fit, inliers, pair.gt, pts))
    elif fit.kind == "H":
        H_gt = getattr(pair.gt, "H", None)
        if H_gt is not None:
            out["corner_error"] = homography_corner_error(fit.model, H_gt, pair.image_size1)
    elif corr is not None and len(corr[0]):
        th = EPIPOLAR_THRESHOLDS_PX
        share = epipolar_consistency(fit.model, corr[0], corr[1], thresholds=th)
        out["epi_share_mean"] = float(share.mean())
        for t in EPI_SHARE_AT_PX:
            out[f"epi_share_{t}"] = float(share[np.flatnonzero(th == t)[0]])
    return out


def _pose_columns(fit: ModelFit, inliers: np.ndarray, gt: PoseGT, pts) -> dict:
    """The pose columns of :func:`model_accuracy`: errors in degrees, 180 without a model or a pose."""
    pose = None
    if fit.model is not None and pts is not None and len(inliers):
        pose = pose_from_model(fit.model, fit.kind, pts[0][inliers], pts[1][inliers], gt.K1, gt.K2)
    err_R, err_t = relative_pose_error(*(pose or (None, None)), gt.R, gt.t)
    return {"pose_err_R": float(err_R), "pose_err_t": float(err_t), "pose_err": float(max(err_R, err_t))}


def label_candidates(
    pair: Pair, f1: Features, f2: Features, matches: np.ndarray, *, method: str = "D",
    threshold: float = GT_THRESHOLD_PX,
) -> np.ndarray:
    """Ground-truth labels of ``matches`` under ``pair.gt`` (:func:`~ctxmatch_lib.groundtruth.label_matches`)."""
    return label_matches(f1.kpts, f2.kpts, matches, pair.gt, method=method, threshold=threshold,
                         shapes1=f1.shapes, shapes2=f2.shapes)
