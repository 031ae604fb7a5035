"""Planning the engine's work: settings checked once, pairs selected, work units keyed.

A unit is one (dataset, pair, feature configuration) with every blob setup, filter and model; its ``key``
(:class:`SweepUnit`) lets every front end asking for the same numbers share one cached part.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..blob import BLOB_PRESETS, BlobConfig, blob_grid
from ..datasets import load_dataset
from ..datasets.base import Pair
from ..features import FEATURE_PRESETS, FeatureConfig, keypoint_budget
from ..geometry import ROBUST_STEPS
from ..groundtruth import GT_METHODS, GT_THRESHOLD_PX
from .cache import FORMAT, digest, pair_digest, source_digest
from .steps import check_estimator, check_matchers, check_models, named_configs, resolve_filters

__all__ = ["SweepUnit", "resolve_feature_configs", "resolve_blob_configs", "select_pairs", "check_settings",
           "plan_units", "plan_sweep", "keyed"]


def resolve_feature_configs(features) -> dict[str, FeatureConfig]:
    """``{name: FeatureConfig}`` by the rule of :func:`~ctxmatch_lib.evaluation.steps.resolve_blobs`; a bare
    config is named by the preset it equals, else by its ``key()``."""
    def default_name(f: FeatureConfig) -> str:
        return next((k for k, v in FEATURE_PRESETS.items() if v == f), None) or f.key()

    return named_configs(features, FEATURE_PRESETS, FeatureConfig, argument="features", kind="feature",
                         noun="feature configuration", default_name=default_name)


def resolve_blob_configs(blobs) -> list[BlobConfig]:
    """Blob setups of a sweep: ``"grid"`` (the 2430 of Sec. 5.2), preset names, ``BlobConfig`` objects,
    or a list mixing them. Duplicates are dropped (first occurrence kept).

    Examples
    --------
    >>> len(resolve_blob_configs("grid")), len(resolve_blob_configs(["paper-best", "baseline"]))
    (2430, 2)
    """
    if isinstance(blobs, (str, BlobConfig)):
        blobs = [blobs]
    out: list[BlobConfig] = []
    for b in blobs:
        if isinstance(b, str):
            if b == "grid":
                out.extend(blob_grid())
            elif b in BLOB_PRESETS:
                out.append(BLOB_PRESETS[b])
            else:
                raise ValueError(f"unknown blob setup {b!r}; use 'grid' or a preset: {', '.join(BLOB_PRESETS)}")
        elif isinstance(b, BlobConfig):
            out.append(b)
        else:
            raise ValueError(f"blobs must hold 'grid', preset names or BlobConfig, got {type(b).__name__}")
    out = list(dict.fromkeys(out))
    if not out:
        raise ValueError("blobs must name at least one blob setup")
    return out


def select_pairs(dataset, select=None, *, step: int = 1, kinds=None, pair_ids: Sequence[str] | None = None) \
        -> list[Pair]:
    """A reproducible subset of the pairs of ``dataset`` (``ctxmatch eval``, ``ctxmatch sweep``, the notebooks).

    Parameters
    ----------
    dataset : Dataset, sequence of Pair, str or list of str
        Pairs, or dataset names / custom folders (:func:`~ctxmatch_lib.datasets.load_dataset`), concatenated.
    select : None, int or sequence of str
        ``None``: all; ``N``: ``N`` pairs evenly spread, in list order; strings: those pair ids.
    step, kinds, pair_ids
        Every ``step``-th pair of each kind; only these kinds (applied first); as strings in ``select``.

    Raises
    ------
    ValueError
        An unknown pair id (the message lists the valid ids closest to it), a bad ``step`` or ``select``.

    Examples
    --------
    >>> [p.pair_id for p in select_pairs("embedded", step=5, kinds=["planar"])]
    ['planar/poster/1-2', 'planar/lab/1-2', 'planar/hubble/1-2']
    """
    import os

    if isinstance(dataset, (str, os.PathLike)):
        pairs = list(load_dataset(dataset))
    else:
        items = list(dataset)
        if items and all(isinstance(d, (str, os.PathLike)) for d in items):
            pairs = [p for d in items for p in load_dataset(d)]
        else:
            pairs = items
    if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 1:
        raise ValueError(f"step must be >= 1, got {step!r}")
    if pair_ids is not None:
        if select is not None:
            raise ValueError("give either select or pair_ids, not both")
        select = list(pair_ids)
    if kinds is not None:
        kinds = {kinds} if isinstance(kinds, str) else set(kinds)
        pairs = [p for p in pairs if p.kind in kinds]
    if isinstance(select, str) or (select is not None and not isinstance(select, (int, np.integer))):
        wanted = [select] if isinstance(select, str) else list(select)
        by_id = {p.pair_id: p for p in pairs}
        unknown = [w for w in wanted if w not in by_id]
        if unknown:
            raise ValueError(f"unknown pair ids (pair_ids): {', '.join(map(repr, unknown[:5]))}; "
                             + _valid_ids(by_id, str(unknown[0])))
        return [by_id[w] for w in wanted]
    if step > 1:
        out, seen = [], {}
        for p in pairs:
            k = seen.get(p.kind, 0)
            seen[p.kind] = k + 1
            if k % step == 0:
                out.append(p)
        pairs = out
    if select is None:
        return pairs
    if isinstance(select, bool) or select < 1:
        raise ValueError(f"pairs must be a positive number of pairs, got {select}")
    if select >= len(pairs):
        return pairs
    idx = np.unique(np.round(np.linspace(0, len(pairs) - 1, int(select))).astype(int))
    return [pairs[i] for i in idx]


def _valid_ids(ids, wanted: str, shown: int = 10) -> str:
    """Some of the valid pair ids for an error message: those closest to ``wanted`` first."""
    import difflib

    if not ids:
        return "the selection holds no pair"
    near = difflib.get_close_matches(wanted, sorted(ids), n=shown, cutoff=0)
    more = f", ... ({len(ids)} in all)" if len(ids) > len(near) else ""
    return f"valid ids, the closest first: {', '.join(near)}{more}"


@dataclass(frozen=True)
class SweepUnit:
    """One work unit: every blob setup, filter and model of a sweep on one pair with one feature config.

    ``key`` (:func:`unit_key`) names its part file; ``features_name`` and ``blob_names`` are applied when the
    rows are read, so they are not in it. ``salt`` (:func:`~ctxmatch_lib.evaluation.cache.source_digest`)
    joins every cache key; ``estimator``: :func:`~ctxmatch_lib.evaluation.steps.check_estimator`'s pairs.
    """

    dataset: str
    pair: Pair
    features_name: str
    features: FeatureConfig
    blobs: tuple
    filters: tuple = ()
    models: tuple = ("none",)
    filter_params: tuple = ()  # ((name, json-of-params), ...)
    gt_method: str = "D"
    gt_threshold: float = GT_THRESHOLD_PX
    model_threshold: float = 15.0
    seed: int = 0
    key: str = field(default="", compare=False)
    blob_names: tuple = field(default=(), compare=False)
    salt: str = ""
    matchers: tuple = ()
    estimator: tuple = ()  # ((key, value), ...), sorted
    runs: int = 1  # seeded runs of each random model step (ROBUST_STEPS) per method

    def label(self) -> str:
        where = self.dataset or self.pair.dataset
        return f"{where + '/' if where else ''}{self.pair.pair_id} [{self.features_name}]"


def unit_key(u: SweepUnit, pair_hash: str) -> str:
    """The name of the unit's part file: a hash of everything its rows depend on (names aside)."""
    # The dataset as the rows show it: planned from a name or from its pairs, the key is the same.
    return digest(
        FORMAT, u.pair.dataset or u.dataset, u.pair.pair_id, pair_hash, u.features.key(),
        [c.kwargs() for c in u.blobs], u.filters, u.models, u.filter_params, u.gt_method, float(u.gt_threshold),
        float(u.model_threshold), int(u.seed), u.salt, u.matchers, u.estimator,
        int(u.runs) if any(m in ROBUST_STEPS for m in u.models) else 1,  # runs repeat the random steps only
    )


