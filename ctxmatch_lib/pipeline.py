"""The per-pair evaluation of Sec. 5.1 (features -> blob -> filters -> model -> ground truth -> metrics), a thin
face over :mod:`ctxmatch_lib.evaluation`.

:func:`evaluate_pair` keeps every intermediate of one pair, :func:`evaluate_dataset` runs a dataset on the
engine (resumable), :func:`summary_table` averages the rows as the Appendix tables; the steps of
:mod:`ctxmatch_lib.evaluation.steps` are re-exported.
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

__all__ = ["BLOB_METHOD", "ROW_COLUMNS", "BlobStage", "PairEvaluation", "resolve_blobs", "check_filters",
           "check_pair_keypoints", "check_models", "pair_features", "blob_candidates", "run_filter", "run_model",
           "label_candidates", "evaluate_pair", "evaluate_dataset", "summary_table", "pair_seed"]

#: Columns of a result row, in order.
ROW_COLUMNS = (
    "dataset", "pair_id", "kind", "blob", "method", "model",
    "precision", "recall", "recall_star", "ap", "correct", "correct_norm", "output", "failure", "empty_output",
    "time_s", "model_time_s", "n_kpts1", "n_kpts2", "n_candidates", "n_gt", "n_gt_star", "gt_method", "error",
)
"""Units as in :mod:`ctxmatch_lib.evaluation.rows` (docs/evaluation.md, Result rows)."""


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
    """Evaluate one pair (:func:`~ctxmatch_lib.evaluation.run_unit`, nothing cached), keeping every intermediate.

    Parameters
    ----------
    pair : Pair
    features : FeatureConfig
    blobs : str, BlobConfig, list or dict
        Blob setups (:func:`resolve_blobs`).
    filters, models : sequence of str
        Registered filters (``"blob"``, no filter, always included); :data:`~ctxmatch_lib.geometry.MODEL_STEPS`.
    gt_method, gt_threshold : {"D", "A", "B", "C"}, float
        Ground-truth method and its distance in pixels (D and A).
    model_threshold : float
        Consistency threshold of the model step in pixels.
    filter_params : dict of str -> dict, optional
        Extra keyword arguments per filter.
    seed : int
        RANSAC seed; combined with ``pair.pair_id``.
    cache_dir, precomputed_features : path, (Features, Features), optional
        Feature cache (:func:`~ctxmatch_lib.features.extract_features`); features that skip extraction.

    Returns
    -------
    PairEvaluation
        ``.stages[blob]``: a :class:`~ctxmatch_lib.evaluation.unit.BlobStage`; ``.rows``: :data:`ROW_COLUMNS`.
        A filter or model step that raises gives a ``RuntimeError``.
    """
    (unit,) = plan_units([pair], features=features, blobs=resolve_blobs(blobs), filters=tuple(filters),
                         models=tuple(models), gt_method=gt_method, gt_threshold=gt_threshold,
                         model_threshold=model_threshold, filter_params=filter_params, seed=seed, salt="")
    if precomputed_features is not None:
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
    """Evaluate every pair of ``dataset`` on the engine (:func:`ctxmatch_lib.evaluation.run_units`: resumable,
    a pair that cannot be evaluated gets error rows and a ``RuntimeWarning``).

    Parameters
    ----------
    dataset : Dataset or iterable of Pair
    progress, recompute : bool
        A tqdm bar on stderr; ignore the cached rows.
    results_dir : path, None or False
        The evaluation cache (default ``ctxmatch_lib.cache.cache_dir("sweep")``); ``False``: none.
    n_jobs : int
        Local worker processes (``-1``: all cores).
    **kwargs
        As :func:`evaluate_pair` (``cache_dir`` is the feature cache), validated before any work.

    Returns
    -------
    pandas.DataFrame
        :data:`ctxmatch_lib.evaluation.SWEEP_COLUMNS`, one row per (pair, blob setup, method, model).
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
    """Per-kind, per-method (and model) means, as the Appendix tables; also per ``features`` and ``blob``
    where several are present.

    Means in % under ``*_pct`` names (an empty output counts as 0 %), mean counts, pair counts of
    ``failures``, ``empty_outputs`` and ``errors`` (see docs/evaluation.md, Result rows).
    """
    import pandas as pd

    if df.empty:
        return pd.DataFrame()
    keys = (["kind"] + [k for k in ("features", "blob") if k in df.columns and df[k].nunique() > 1]
            + ["method", "model"])
    d = df.copy()
    # Groups in order of appearance, not sorted.
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
