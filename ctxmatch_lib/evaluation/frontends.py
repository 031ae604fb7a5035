"""The engine's entry points: :func:`run_sweep` (a grid, ``ctxmatch sweep``), :func:`evaluate_cached` (named
presets, the report notebooks) and :func:`check_output`; both plan with :mod:`~ctxmatch_lib.evaluation.plan`
and run with :func:`~ctxmatch_lib.evaluation.run.run_units`, so they share unit keys."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

from ..cache import check_writable, write_parquet_atomic
from ..groundtruth import GT_THRESHOLD_PX
from .cache import FORMAT
from .plan import plan_sweep, plan_units
from .run import check_runner, run_units
from .steps import resolve_blobs, resolve_filters

__all__ = ["check_output", "run_sweep", "evaluate_cached"]


def check_output(path, name: str = "out", suffix: str = ".parquet") -> Path:
    """``path`` checked, before any work, to have ``suffix`` and be writable; errors name ``name``."""
    if suffix and Path(path).suffix.lower() != suffix:
        raise ValueError(f"{name} must end with {suffix}, got {path}")
    return check_writable(path, name)


def run_sweep(datasets="embedded", *, features="sift-rootsift", blobs="grid", filters=(), models=("none",),
              pairs=None, kinds=None, gt_method: str = "D", gt_threshold: float = GT_THRESHOLD_PX,
              model_threshold: float = 15.0, filter_params: Mapping[str, dict] | None = None, seed: int = 0,
              max_keypoints: int | str | None = None, n_jobs: int = 1, dask=None, cache_dir=None,
              feature_cache_dir=None, out=None, progress: bool = True, data_root=None, recompute: bool = False,
              matchers=(), estimator=None, runs: int = 1):
    """Run (or resume) a sweep and return its rows as a ``pandas.DataFrame`` (:data:`SWEEP_COLUMNS`).

    Parameters
    ----------
    datasets : str or list of str
        Registered dataset names or custom folders (``"embedded"``, ``"planar,nonplanar"``, ...).
    features : str, FeatureConfig, list or dict
        See :func:`~ctxmatch_lib.evaluation.plan.resolve_feature_configs`.
    blobs : str, BlobConfig or list
        ``"grid"`` (the 2430 setups of Sec. 5.2), preset names or configs.
    filters, filter_params
        Registered filters (method ``"blob"`` is always there) and extra keyword arguments per filter.
    models, matchers : sequence of str
        Model steps (:data:`~ctxmatch_lib.geometry.MODEL_STEPS`); extra matchers (:mod:`ctxmatch_lib.opencv_matchers`).
    estimator : dict, optional
        USAC overrides of the robust model steps (``threshold``, ``confidence``, ``max_iters``).
    runs : int
        Seeded runs of each random model step (:data:`~ctxmatch_lib.geometry.ROBUST_STEPS`) per pair and
        method, one row each (column ``run``; :func:`~ctxmatch_lib.evaluation.steps.run_seed`); the
        features, candidates and filters run once.
    max_keypoints : int or str, optional
        Keypoint cap (0: none) or a name of :data:`~ctxmatch_lib.features.KEYPOINT_BUDGETS`.
    pairs, kinds
        Pair subset (:func:`~ctxmatch_lib.evaluation.plan.select_pairs`) and pair kinds kept.
    gt_method, gt_threshold, model_threshold, seed
        As in :func:`ctxmatch_lib.pipeline.evaluate_pair`.
    n_jobs, dask
        Local worker processes (-1: every core); or a Dask scheduler address or client.
    cache_dir, feature_cache_dir : path, optional
        The sweep cache (default ``ctxmatch_lib.cache.cache_dir("sweep")``) and the feature cache.
    out : path, optional
        Also write the table to this Parquet file, with the settings as metadata.
    progress, recompute, data_root
        A tqdm bar; ignore existing result parts; root of the datasets.

    Returns
    -------
    pandas.DataFrame
        One row per (pair, features, blob setup, method, model, run), in the sweep's order.
    """
    check_runner(n_jobs, dask)
    if out is not None:
        check_output(out, "out")
    units = plan_sweep(datasets, features=features, blobs=blobs, filters=filters, models=models,
                       pairs=pairs, kinds=kinds, gt_method=gt_method, gt_threshold=gt_threshold,
                       model_threshold=model_threshold, filter_params=filter_params, seed=seed,
                       max_keypoints=max_keypoints, data_root=data_root, matchers=matchers, estimator=estimator,
                       runs=runs)
    df = run_units(units, cache_dir=cache_dir, feature_cache_dir=feature_cache_dir, n_jobs=n_jobs, dask=dask,
                   progress=progress, recompute=recompute, desc="ctxmatch sweep")
    if out is not None:
        meta = {"datasets": datasets, "features": {u.features_name: u.features.key() for u in units},
                "blobs": len(units[0].blobs), "filters": list(units[0].filters), "models": list(units[0].models),
                "pairs": len({(u.dataset, u.pair.pair_id) for u in units}), "gt_method": gt_method,
                "gt_threshold": gt_threshold, "model_threshold": model_threshold, "seed": seed,
                "matchers": list(units[0].matchers), "estimator": dict(units[0].estimator), "runs": runs,
                "format": FORMAT}
        write_parquet_atomic(df, out, meta)
    return df


def evaluate_cached(
    pairs: Iterable,
    *,
    features=("sift-rootsift",),
    blobs=("paper-best", "baseline"),
    filters="all",
    models=("none", "1sac"),
    max_keypoints: int | str | None = None,
    cache: bool = True,
    cache_dir=None,
    progress: bool = False,
    n_jobs: int = 1,
    **kwargs,
):
    """Evaluate ``pairs`` under every feature setup, reading and writing the evaluation cache.

    Parameters
    ----------
    pairs : iterable of Pair
        E.g. from :func:`~ctxmatch_lib.evaluation.plan.select_pairs`.
    features : sequence of str or FeatureConfig
        Feature setups (names of :data:`~ctxmatch_lib.features.FEATURE_PRESETS`), named in ``features``.
    blobs, models, kwargs
        As :func:`ctxmatch_lib.pipeline.evaluate_pair` (``gt_method``, ``gt_threshold``,
        ``model_threshold``, ``filter_params``, ``seed``) and :func:`run_sweep` (``matchers``, ``estimator``,
        ``runs``).
    filters : "all" or sequence of str
        See :func:`~ctxmatch_lib.evaluation.steps.resolve_filters`.
    max_keypoints, cache_dir, progress, n_jobs
        As in :func:`run_sweep`.
    cache : bool
        Read and write the cache (``False``: recompute, write nothing).

    Returns
    -------
    pandas.DataFrame
        :data:`~ctxmatch_lib.evaluation.rows.SWEEP_COLUMNS`; ``time_s`` as measured when the row was computed.
    """
    known = {"gt_method", "gt_threshold", "model_threshold", "filter_params", "seed", "matchers", "estimator", "runs"}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise TypeError(f"evaluate_cached got unexpected arguments {unknown}; known: {sorted(known)}")
    filters = resolve_filters(filters)
    blob_cfgs = resolve_blobs(list(blobs) if not isinstance(blobs, str) else blobs)
    units = plan_units(list(pairs), features=list(features) if not isinstance(features, str) else features,
                       blobs=blob_cfgs, filters=filters, models=models, max_keypoints=max_keypoints,
                       salt=None if cache else "", **kwargs)  # the code's digest keys the cache alone
    return run_units(units, cache_dir=cache_dir if cache else False, progress=progress, desc="evaluate",
                     n_jobs=n_jobs)