def check_settings(*, features, blobs, filters, models, gt_method, gt_threshold, model_threshold,
                    filter_params, seed, max_keypoints, matchers=(), estimator=None, runs=1) -> dict:
    """Validate every setting of an evaluation before any work; returns them resolved."""
    if gt_method not in GT_METHODS:
        raise ValueError(f"gt_method must be one of {GT_METHODS}, got {gt_method!r}")
    if gt_method in ("B", "C") and gt_threshold != GT_THRESHOLD_PX:
        # B and C have their own fixed thresholds (overlap error 50 %, C's centre 30 px; Sec. 5.1).
        raise ValueError(f"gt_threshold applies to methods D and A only; method {gt_method} uses its own "
                         f"thresholds (got gt_threshold={gt_threshold!r})")
    for name, value in (("gt_threshold", gt_threshold), ("model_threshold", model_threshold)):
        if isinstance(value, bool) or not (isinstance(value, (int, float, np.number)) and math.isfinite(value)
                                           and value > 0):
            raise ValueError(f"{name} must be a positive number of pixels, got {value!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 1:
        raise ValueError(f"runs must be a positive integer, got {runs!r}")
    max_keypoints = keypoint_budget(max_keypoints)  # a budget name ("paper", "dense") or an int
    feats = resolve_feature_configs(features)
    if max_keypoints is not None:
        feats = {k: replace(v, max_keypoints=int(max_keypoints)) for k, v in feats.items()}
    if isinstance(blobs, Mapping):
        names, blob_cfgs = tuple(blobs), tuple(blobs.values())
        for b in blob_cfgs:
            if not isinstance(b, BlobConfig):
                raise ValueError(f"blobs must map names to BlobConfig, got {type(b).__name__}")
    else:
        blob_cfgs, names = tuple(resolve_blob_configs(blobs)), ()
    # "all" is every filter that can run here (resolve_filters); a list is checked as given.
    filters = resolve_filters(filters if isinstance(filters, str) else tuple(filters))
    models = check_models((models,) if isinstance(models, str) else tuple(models))
    params = dict(filter_params or {})
    unknown = sorted(set(params) - set(filters))
    if unknown:
        raise ValueError(f"filter_params names filters not in the sweep: {', '.join(unknown)}")
    fparams = tuple((k, json.dumps(params[k], sort_keys=True)) for k in filters if k in params)
    return dict(feats=feats, blobs=blob_cfgs, blob_names=names, filters=filters, models=models, fparams=fparams,
                gt_method=gt_method, gt_threshold=float(gt_threshold), model_threshold=float(model_threshold),
                seed=int(seed), matchers=check_matchers(matchers), estimator=check_estimator(estimator),
                runs=int(runs))


def _units(dataset_name, pairs, st, salt: str | None) -> list[SweepUnit]:
    # A unit's key follows the code it runs: its filters' code, not the others'.
    salt = source_digest(tuple(st["filters"])) if salt is None else salt
    return [SweepUnit(str(dataset_name), pair, fname, fcfg, st["blobs"], st["filters"], st["models"], st["fparams"],
                      st["gt_method"], st["gt_threshold"], st["model_threshold"], st["seed"],
                      blob_names=st["blob_names"], salt=salt, matchers=st["matchers"], estimator=st["estimator"],
                      runs=st["runs"])
            for fname, fcfg in st["feats"].items() for pair in pairs]


def plan_units(pairs, *, features="sift-rootsift", blobs="paper-best", filters=(), models=("none",),
               gt_method: str = "D", gt_threshold: float = GT_THRESHOLD_PX, model_threshold: float = 15.0,
               filter_params: Mapping[str, dict] | None = None, seed: int = 0,
               max_keypoints: int | None = None, salt: str | None = None, matchers=(),
               estimator: Mapping | None = None, runs: int = 1) -> list[SweepUnit]:
    """The work units evaluating ``pairs`` (a list of :class:`Pair`), in table order (features, pair).

    Arguments as :func:`~ctxmatch_lib.evaluation.frontends.run_sweep`, validated before any work; ``blobs``
    may be a dict name -> ``BlobConfig``; ``salt``: see :class:`SweepUnit`.
    """
    st = check_settings(features=features, blobs=blobs, filters=filters, models=models, gt_method=gt_method,
                         gt_threshold=gt_threshold, model_threshold=model_threshold, filter_params=filter_params,
                         seed=seed, max_keypoints=max_keypoints, matchers=matchers, estimator=estimator,
                         runs=runs)
    pairs = list(pairs)
    for p in pairs:
        if not isinstance(p, Pair):
            raise ValueError(f"pairs must hold Pair objects, got {type(p).__name__}")
    return _units("", pairs, st, salt)


def plan_sweep(datasets="embedded", *, features="sift-rootsift", blobs="grid", filters=(), models=("none",),
               pairs=None, kinds=None, gt_method: str = "D", gt_threshold: float = GT_THRESHOLD_PX,
               model_threshold: float = 15.0, filter_params: Mapping[str, dict] | None = None, seed: int = 0,
               max_keypoints: int | None = None, data_root=None, salt: str | None = None, matchers=(),
               estimator: Mapping | None = None, runs: int = 1) -> list[SweepUnit]:
    """The work units of a sweep, in table order (dataset, features, pair); arguments as
    :func:`~ctxmatch_lib.evaluation.frontends.run_sweep` and :func:`plan_units`, validated before any work."""
    st = check_settings(features=features, blobs=blobs, filters=filters, models=models, gt_method=gt_method,
                         gt_threshold=gt_threshold, model_threshold=model_threshold, filter_params=filter_params,
                         seed=seed, max_keypoints=max_keypoints, matchers=matchers, estimator=estimator,
                         runs=runs)
    if isinstance(datasets, str):
        datasets = [d.strip() for d in datasets.split(",") if d.strip()]
    datasets = list(datasets)
    if not datasets:
        raise ValueError("datasets must name at least one dataset")
    units = []
    for ds_name in datasets:
        ds = load_dataset(ds_name, root=data_root)
        chosen = select_pairs(ds.pairs, pairs, kinds=kinds)
        if not chosen:
            raise ValueError(f"no pairs of dataset {ds_name!r} left after selecting pairs={pairs!r}, kinds={kinds!r}")
        units.extend(_units(ds_name, chosen, st, salt))
    return units


def keyed(units: list[SweepUnit]) -> list[SweepUnit]:
    """The units with their ``key`` set (the pair's files are read and hashed once per pair)."""
    digests: dict = {}
    out = []
    for u in units:
        pid = (u.pair.image1, u.pair.image2, u.pair.pair_id, u.pair.dataset)
        if pid not in digests:
            try:
                digests[pid] = pair_digest(u.pair)
            except OSError as exc:
                # The unit runs and reports the unreadable file; its part is never written.
                digests[pid] = f"unreadable:{exc}"
        out.append(replace(u, key=unit_key(u, digests[pid])))
    return out
