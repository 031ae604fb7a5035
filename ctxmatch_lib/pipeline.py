"""The per-pair evaluation of Sec. 5.1 (features -> blob -> filters -> model -> ground truth -> metrics) as a
thin face over the evaluation engine of :mod:`ctxmatch_lib.evaluation`.

:func:`evaluate_pair` runs one pair through the engine's unit and keeps every intermediate result in a
:class:`PairEvaluation`; :func:`evaluate_dataset` runs a whole dataset on the engine (per-pair parts in the
cache, resumable) into one row per (pair, blob setup, method, model); :func:`summary_table` averages the rows
as the Appendix tables. The steps (:func:`pair_features`, :func:`blob_candidates`, :func:`run_filter`,
:func:`run_model`, :func:`label_candidates`) live in :mod:`ctxmatch_lib.evaluation.steps` and are
re-exported here.

* the ground truth labels the **blob candidates** once; every later output (a filter's mask, then a model's
  mask) is a subset of them, so its labels are read off, never recomputed;
* the recall reference of a row is the set of correct candidates of its own blob setup (Sec. 5.3), the
  recall* reference their union over the blob setups evaluated on the pair;
* the unfiltered candidates are method ``"blob"``; a model step is fitted on the method's output, ``H`` for
  planar pairs, ``F`` otherwise;
* ``time_s`` is the time of the method itself (blob matching, or the filter alone), ``model_time_s`` of the
  model step.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .datasets.base import Dataset, Pair, PoseGT
from .evaluation.plan import plan_units
from .evaluation.run import named_rows, run_units
from .evaluation.steps import (BLOB_METHOD, blob_candidates, check_filters, check_models, check_pair_keypoints,
                               label_candidates, pair_features, pair_seed, resolve_blobs, run_filter, run_model)
from .evaluation.unit import BlobStage, run_unit
from .features import FeatureConfig
from .geometry import CONSISTENCY_THRESHOLD_PX
from .groundtruth import GT_THRESHOLD_PX
from .metrics import ground_truth_union

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
    """Evaluate one pair and keep every intermediate: the engine's unit (:func:`~ctxmatch_lib.evaluation.run_unit`,
    nothing cached) with its blob stages recorded.

    Parameters
    ----------
    pair : Pair
    features : FeatureConfig
    blobs : str, BlobConfig, list or dict
        Blob setups (:func:`resolve_blobs`).
    filters : sequence of str
        Registered filter names; ``"blob"`` (no filter) is always included.
    models : sequence of str
        Model steps among :data:`~ctxmatch_lib.geometry.MODEL_STEPS`.
    gt_method : {"D", "A", "B", "C"}
        Ground-truth method; ``gt_threshold`` its distance in pixels (D and A).
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
        ``.stages[blob]`` is a :class:`~ctxmatch_lib.evaluation.unit.BlobStage` (candidates in score order,
        labels, every mask and model fit); ``.rows`` the result rows (see :data:`ROW_COLUMNS`).

    Raises
    ------
    RuntimeError
        When a filter or model step raises on the pair (the engine records it as an error row instead).
    """
    (unit,) = plan_units([pair], features=features, blobs=resolve_blobs(blobs), filters=tuple(filters),
                         models=tuple(models), gt_method=gt_method, gt_threshold=gt_threshold,
                         model_threshold=model_threshold, filter_params=filter_params, seed=seed, salt="")
    if precomputed_features is not None:
        check_pair_keypoints(pair, *precomputed_features)
        feats = tuple(precomputed_features)
    else:
        feats = pair_features(pair, unit.features, cache_dir=cache_dir)
        check_pair_keypoints(pair, *feats)
    stages = {}
    df = named_rows(run_unit(unit, cache_dir=False, features=feats, stages=stages), unit)
    errors = df["error"].astype(str)
    if (errors != "").any():
        raise RuntimeError(f"pair {pair.pair_id!r}: {errors[errors != ''].iloc[0]}")
    rows = df[list(ROW_COLUMNS)].assign(dataset=pair.dataset).to_dict("records")
    return PairEvaluation(pair, feats, stages, gt_method, rows)


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
