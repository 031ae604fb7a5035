"""The engine's entry points: on a grid (:func:`run_sweep`, ``ctxmatch sweep``) and on named presets
(:func:`evaluate_cached`, the report notebooks; ``ctxmatch eval`` plans with
:func:`~ctxmatch_lib.evaluation.plan.plan_sweep` directly), and the check of an output file.

All of them plan units with :mod:`~ctxmatch_lib.evaluation.plan` and run them with
:func:`~ctxmatch_lib.evaluation.run.run_units`, so the same settings give the same unit keys, and each
reuses what the others computed.
"""

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
    """Check, before any work, that ``path`` can be written: the right suffix, then
    :func:`ctxmatch_lib.cache.check_writable` (not a folder; its first existing ancestor a writable folder,
    missing folders being created when it is written).

    ``name`` is what the error calls it (``"--out"`` on the command line). Returns the path.

    Raises
    ------
    ValueError
        Naming ``name``, the path and the reason.
    """
    if suffix and Path(path).suffix.lower() != suffix:
        raise ValueError(f"{name} must end with {suffix}, got {path}")
    return check_writable(path, name)


def run_sweep(datasets="embedded", *, features="sift-rootsift", blobs="grid", filters=(), models=("none",),
              pairs=None, kinds=None, gt_method: str = "D", gt_threshold: float = GT_THRESHOLD_PX,
              model_threshold: float = 15.0, filter_params: Mapping[str, dict] | None = None, seed: int = 0,
              max_keypoints: int | str | None = None, n_jobs: int = 1, dask=None, cache_dir=None,
              feature_cache_dir=None, out=None, progress: bool = True, data_root=None, recompute: bool = False,
              matchers=(), estimator=None):
    """Run (or resume) a sweep and return its rows as a ``pandas.DataFrame`` (:data:`SWEEP_COLUMNS`).

    Parameters
    ----------
    datasets : str or list of str
        Registered dataset names or custom folders (``"embedded"``, ``"planar,nonplanar"``, ...).
    features : str, FeatureConfig, list or dict
        Detector+descriptor configurations (:func:`~ctxmatch_lib.evaluation.plan.resolve_feature_configs`).
    blobs : str, BlobConfig or list
        ``"grid"`` (the 2430 setups of Sec. 5.2), preset names or configs (:func:`~ctxmatch_lib.evaluation.plan.resolve_blob_configs`).
    filters : sequence of str
        Registered filters run on every setup's candidates (the unfiltered candidates are always the
        method ``"blob"``); ``filter_params`` gives extra keyword arguments per filter.
    models : sequence of str
        Model steps (``"none"``, ``"1sac"``, ``"ransac"``, ``"prosac"``, ``"magsac"``) after each method; every
        row with a model carries its accuracy (:data:`~ctxmatch_lib.evaluation.rows.GEOMETRY_COLUMNS`).
    matchers : sequence of str
        Alternative matchers evaluated as methods beside the blob candidates and the filters
        (``"opencv_ratio"``, ``"opencv_mnn"``: :mod:`ctxmatch_lib.opencv_matchers`).
    estimator : dict, optional
        USAC overrides of the robust model steps (``threshold``, ``confidence``, ``max_iters``).
    max_keypoints : int or str, optional
        Override the keypoint cap of every feature configuration: an integer (0: none; small values for quick
        runs) or a budget name of :data:`~ctxmatch_lib.features.KEYPOINT_BUDGETS` (``"paper"``).
    pairs : None, int or list of str
        Pair subset (:func:`~ctxmatch_lib.evaluation.plan.select_pairs`): ``N`` evenly spread pairs, or pair ids; ``kinds`` keeps only
        some pair kinds.
    gt_method, gt_threshold, model_threshold, seed
        As in :func:`ctxmatch_lib.pipeline.evaluate_pair`.
    n_jobs : int
        Local worker processes (joblib, loky backend); ``1`` runs in this process, ``-1`` uses every core.
    dask : str or distributed.Client, optional
        Run the units on a Dask cluster instead: a scheduler address (``"tcp://host:8786"``) or a client.
        Workers must see the data and image paths the driver sees; each worker keeps its own caches.
    cache_dir : path, optional
        The sweep cache (default ``ctxmatch_lib.cache.cache_dir("sweep")``); ``feature_cache_dir`` the
        feature cache (default: that of :mod:`ctxmatch_lib.features`).
    out : path, optional
        Also write the table to this Parquet file (atomically), with the sweep settings as metadata.
    progress : bool
        A tqdm bar over the units, with ETA, on stderr; it names the pair in progress.
    recompute : bool
        Ignore (and overwrite) the existing result parts of this sweep.

    Returns
    -------
    pandas.DataFrame
        One row per (pair, features, blob setup, method, model), in the sweep's order whatever the order
        in which units finished: identical for serial, joblib and Dask runs, and for a resumed run. A pair
        that could not be evaluated has rows with NaN metrics and a non-empty ``error`` (see
        :func:`~ctxmatch_lib.evaluation.run.run_units`).
    """
    check_runner(n_jobs, dask)
    if out is not None:
        check_output(out, "out")
    units = plan_sweep(datasets, features=features, blobs=blobs, filters=filters, models=models,
                       pairs=pairs, kinds=kinds, gt_method=gt_method, gt_threshold=gt_threshold,
                       model_threshold=model_threshold, filter_params=filter_params, seed=seed,
                       max_keypoints=max_keypoints, data_root=data_root, matchers=matchers, estimator=estimator)
    df = run_units(units, cache_dir=cache_dir, feature_cache_dir=feature_cache_dir, n_jobs=n_jobs, dask=dask,
                   progress=progress, recompute=recompute, desc="ctxmatch sweep")
    if out is not None:
        meta = {"datasets": datasets, "features": {u.features_name: u.features.key() for u in units},
                "blobs": len(units[0].blobs), "filters": list(units[0].filters), "models": list(units[0].models),
                "pairs": len({(u.dataset, u.pair.pair_id) for u in units}), "gt_method": gt_method,
                "gt_threshold": gt_threshold, "model_threshold": model_threshold, "seed": seed,
                "matchers": list(units[0].matchers), "estimator": dict(units[0].estimator), "format": FORMAT}
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
        Feature setups (names of :data:`~ctxmatch_lib.features.FEATURE_PRESETS`); results get a
        ``features`` column with the name.
    blobs, models, kwargs
        As :func:`ctxmatch_lib.pipeline.evaluate_pair` (``gt_method``, ``gt_threshold``,
        ``model_threshold``, ``filter_params``, ``seed``) and :func:`run_sweep` (``matchers``, ``estimator``);
        the ``blob`` column holds the preset names.
    filters : "all" or sequence of str
        See :func:`~ctxmatch_lib.evaluation.steps.resolve_filters`.
    max_keypoints : int or str, optional
        Keypoint cap of every feature setup: an integer (0: none) or a budget name of
        :data:`~ctxmatch_lib.features.KEYPOINT_BUDGETS` (``"paper"``: the calibrated budget of the paper-scale
        runs); ``None``: each preset's own.
    cache : bool
        Read and write the cache (``False``: always recompute, write nothing).
    cache_dir : path, optional
        The evaluation cache (default ``ctxmatch_lib.cache.cache_dir("sweep")``, shared with ``ctxmatch
        eval`` and ``ctxmatch sweep``).
    progress : bool
        A tqdm bar over (feature setup, pair), naming the pair in progress.
    n_jobs : int
        Worker processes (joblib; -1: all cores). The rows do not depend on it.

    Returns
    -------
    pandas.DataFrame
        :data:`ctxmatch_lib.evaluation.rows.SWEEP_COLUMNS`, which include the pipeline's
        :data:`~ctxmatch_lib.pipeline.ROW_COLUMNS` and ``features``; ``time_s`` is the time measured when
        the row was computed, possibly by an earlier run. Pairs that could not be evaluated have a
        non-empty ``error`` (and a ``RuntimeWarning``).
    """
    known = {"gt_method", "gt_threshold", "model_threshold", "filter_params", "seed", "matchers", "estimator"}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise TypeError(f"evaluate_cached got unexpected arguments {unknown}; known: {sorted(known)}")
    filters = resolve_filters(filters)
    blob_cfgs = resolve_blobs(list(blobs) if not isinstance(blobs, str) else blobs)
    units = plan_units(list(pairs), features=list(features) if not isinstance(features, str) else features,
                       blobs=blob_cfgs, filters=filters, models=models, max_keypoints=max_keypoints, **kwargs)
    return run_units(units, cache_dir=cache_dir if cache else False, progress=progress, desc="evaluate",
                     n_jobs=n_jobs)
