"""The per-pair evaluation of Sec. 5.1: features -> blob -> filters -> model -> ground truth -> metrics.

Each step is a function that can be called on its own (:func:`pair_features`, :func:`blob_candidates`,
:func:`run_filter`, :func:`run_model`, :func:`label_candidates`: they live in
:mod:`ctxmatch_lib.evaluation.steps` and are re-exported here; :func:`metrics_rows`);
:func:`evaluate_pair` chains them for one pair and keeps every intermediate result in a
:class:`PairEvaluation`, and :func:`evaluate_dataset` runs a whole dataset into a ``pandas.DataFrame`` with
one row per (pair, blob setup, method, model), on the evaluation engine of :mod:`ctxmatch_lib.evaluation`
(per-pair result parts in the cache, resumable; tested to give the same rows as :func:`evaluate_pair`).
This module sits on the engine: the steps below it never import it.

How the pieces fit:

* the ground truth labels the **blob candidates** once per blob setup; every later output (a filter's
  mask, then a model's mask) is a subset of them, so its labels are read off, never recomputed;
* the recall reference of a row is the set of correct candidates of its own blob setup (Sec. 5.3), the
  recall* reference the union of the correct candidates of all blob setups evaluated on the pair (same
  keypoints, so the union is well defined);
* the unfiltered candidates appear as method ``"blob"``; models are ``"none"``, ``"1sac"``, ``"ransac"``, ``"prosac"``,
  fitted on the method's output, ``H`` for planar pairs and ``F`` for non-planar and depth pairs;
* ``time_s`` is the running time of the method itself (blob matching for ``"blob"``, the filter alone for
  a filter), the same on every model row of that method as in the paper's tables; ``model_time_s`` is
  the model step's own time.

Keypoints are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .datasets.base import Dataset, Pair, PoseGT
from .evaluation.plan import plan_units
from .evaluation.run import run_units
from .evaluation.steps import (BLOB_METHOD, blob_candidates, check_filters, check_models, check_pair_keypoints,
                               label_candidates, pair_features, pair_seed, resolve_blobs,
                               run_filter, run_model)
from .features import FeatureConfig
from .geometry import CONSISTENCY_THRESHOLD_PX
from .groundtruth import GT_METHODS, GT_THRESHOLD_PX
from .metrics import evaluate_matches, ground_truth_union

__all__ = [
    "BLOB_METHOD",
    "ROW_COLUMNS",
    "BlobStage",
    "PairEvaluation",
    "resolve_blobs",
    "check_filters",
    "check_pair_keypoints",
    "check_models",
    "pair_features",
    "blob_candidates",
    "run_filter",
    "run_model",
    "label_candidates",
    "metrics_rows",
    "evaluate_pair",
    "evaluate_dataset",
    "summary_table",
    "pair_seed",
]

#: Columns of a result row, in order.
ROW_COLUMNS = (
    "dataset", "pair_id", "kind", "blob", "method", "model",
    "precision", "recall", "recall_star", "ap", "correct", "correct_norm", "output", "failure", "empty_output",
    "time_s", "model_time_s", "n_kpts1", "n_kpts2", "n_candidates", "n_gt", "n_gt_star", "gt_method", "error",
)
"""Units: ``precision``, ``recall``, ``recall_star`` and ``ap`` are fractions in [0, 1] (NaN when
undefined); ``correct`` is a plain count, ``correct_norm`` the normalised count of Sec. 5.1; ``failure`` a
non-empty output without a correct match, ``empty_output`` an output with no match at all; ``time_s`` (the method)
and ``model_time_s`` (the model step) in seconds; ``error`` is empty, or says why the row could not be
evaluated (its metrics are then NaN). :func:`summary_table` prints percentages under ``*_pct`` names."""


# -------------------------------------------------------------------------------------- per-pair state


@dataclass
class BlobStage:
    """Everything computed for one blob setup on one pair.

    ``keeps[method]`` masks the candidates (``keeps["blob"]`` is all ``True``); ``fits[(method, model)]``
    is the :class:`~ctxmatch_lib.geometry.ModelFit` over the method's output, whose ``keep`` masks that
    output; :meth:`final_mask` combines the two into a mask over the candidates.
    """

    name: str
    config: object
    matches: np.ndarray
    scores: np.ndarray
    labels: np.ndarray
    time_s: float
    keeps: dict = field(default_factory=dict)
    method_times: dict = field(default_factory=dict)
    fits: dict = field(default_factory=dict)
    model_times: dict = field(default_factory=dict)

    @property
    def correct_candidates(self) -> np.ndarray:
        """The recall reference: ground-truth-correct candidates, ``(M, 2)``."""
        return self.matches[self.labels]

    def final_mask(self, method: str, model: str) -> np.ndarray:
        """Mask over the candidates of the output of ``method`` followed by ``model``."""
        keep = self.keeps[method].copy()
        keep[np.flatnonzero(keep)] = self.fits[(method, model)].keep
        return keep


@dataclass
class PairEvaluation:
    """All intermediate results of :func:`evaluate_pair` and its result rows."""

    pair: Pair
    features: tuple
    stages: dict
    gt_method: str
    rows: list = field(default_factory=list)

    @property
    def reference_star(self) -> np.ndarray:
        """Union of the correct candidates over the blob setups (the recall* reference)."""
        return ground_truth_union(*(s.correct_candidates for s in self.stages.values()))


def metrics_rows(evaluation: PairEvaluation, *, reference_star=None) -> list[dict]:
    """One row dict per (blob setup, method, model) of an evaluated pair.

    ``reference_star`` overrides the recall* reference (by default :attr:`PairEvaluation.reference_star`),
    e.g. with a union over configurations run elsewhere on the same keypoints.
    """
    pair = evaluation.pair
    f1, f2 = evaluation.features
    ref_star = evaluation.reference_star if reference_star is None else reference_star
    rows = []
    for stage in evaluation.stages.values():
        ref = stage.correct_candidates
        for method in stage.keeps:
            for (m, model), fit in stage.fits.items():
                if m != method:
                    continue
                mask = stage.final_mask(method, model)
                mm = evaluate_matches(stage.matches[mask], stage.labels[mask], reference=ref,
                                      reference_star=ref_star, scores=stage.scores[mask],
                                      time_s=stage.method_times[method])
                rows.append({
                    "dataset": pair.dataset, "pair_id": pair.pair_id, "kind": pair.kind, "blob": stage.name,
                    "method": method, "model": model,
                    "precision": mm.precision, "recall": mm.recall, "recall_star": mm.recall_star, "ap": mm.ap,
                    "correct": mm.correct, "correct_norm": mm.correct_norm, "output": mm.output,
                    "failure": mm.failure, "empty_output": mm.empty_output, "time_s": mm.time_s,
                    "model_time_s": stage.model_times[(method, model)],
                    "n_kpts1": len(f1), "n_kpts2": len(f2), "n_candidates": len(stage.matches),
                    "n_gt": mm.n_gt, "n_gt_star": mm.n_gt_star, "gt_method": evaluation.gt_method, "error": "",
                })
    return rows


def evaluate_pair(
    pair: Pair,
    *,
    features: FeatureConfig = FeatureConfig(),
    blobs="paper-best",
    filters: Sequence[str] = ("dtm",),
    models: Sequence[str] = ("none", "1sac"),
    gt_method: str = "D",
    gt_threshold: float = GT_THRESHOLD_PX,
    model_threshold: float = CONSISTENCY_THRESHOLD_PX,
    filter_params: Mapping[str, dict] | None = None,
    seed: int = 0,
    cache_dir=None,
    precomputed_features: tuple | None = None,
) -> PairEvaluation:
    """Evaluate one pair: features, then for each blob setup candidates, labels, filters, models, metrics.

    Parameters
    ----------
    pair : Pair
    features : FeatureConfig
    blobs : str, BlobConfig, list or dict
        Blob setups (:func:`resolve_blobs`).
    filters : sequence of str
        Registered filter names; ``"blob"`` (no filter) is always included.
    models : sequence of str
        Model steps among ``none``, ``1sac``, ``ransac``, ``prosac``.
    gt_method : {"D", "A"}
        Ground-truth method; ``gt_threshold`` its distance in pixels.
    model_threshold : float
        Consistency threshold of 1SAC / RANSAC in pixels.
    filter_params : dict of str -> dict, optional
        Extra keyword arguments per filter.
    seed : int
        RANSAC seed; combined with ``pair.pair_id``.
    cache_dir
        Feature cache (see :func:`~ctxmatch_lib.features.extract_features`).
    precomputed_features : (Features, Features), optional
        Skip extraction.

    Returns
    -------
    PairEvaluation
        ``.rows`` holds the result rows (see :data:`ROW_COLUMNS`).
    """
    if gt_method not in GT_METHODS:
        raise ValueError(f"gt_method must be one of {GT_METHODS}, got {gt_method!r}")
    blob_cfgs = resolve_blobs(blobs)
    filters = check_filters(filters)
    models = check_models(models)
    filter_params = dict(filter_params or {})
    f1, f2 = precomputed_features if precomputed_features is not None else pair_features(
        pair, features, cache_dir=cache_dir)
    check_pair_keypoints(pair, f1, f2)
    rng_seed = pair_seed(seed, pair.pair_id)
    stages = {}
    for bname, cfg in blob_cfgs.items():
        matches, scores, t_blob = blob_candidates(f1, f2, cfg)
        labels = label_candidates(pair, f1, f2, matches, method=gt_method, threshold=gt_threshold)
        stage = BlobStage(bname, cfg, matches, scores, labels, t_blob)
        stage.keeps[BLOB_METHOD] = np.ones(len(matches), bool)
        stage.method_times[BLOB_METHOD] = t_blob
        for name in filters:
            try:
                keep, t = run_filter(name, f1, f2, matches, scores, image_size1=pair.image_size1,
                                     image_size2=pair.image_size2, blob_ratio=cfg.ratio,
                                     **filter_params.get(name, {}))
            except Exception as exc:
                raise RuntimeError(f"filter {name!r} failed on pair {pair.pair_id!r}: {exc}") from exc
            stage.keeps[name], stage.method_times[name] = keep, t
        for method, keep in stage.keeps.items():
            for model in models:
                fit, t = run_model(model, f1, f2, matches[keep], scores[keep], pair_kind=pair.kind,
                                   threshold=model_threshold, rng=rng_seed,
                                   intrinsics=(pair.gt.K1, pair.gt.K2) if isinstance(pair.gt, PoseGT) else None)
                stage.fits[(method, model)], stage.model_times[(method, model)] = fit, t
        stages[bname] = stage
    evaluation = PairEvaluation(pair, (f1, f2), stages, gt_method)
    evaluation.rows = metrics_rows(evaluation)
    return evaluation


def evaluate_dataset(
    dataset: Dataset | Iterable[Pair],
    *,
    progress: bool = True,
    results_dir=None,
    recompute: bool = False,
    n_jobs: int = 1,
    **kwargs,
):
    """Evaluate every pair of ``dataset``; returns a ``pandas.DataFrame`` of all rows.

    Runs on the one evaluation engine of :func:`ctxmatch_lib.evaluation.run_units` (shared with
    ``ctxmatch eval``, ``ctxmatch sweep`` and the report notebooks): each pair is a work unit whose rows
    are kept as a Parquet part in the evaluation cache, so an interrupted run resumes with no lost and no duplicated rows and a rerun
    only reads. A pair that cannot be evaluated (unreadable image, 0 keypoints, a filter that raised) is
    reported with a ``RuntimeWarning`` naming it, the image and the reason, and gets rows with NaN metrics
    and a non-empty ``error``; the run goes on.

    Parameters
    ----------
    dataset : Dataset or iterable of Pair
    progress : bool
        A tqdm bar on stderr naming the pair in progress.
    results_dir : path, None or False
        The evaluation cache (default ``ctxmatch_lib.cache.cache_dir("sweep")``); ``False`` keeps
        nothing on disk (and cannot resume).
    recompute : bool
        Ignore the cached rows of these pairs and settings.
    n_jobs : int
        Local worker processes (``-1``: all cores).
    **kwargs
        As :func:`evaluate_pair`: ``features``, ``blobs``, ``filters``, ``models``, ``gt_method``,
        ``gt_threshold``, ``model_threshold``, ``filter_params``, ``seed``, and ``cache_dir`` (the
        feature cache). All are validated before any work.

    Returns
    -------
    pandas.DataFrame
        :data:`ctxmatch_lib.evaluation.SWEEP_COLUMNS` (which include :data:`ROW_COLUMNS`), one row per (pair,
        blob setup, method, model), in dataset order.
    """
    known = {"features", "blobs", "filters", "models", "gt_method", "gt_threshold", "model_threshold",
             "filter_params", "seed", "cache_dir"}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise TypeError(f"evaluate_dataset got unexpected arguments {unknown}; known: {sorted(known)}")
    feature_cache = kwargs.pop("cache_dir", None)
    kwargs.setdefault("features", FeatureConfig())
    kwargs.setdefault("filters", ("dtm",))
    kwargs.setdefault("models", ("none", "1sac"))
    kwargs["blobs"] = resolve_blobs(kwargs.get("blobs", "paper-best"))
    units = plan_units(list(dataset), **kwargs)
    return run_units(units, cache_dir=results_dir, feature_cache_dir=feature_cache, n_jobs=n_jobs,
                     progress=progress, recompute=recompute, desc="ctxmatch eval")


def summary_table(df):
    """Per-kind, per-method (and model) means, as the Appendix tables: one row per group.

    Columns (units in the names; the rows themselves hold fractions):

    * ``pairs``: pairs evaluated in the group (rows with an ``error`` excluded);
    * ``precision_pct``, ``recall_pct``, ``recall_star_pct``, ``mAP_pct``: means over those pairs, in %.
      An empty output counts as 0 % precision and 0 % recall (the paper's convention); recall, recall*
      and AP are NaN, and skipped, on a pair without any correct candidate;
    * ``correct``, ``correct_norm`` (the normalised count of Sec. 5.1), ``output``: mean match counts;
    * ``failures``: pairs whose output is not empty but holds no correct match; ``empty_outputs``: pairs with
      an empty output (the paper's failures are ``failures + empty_outputs``); ``errors``: pairs that could not be
      evaluated (see the ``error`` column);
    * ``time_s``: mean seconds of the method itself; ``model_time_s``: of the model step alone.

    Grouped by ``blob`` too when several blob setups are present, and by ``features`` when several feature
    setups are.
    """
    import pandas as pd

    if df.empty:
        return pd.DataFrame()
    keys = (["kind"] + [k for k in ("features", "blob") if k in df.columns and df[k].nunique() > 1]
            + ["method", "model"])
    d = df.copy()
    # Keep the order of appearance (blob first, filters as given, models as given) rather than sorting.
    for k in keys:
        d[k] = pd.Categorical(d[k], categories=list(dict.fromkeys(d[k])), ordered=True)
    err = d["error"].astype(str) != "" if "error" in d.columns else pd.Series(False, index=d.index)
    empty = d["empty_output"] if "empty_output" in d.columns else d["output"] == 0
    d = d.assign(_err=err, _empty=empty & ~err, _failure=d["failure"] & ~err)
    ok = d[~err]
    g = ok.groupby(keys, observed=True, sort=True)
    ge = d.groupby(keys, observed=True, sort=True)
    out = pd.DataFrame({
        "pairs": g["pair_id"].nunique(),
        "precision_pct": 100 * g["precision"].mean(),
        "recall_pct": 100 * g["recall"].mean(),
        "recall_star_pct": 100 * g["recall_star"].mean(),
        "mAP_pct": 100 * g["ap"].mean(),
        "correct": g["correct"].mean(),
        "correct_norm": g["correct_norm"].mean(),
        "output": g["output"].mean(),
        "failures": g["_failure"].sum(),
        "empty_outputs": g["_empty"].sum(),
        "time_s": g["time_s"].mean(),
        "model_time_s": g["model_time_s"].mean(),
    })
    out = out.reindex(ge.size().index)
    out["errors"] = ge["_err"].sum().astype(int)
    for c in ("pairs", "failures", "empty_outputs"):
        out[c] = out[c].fillna(0).astype(int)
    return out
