"""Cached evaluation runs for the report notebooks (Fig. 7 ``pr_plot``, ``inl_plot``, Tables 1-3).

A thin layer over the one evaluation engine (:func:`ctxmatch_lib.sweep.run_units`, shared with ``ctxmatch
eval`` and ``ctxmatch sweep``): one Parquet part of result rows per (pair, feature setup, evaluation
settings), so that the notebooks sharing one configuration compute it once and every rerun only reads,
and a run killed half-way resumes. The part's key hashes the pair's images and ground truth and every
setting; it also includes a digest of the library source that produces the numbers (everything except
``plots``, ``cli`` and the report modules), so editing a filter invalidates its results instead of
serving stale ones.

``dtm1`` (DTM1 only) and ``dtm2`` (DTM1 + DTM2, the same as ``dtm``) are filter names everywhere
(:func:`ctxmatch_lib.pipeline.register_dtm_stages`), so that Tables 1-3 can list both as the paper does.
"""

from __future__ import annotations

from collections.abc import Iterable

from .pipeline import register_dtm_stages
from .sweep import select_pairs, source_digest

__all__ = [
    "PAPER_FILTER_ORDER",
    "register_dtm_stages",
    "resolve_filters",
    "select_pairs",
    "source_digest",
    "evaluate_cached",
]

#: Filters in the row order of the paper's Tables 1-3 (those not implemented here are skipped).
PAPER_FILTER_ORDER = ("th", "dtm1", "dtm2", "lmr", "lpm", "glpm", "gms", "vfc", "llt", "rfm_scan", "adalam",
                      "oanet", "acne", "pfm", "pgm", "scv", "bm")


def resolve_filters(filters="all") -> tuple[str, ...]:
    """Filter names to evaluate.

    ``"all"`` is every registered filter, with ``dtm`` replaced by its two stages ``dtm1`` and ``dtm2``, in
    the order of the paper's tables (:data:`PAPER_FILTER_ORDER`), then any others alphabetically; the learned
    filters (``oanet``, ``acne``) only when torch is installed. A list is validated and returned as given.

    Examples
    --------
    >>> resolve_filters(["th", "dtm2"])
    ('th', 'dtm2')
    """
    from .filters import FILTERS
    from .pipeline import check_filters

    register_dtm_stages()
    if isinstance(filters, str) and filters == "all":
        from .filters.learned import LEARNED_FILTERS, torch_available

        # The learned filters need the optional torch; without it "all" means every filter that can run.
        names = [n for n in FILTERS if n != "dtm" and (torch_available() or n not in LEARNED_FILTERS)]
        rank = {n: i for i, n in enumerate(PAPER_FILTER_ORDER)}
        return tuple(sorted(names, key=lambda n: (rank.get(n, len(rank)), n)))
    return check_filters(filters)


def evaluate_cached(
    pairs: Iterable,
    *,
    features=("sift-rootsift",),
    blobs=("paper-best", "baseline"),
    filters="all",
    models=("none", "1sac"),
    cache: bool = True,
    cache_dir=None,
    progress: bool = False,
    **kwargs,
):
    """Evaluate ``pairs`` under every feature setup, reading and writing the evaluation cache.

    Parameters
    ----------
    pairs : iterable of Pair
        E.g. from :func:`select_pairs`.
    features : sequence of str or FeatureConfig
        Feature setups (names of :data:`~ctxmatch_lib.features.FEATURE_PRESETS`); results get a
        ``features`` column with the name.
    blobs, models, kwargs
        As :func:`ctxmatch_lib.pipeline.evaluate_pair` (``gt_method``, ``gt_threshold``,
        ``model_threshold``, ``filter_params``, ``seed``); the ``blob`` column holds the preset names.
    filters : "all" or sequence of str
        See :func:`resolve_filters`.
    cache : bool
        Read and write the cache (``False``: always recompute, write nothing).
    cache_dir : path, optional
        The evaluation cache (default ``ctxmatch_lib._paths.cache_dir("sweep")``, shared with ``ctxmatch
        eval`` and ``ctxmatch sweep``).
    progress : bool
        A tqdm bar over (feature setup, pair), naming the pair in progress.

    Returns
    -------
    pandas.DataFrame
        :data:`ctxmatch_lib.sweep.SWEEP_COLUMNS`, which include the pipeline's
        :data:`~ctxmatch_lib.pipeline.ROW_COLUMNS` and ``features``; ``time_s`` is the time measured when
        the row was computed, possibly by an earlier run. Pairs that could not be evaluated have a
        non-empty ``error`` (and a ``RuntimeWarning``).
    """
    from .pipeline import resolve_blobs
    from .sweep import plan_units, run_units

    known = {"gt_method", "gt_threshold", "model_threshold", "filter_params", "seed"}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise TypeError(f"evaluate_cached got unexpected arguments {unknown}; known: {sorted(known)}")
    filters = resolve_filters(filters)
    blob_cfgs = resolve_blobs(list(blobs) if not isinstance(blobs, str) else blobs)
    units = plan_units(list(pairs), features=list(features) if not isinstance(features, str) else features,
                       blobs=blob_cfgs, filters=filters, models=models, salt=source_digest(), **kwargs)
    return run_units(units, cache_dir=cache_dir if cache else False, progress=progress, desc="evaluate")
