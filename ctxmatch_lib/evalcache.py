"""Cached evaluation runs for the report notebooks (Fig. 7 ``pr_plot``, ``inl_plot``, Tables 1-3).

A thin layer over :func:`ctxmatch_lib.pipeline.evaluate_pair`: one Parquet file of result rows per (pair,
feature setup, evaluation settings, library source), so that the notebooks sharing one configuration
compute it once and every rerun only reads. The key includes a digest of the library source that produces
the numbers (everything except ``plots``, ``cli`` and the report modules), so editing a filter
invalidates its results instead of serving stale ones. Files are written to a temporary name and moved
into place, so an interrupted run leaves no half-written entry.

It also registers the two DTM stages as separate filters, ``dtm1`` (DTM1 only) and ``dtm2`` (DTM1 +
DTM2, the same as ``dtm``), so that Tables 1-3 can list both as the paper does.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from ._paths import atomic_path

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

_RESULTS_FORMAT = 1


def register_dtm_stages() -> None:
    """Register ``dtm1`` (``stages=1``) and ``dtm2`` (``stages=2``) in :data:`~ctxmatch_lib.filters.FILTERS`."""
    from .dtm import dtm_filter
    from .filters import FILTERS, register_filter

    for name, stages in (("dtm1", 1), ("dtm2", 2)):
        if name not in FILTERS:
            register_filter(name, functools.partial(dtm_filter, stages=stages))


def resolve_filters(filters="all") -> tuple[str, ...]:
    """Filter names to evaluate.

    ``"all"`` is every registered filter, with ``dtm`` replaced by its two stages ``dtm1`` and ``dtm2``, in
    the order of the paper's tables (:data:`PAPER_FILTER_ORDER`), then any others alphabetically. A list is
    validated and returned as given.

    Examples
    --------
    >>> resolve_filters(["th", "dtm2"])
    ('th', 'dtm2')
    """
    from .filters import FILTERS
    from .pipeline import check_filters

    register_dtm_stages()
    if isinstance(filters, str) and filters == "all":
        names = [n for n in FILTERS if n != "dtm"]
        rank = {n: i for i, n in enumerate(PAPER_FILTER_ORDER)}
        return tuple(sorted(names, key=lambda n: (rank.get(n, len(rank)), n)))
    if isinstance(filters, str):
        filters = [filters]
    return check_filters(filters)


def select_pairs(dataset, *, step: int = 1, kinds: Sequence[str] | None = None,
                 pair_ids: Sequence[str] | None = None) -> list:
    """A subset of the pairs of ``dataset``: a :class:`~ctxmatch_lib.datasets.Dataset`, a list of pairs, a
    registered name or folder (:func:`~ctxmatch_lib.datasets.load_dataset`), or a list of names (their pairs
    concatenated, e.g. ``["planar", "nonplanar"]``).

    ``pair_ids`` picks pairs by id (in that order; unknown ids raise ``ValueError``); otherwise every
    ``step``-th pair of each kind (in dataset order), restricted to ``kinds`` when given.

    Examples
    --------
    >>> [p.pair_id for p in select_pairs("embedded", step=5, kinds=["planar"])]
    ['planar/poster/1-2', 'planar/lab/1-2', 'planar/hubble/1-2']
    """
    from .datasets import load_dataset

    if isinstance(dataset, (str, os.PathLike)):
        pairs = list(load_dataset(dataset))
    else:
        items = list(dataset)
        if items and all(isinstance(d, (str, os.PathLike)) for d in items):
            pairs = [p for d in items for p in load_dataset(d)]
        else:
            pairs = items
    if pair_ids is not None:
        by_id = {p.pair_id: p for p in pairs}
        missing = [i for i in pair_ids if i not in by_id]
        if missing:
            raise ValueError(f"pair_ids not in the dataset: {missing}; known: {sorted(by_id)[:10]} ...")
        return [by_id[i] for i in pair_ids]
    if step < 1:
        raise ValueError(f"step must be >= 1, got {step}")
    out, seen = [], {}
    for p in pairs:
        if kinds is not None and p.kind not in kinds:
            continue
        k = seen.get(p.kind, 0)
        seen[p.kind] = k + 1
        if k % step == 0:
            out.append(p)
    return out


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-1 of the library source files that produce evaluation numbers (all of ``ctxmatch_lib`` but
    ``plots/``, ``cli/``, ``report.py`` and this module)."""
    root = Path(__file__).resolve().parent
    skip = {root / "report.py", root / "evalcache.py"}
    h = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if path in skip or rel.parts[0] in ("plots", "cli"):
            continue
        h.update(str(rel).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _feature_config(features):
    from .features import FEATURE_PRESETS, FeatureConfig

    if isinstance(features, FeatureConfig):
        return repr(features), features
    if features not in FEATURE_PRESETS:
        raise ValueError(f"unknown feature preset {features!r}; known: {', '.join(FEATURE_PRESETS)}")
    return features, FEATURE_PRESETS[features]


def _write_atomic(df, path: Path) -> None:
    with atomic_path(path) as tmp:
        df.to_parquet(tmp, index=False)


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
    """Evaluate ``pairs`` under every feature setup, reading and writing a per-pair result cache.

    Parameters
    ----------
    pairs : iterable of Pair
        E.g. from :func:`select_pairs`.
    features : sequence of str or FeatureConfig
        Feature setups (names of :data:`~ctxmatch_lib.features.FEATURE_PRESETS`); results get a
        ``features`` column with the name.
    blobs, models, kwargs
        As :func:`ctxmatch_lib.pipeline.evaluate_pair` (``gt_method``, ``gt_threshold``, ``seed``, ...).
    filters : "all" or sequence of str
        See :func:`resolve_filters`.
    cache : bool
        Read and write the cache (``False``: always recompute, write nothing).
    cache_dir : path, optional
        Default ``ctxmatch_lib._paths.cache_dir("results")``.
    progress : bool
        A tqdm bar over (feature setup, pair).

    Returns
    -------
    pandas.DataFrame
        The pipeline's rows (:data:`~ctxmatch_lib.pipeline.ROW_COLUMNS`) plus ``features``; ``time_s`` is
        the time measured when the row was computed, possibly by an earlier run.
    """
    import pandas as pd
    from tqdm import tqdm

    from ._paths import cache_dir as default_cache_dir
    from .pipeline import ROW_COLUMNS, check_models, evaluate_pair, resolve_blobs

    filters = resolve_filters(filters)
    models = check_models(models)
    blob_cfgs = resolve_blobs(list(blobs) if not isinstance(blobs, str) else blobs)
    feature_setups = [_feature_config(f) for f in ([features] if isinstance(features, str) else features)]
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir("results")
    settings = {
        "format": _RESULTS_FORMAT, "source": source_digest(), "filters": list(filters), "models": list(models),
        "blobs": {k: v.kwargs() for k, v in blob_cfgs.items()},
        "kwargs": {k: kwargs[k] for k in sorted(kwargs)},
    }
    jobs = [(name, cfg, pair) for name, cfg in feature_setups for pair in pairs]
    frames = []
    for name, cfg, pair in tqdm(jobs, desc="evaluate", unit="pair", disable=not progress):
        key_src = json.dumps({**settings, "features": cfg.key() if hasattr(cfg, "key") else repr(cfg),
                              "dataset": pair.dataset, "pair": pair.pair_id,
                              "images": [str(pair.image1), str(pair.image2)]}, sort_keys=True, default=str)
        path = folder / f"{hashlib.sha1(key_src.encode()).hexdigest()}.parquet"
        if cache and path.exists():
            frames.append(pd.read_parquet(path))
            continue
        ev = evaluate_pair(pair, features=cfg, blobs=blob_cfgs, filters=filters, models=models, **kwargs)
        df = pd.DataFrame(ev.rows, columns=list(ROW_COLUMNS)).assign(features=name)
        if cache:
            folder.mkdir(parents=True, exist_ok=True)
            _write_atomic(df, path)
        frames.append(df)
    if not frames:
        return pd.DataFrame(columns=[*ROW_COLUMNS, "features"])
    return pd.concat(frames, ignore_index=True)
