"""Experiment sweeps: dataset × features × blob setup × filter × model, cached on disk and resumable.

The blob-matching grid of Sec. 5.2 (:func:`~ctxmatch_lib.blob.blob_grid`, 2430 setups) is evaluated by
exploiting its structure: on each image pair one :class:`~ctxmatch_lib.blob.BlobContext` serves every
setup, the candidate set G is built once per (f, ∩/∪, f') (27 sets), the NNR-like ratios (a, b) once per
(t_o, D) on each set, and the five combinations W(a, b) reuse them. Each setup's candidates are ranked by
their score and the ranking's average precision (:func:`~ctxmatch_lib.metrics.average_precision`, with
method-D labels) is one row: ``ap`` against the setup's own correct candidates, ``ap_star`` against the
correct candidates of all setups of the sweep on the pair (the recall* reference). The mean of ``ap_star``
over pairs is the mAP of the heat map of Fig. 5 (:func:`blob_map`).

This is the one evaluation engine of the package: ``ctxmatch sweep`` (:func:`run_sweep`), ``ctxmatch eval``
and :func:`ctxmatch_lib.pipeline.evaluate_dataset`, and the report notebooks
(:func:`ctxmatch_lib.evalcache.evaluate_cached`) all plan units (:func:`plan_sweep`, :func:`plan_units`)
and run them with :func:`run_units`.

Work is split into **units**, one per (dataset, pair, feature configuration), each holding every blob
setup, filter and model of the sweep for that pair. A unit's rows are written as one Parquet *part file*
(temporary name, then ``os.replace``) named by the hash of everything the rows depend on, so

* a run killed at any moment loses at most the units in flight, and rerunning the same sweep skips the
  units whose part exists: no lost and no duplicated rows;
* two sweeps sharing units (the two blob notebooks, the CLI and the benchmark) share their results;
* the final table is the concatenation of the parts in the sweep's own order, whatever order the units
  finished in, so serial, joblib and Dask runs give identical tables;
* nothing is lost to one bad pair: an unreadable image, an image without keypoints, keypoints outside the
  pair's (width, height), or a filter or model step that raises gives that pair (or that method) rows
  with NaN metrics and an ``error`` naming the image and the reason, a ``RuntimeWarning``, and the run
  goes on; such a unit's part is not written, so the next run tries it again.

Cache layout under ``ctxmatch_lib._paths.cache_dir("sweep")`` (features are cached by
:mod:`ctxmatch_lib.features` in its own folder)::

    results/<unit-hash>.parquet      one part per finished unit (rows of one pair)
    candidates/<pair-hash>.npz       candidate sets G (matches, distances) per (f, ∩/∪, f') of a pair
    overlap/<image-hash>.npz         overlap errors of every pair of keypoints of an image whose patches
                                     can overlap (FGINN by overlap looks them up instead of recomputing)
    filters/<hash>.npz               filter masks per blob setup, per (pair, filter, filter parameters)

Keypoints are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._paths import atomic_path, write_parquet_atomic
from ._validation import cumulative_distinct
from .blob import BLOB_PRESETS, BlobConfig, BlobContext, blob_grid, combine_ratios, rank_candidates
from .blob.overlap import ellipse_overlap_error
from .datasets import load_dataset
from .datasets.base import Pair
from .features import FEATURE_PRESETS, FeatureConfig, Features
from .groundtruth import GT_METHODS, GT_THRESHOLD_PX
from .metrics import average_precision, evaluate_matches, normalised_count

__all__ = [
    "SWEEP_COLUMNS",
    "SweepUnit",
    "resolve_features",
    "resolve_blob_configs",
    "select_pairs",
    "plan_units",
    "plan_sweep",
    "run_unit",
    "run_units",
    "run_sweep",
    "source_digest",
    "blob_map",
    "heatmap_matrix",
    "write_parquet_atomic",
]

# Bump when the rows or the cached intermediates change meaning: old parts and caches are then ignored.
_SWEEP_FORMAT = 3

#: Columns of a sweep row, in order. Blob-setup fields are spelled out so results can be grouped by them.
SWEEP_COLUMNS = (
    "dataset", "pair_id", "kind", "features", "blob", "f", "prefilter", "f_prime", "ratio", "t_o", "t_o_kind",
    "combine", "method", "model", "precision", "recall", "recall_star", "ap", "ap_star", "correct",
    "correct_norm", "output", "failure", "empty_output", "time_s", "model_time_s", "n_kpts1", "n_kpts2", "n_candidates",
    "n_gt", "n_gt_star", "gt_method", "error",
)

_INT_COLUMNS = ("f_prime", "correct", "correct_norm", "output", "n_kpts1", "n_kpts2", "n_candidates", "n_gt",
                "n_gt_star")


# ------------------------------------------------------------------------------------------ arguments


def resolve_features(features) -> dict[str, FeatureConfig]:
    """Named feature configurations: a preset name (``"sift-rootsift"``, ``"sift-rootsift-upright"``,
    ``"sift"``), a :class:`FeatureConfig`, a list of them, or a dict name -> config.

    Returns
    -------
    dict of str -> FeatureConfig
        In the given order; a bare config is named by the preset it equals, else by its ``key()``.
    """
    if isinstance(features, (str, FeatureConfig)):
        features = [features]
    items = features.items() if isinstance(features, Mapping) else [(None, f) for f in features]
    out: dict[str, FeatureConfig] = {}
    for name, f in items:
        if isinstance(f, str):
            if f not in FEATURE_PRESETS:
                raise ValueError(f"unknown feature preset {f!r}; known presets: {', '.join(FEATURE_PRESETS)}")
            name, f = name or f, FEATURE_PRESETS[f]
        elif not isinstance(f, FeatureConfig):
            raise ValueError(f"features must hold preset names or FeatureConfig, got {type(f).__name__}")
        else:
            name = name or next((k for k, v in FEATURE_PRESETS.items() if v == f), None)
        out[name or f.key()] = f
    if not out:
        raise ValueError("features must name at least one feature configuration")
    return out


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
    """A reproducible subset of the pairs of ``dataset`` (the one pair selector of ``ctxmatch eval``,
    ``ctxmatch sweep`` and the report notebooks).

    Parameters
    ----------
    dataset : Dataset, sequence of Pair, str or list of str
        Pairs, or a registered dataset name / custom folder (:func:`~ctxmatch_lib.datasets.load_dataset`),
        or a list of names (their pairs concatenated, e.g. ``["planar", "nonplanar"]``).
    select : None, int or sequence of str
        ``None``: all; an int ``N``: ``N`` pairs evenly spread over the list (so every kind and sequence
        of a dataset is represented), in list order; strings: those pair ids, in the given order.
    step : int
        Keep every ``step``-th pair of each kind (in dataset order; the first pair of each kind is kept).
    kinds : str or iterable of str, optional
        Keep only these kinds (``"planar"``, ``"nonplanar"``, ``"depth"``) first.
    pair_ids : sequence of str, optional
        Same as strings in ``select``.

    Returns
    -------
    list of Pair

    Raises
    ------
    ValueError
        Unknown pair ids, ``select`` < 1 or ``step`` < 1.

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
            raise ValueError(f"unknown pair ids (pair_ids): {', '.join(map(str, unknown[:5]))}; "
                             f"known: {', '.join(sorted(by_id)[:10])} ...")
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


def _check_names(filters, models) -> tuple[tuple, tuple]:
    from .pipeline import check_filters, check_models

    return check_filters(filters), check_models(models)


# -------------------------------------------------------------------------------------------- hashing


def _sha1(*parts) -> str:
    h = hashlib.sha1()
    for p in parts:
        if isinstance(p, np.ndarray):
            h.update(repr((p.dtype.str, p.shape)).encode())
            h.update(np.ascontiguousarray(p).tobytes())
        elif isinstance(p, (bytes, bytearray)):
            h.update(p)
        else:
            h.update(repr(p).encode())
        h.update(b"\x00")
    return h.hexdigest()


def _pair_digest(pair: Pair) -> str:
    """What a pair's rows depend on besides the sweep settings: both image files and the ground truth."""
    gt = pair.gt
    fields = [type(gt).__name__]
    for name in ("H", "F", "pts1", "pts2", "flow12", "flow21"):
        value = getattr(gt, name, None)
        fields.append(name if value is None else np.asarray(value))
    return _sha1(Path(pair.image1).read_bytes(), Path(pair.image2).read_bytes(), pair.kind, *fields)


def _features_digest(*feats: Features) -> str:
    # The metric enters only when it is not L2, so the L2 digests (and cached candidate sets) are unchanged.
    extra = [f.metric for f in feats if f.metric != "l2"]
    return _sha1(*[a for f in feats for a in (f.kpts, f.shapes, f.desc)], *extra)


def _blob_record(cfg: BlobConfig) -> dict:
    return {"blob": cfg.label, "f": str(cfg.f), "prefilter": cfg.prefilter, "f_prime": cfg.f_prime,
            "ratio": cfg.ratio, "t_o": np.nan if cfg.t_o is None else float(cfg.t_o), "t_o_kind": cfg.t_o_kind,
            "combine": cfg.combine}


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-1 of the library source files and shipped models that produce evaluation numbers (all of
    ``ctxmatch_lib`` but ``plots/``, ``cli/``, ``report.py`` and ``evalcache.py``)."""
    root = Path(__file__).resolve().parent
    skip = {root / "report.py", root / "evalcache.py"}
    h = hashlib.sha1()
    # Shipped models (LMR's trees, the learned filters' weights) produce numbers too.
    files = [*root.rglob("*.py"), *root.rglob("*.npz"), *root.rglob("*.pt")]
    for path in sorted(files):
        rel = path.relative_to(root)
        if path in skip or rel.parts[0] in ("plots", "cli"):
            continue
        h.update(str(rel).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


# ------------------------------------------------------------------------------------------ disk I/O


def _save_npz(path: Path, arrays: dict) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def _load_npz(path: Path) -> dict | None:
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception:  # a foreign or damaged file is a miss; it is overwritten
        return None

def _sweep_cache(cache_dir) -> Path:
    if cache_dir is None:
        from ._paths import cache_dir as default_cache_dir

        return default_cache_dir("sweep")
    path = Path(cache_dir)
    path.mkdir(parents=True, exist_ok=True)
    return path


# ------------------------------------------------------------------------- FGINN by overlap, tabulated


def _overlap_table(feats: Features, cache: Path | None) -> tuple[np.ndarray, np.ndarray]:
    """Overlap errors of every keypoint pair of one image whose patches may overlap, both orders.

    Returns ``keys`` (sorted, ``p * N + q``) and ``err``; any pair not listed has overlap error exactly 1
    (disjoint bounding circles), as :func:`~ctxmatch_lib.blob.ellipse_overlap_error` returns for it.
    """
    n = len(feats)
    path = None
    if cache is not None:
        path = cache / "overlap" / f"{_sha1(_SWEEP_FORMAT, feats.kpts, feats.shapes)}.npz"
        hit = _load_npz(path)
        if hit is not None:
            return hit["keys"], hit["err"]
    if n < 2:
        keys, err = np.empty(0, np.int64), np.empty(0)
    else:
        from scipy.spatial import cKDTree

        # The Frobenius norm bounds the spectral norm (the bounding radius), so this finds a superset
        # of the pairs ellipse_overlap_error treats as near; it returns exactly 1 for the others.
        r = np.sqrt(np.sum(feats.shapes ** 2, axis=(1, 2)))
        tree = cKDTree(feats.kpts)
        nb = tree.query_ball_point(feats.kpts, 2 * r)
        p = np.repeat(np.arange(n), [len(x) for x in nb])
        q = np.fromiter((j for x in nb for j in x), np.int64, count=len(p))
        # A pair is found from the endpoint with the larger radius, in either order.
        keep = p != q
        p, q = np.minimum(p[keep], q[keep]), np.maximum(p[keep], q[keep])
        d2 = np.sum((feats.kpts[p] - feats.kpts[q]) ** 2, axis=1)
        keep = d2 < (r[p] + r[q]) ** 2
        p, q = p[keep], q[keep]
        pq = np.unique(p * n + q)
        p, q = pq // n, pq % n
        e = ellipse_overlap_error(feats.kpts[p], feats.shapes[p], feats.kpts[q], feats.shapes[q])
        # The error is symmetric (the two one-sided estimates are averaged), so one value serves both orders.
        keys = np.concatenate([p * n + q, q * n + p])
        err = np.concatenate([e, e])
        order = np.argsort(keys)
        keys, err = keys[order], err[order]
    if path is not None:
        _save_npz(path, {"keys": keys, "err": err})
    return keys, err


class _SweepContext(BlobContext):
    """A :class:`BlobContext` whose :meth:`overlap_errors` looks the errors up in per-image tables.

    The overlap error of two keypoints of one image depends neither on the candidate set, nor on the
    ratio, nor on the threshold ``t_o``; the grid asks for it 27 × 9 × 2 times per pair, so it is
    computed once per image (and cached on disk). The values are those of
    :func:`~ctxmatch_lib.blob.ellipse_overlap_error` on the same arguments, so the scores are identical to
    :func:`~ctxmatch_lib.blob.match_context` on a plain context (tested).
    """

    def __init__(self, *args, overlap_tables=None, **kwargs):
        super().__init__(*args, **kwargs)
        self._tables = overlap_tables
        self._last: dict = {}

    def overlap_errors(self, img, other, cand):
        if self._tables is None:
            return super().overlap_errors(img, other, cand)
        other = np.asarray(other, np.int64)
        last = self._last.get(img)
        # The grid asks for the same look-up for every t_o and ratio in a row: reuse the last one.
        if last is not None and last[1].shape == cand.shape and np.array_equal(last[0], other) \
                and np.array_equal(last[1], cand):
            return last[2]
        keys_t, err_t = self._tables[img]
        size = len(self.kpts[img])
        if cand.shape[1] == size and len(keys_t):
            # Whole lines (the rare fallback of second_best): fill each anchor's row from the table.
            lo, hi = np.searchsorted(keys_t, other * size), np.searchsorted(keys_t, (other + 1) * size)
            cnt = hi - lo
            rows = np.repeat(np.arange(len(other)), cnt)
            at = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(lo, cnt)
            full = np.ones((len(other), size))
            full[rows, keys_t[at] % size] = err_t[at]
            err = np.take_along_axis(full, cand, axis=1)
        else:
            keys = other[:, None] * size + cand
            err = np.ones(keys.shape)
            if len(keys_t):
                pos = np.minimum(np.searchsorted(keys_t, keys), len(keys_t) - 1)
                found = keys_t[pos] == keys
                err[found] = err_t[pos[found]]
        self._last[img] = (other, cand.copy(), err)
        return err


# ------------------------------------------------------------------------------------ average precision


def _ranked_ap(rows, cols, lab, scores, den: int, n: int, m: int) -> float:
    """:func:`~ctxmatch_lib.metrics.average_precision` with a precomputed reference size, in O(K log K).

    The same arithmetic in the same order, so the value is bit-identical (tested); ties in ``scores`` keep
    the given order, as there.
    """
    if den == 0:
        return float("nan")
    k = len(lab)
    if k == 0:
        return 0.0
    order = np.argsort(scores, kind="stable")
    lab = lab[order]
    prec = np.cumsum(lab) / np.arange(1, k + 1)
    cnt = np.zeros(k, np.int64)
    if lab.any():
        r, c = rows[order][lab], cols[order][lab]
        cnt[lab] = np.minimum(cumulative_distinct(r), cumulative_distinct(c)).astype(np.int64)
        cnt = np.maximum.accumulate(cnt)
    dn = np.diff(np.r_[0, cnt])
    return float((prec * dn).sum() / den)


# ------------------------------------------------------------------------------------------ one unit


@dataclass(frozen=True)
class SweepUnit:
    """One work unit: every blob setup, filter and model of a sweep on one pair with one feature config.

    ``key`` names its part file; it hashes the pair's images and ground truth and every setting the rows
    depend on. ``blob_names`` (optional, one per blob setup) is what the ``blob`` column shows instead of
    the setup's label (``ctxmatch eval`` and the report notebooks show preset names); it is applied when
    the rows are read, so it is not part of the key and parts are shared whatever the names. ``salt``
    joins the key (``ctxmatch eval`` and the notebooks put :func:`source_digest` there, so that editing
    the library invalidates their rows) and the keys of the cached candidate sets and filter masks.
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

    def label(self) -> str:
        where = self.dataset or self.pair.dataset
        return f"{where + '/' if where else ''}{self.pair.pair_id} [{self.features_name}]"


def _unit_key(u: SweepUnit, pair_digest: str) -> str:
    return _sha1(
        _SWEEP_FORMAT, u.dataset, u.pair.dataset, u.pair.pair_id, pair_digest, u.features_name, u.features.key(),
        [c.kwargs() for c in u.blobs], u.filters, u.models, u.filter_params, u.gt_method, float(u.gt_threshold),
        float(u.model_threshold), int(u.seed), u.salt,
    )


def _candidate_sets(ctx_factory, keys, cache: Path | None, digest: str, salt: str = ""):
    """G per candidate key, with the seconds it took (descriptor distances + the set), from the cache or
    from the context (then cached)."""
    path = cache / "candidates" / f"{_sha1(_SWEEP_FORMAT, digest, salt)}.npz" if cache is not None else None
    stored = (_load_npz(path) if path is not None else None) or {}
    out, added = {}, False
    for key in keys:
        name = "{}_{}_{}".format(*key)
        if f"m_{name}" in stored:
            out[key] = (stored[f"m_{name}"].astype(np.int64), stored[f"d_{name}"], float(stored[f"t_{name}"]))
            continue
        t0 = time.perf_counter()
        ctx, t_ctx = ctx_factory()
        matches, dist = ctx.candidates(*key)
        # The context (all descriptor distances) serves every key; each key's time includes building it,
        # as a standalone blob_matching call would.
        t = time.perf_counter() - t0 + (t_ctx if t_ctx is not None else 0.0)
        out[key] = (matches, dist, t)
        stored[f"m_{name}"] = matches.astype(np.int32)
        stored[f"d_{name}"] = dist
        stored[f"t_{name}"] = np.float64(t)
        added = True
    if added and path is not None:
        _save_npz(path, stored)
    return out


class PairError(RuntimeError):
    """A pair that cannot be evaluated (unreadable image, no keypoints); the message names the image."""


def _unit_features(unit: SweepUnit, feature_cache_dir):
    """Features of both images, or :class:`PairError` naming the image that failed and why."""
    from .features import extract_features

    out = []
    for which, image in (("image1", unit.pair.image1), ("image2", unit.pair.image2)):
        try:
            feats = extract_features(image, unit.features, cache_dir=feature_cache_dir)
        except Exception as exc:  # any decoder or extractor failure is this pair's, not the run's
            raise PairError(f"{which} {image}: cannot be read ({type(exc).__name__}: {exc})") from exc
        if len(feats) == 0:
            raise PairError(f"{which} {image}: 0 keypoints")
        out.append(feats)
    from .pipeline import check_pair_keypoints

    try:
        check_pair_keypoints(unit.pair, *out)
    except ValueError as exc:
        raise PairError(str(exc)) from exc
    return out


def _error_rows(unit: SweepUnit, message: str, n: int = 0, m: int = 0) -> list[dict]:
    """Rows of a unit that could not be evaluated: NaN metrics, zero counts, ``error`` set."""
    rows = []
    for cfg in unit.blobs:
        for method in ("blob", *unit.filters):
            for model in unit.models:
                rows.append(_error_row(unit, cfg, method, model, message, n, m))
    return rows


def _error_row(unit, cfg, method, model, message, n, m, **known) -> dict:
    pair = unit.pair
    nan = float("nan")
    row = {"dataset": pair.dataset or unit.dataset, "pair_id": pair.pair_id, "kind": pair.kind,
           "features": unit.features_name, **_blob_record(cfg), "method": method, "model": model,
           "precision": nan, "recall": nan, "recall_star": nan, "ap": nan, "ap_star": nan, "correct": 0,
           "correct_norm": 0, "output": 0, "failure": False, "empty_output": False, "time_s": nan, "model_time_s": nan,
           "n_kpts1": n, "n_kpts2": m, "n_candidates": 0, "n_gt": 0, "n_gt_star": 0, "gt_method": unit.gt_method,
           "error": message}
    row.update(known)
    return row


def run_unit(unit: SweepUnit, *, cache_dir=None, feature_cache_dir=None):
    """Evaluate one :class:`SweepUnit`; returns a ``pandas.DataFrame`` with :data:`SWEEP_COLUMNS`.

    Rows come in the unit's blob order; for each setup, the unfiltered candidates (method ``"blob"``) and
    then each filter, each with the unit's models. The AP of a row is that of its output ranked by the
    blob score; the recall reference is the setup's correct candidates, recall* the union of the correct
    candidates of all setups of the unit.

    Nothing raises for one pair's sake: an unreadable image or an image with 0 keypoints gives rows with
    NaN metrics whose ``error`` names the image and the reason; a filter or model step that raises gives
    such rows for that method (or method + model) only, and the other methods are evaluated as usual.

    ``cache_dir``: the sweep cache (``None``: the default; ``False``: no cache).
    """
    import pandas as pd

    from .pipeline import label_candidates, pair_seed, run_filter, run_model

    cache = None if cache_dir is False else _sweep_cache(cache_dir)
    pair = unit.pair
    try:
        f1, f2 = _unit_features(unit, feature_cache_dir)
    except PairError as exc:
        return _frame(pd, _error_rows(unit, str(exc)))
    n, m = len(f1), len(f2)
    digest = _features_digest(f1, f2)
    blobs = list(unit.blobs)
    cand_keys = list(dict.fromkeys(c.candidate_key for c in blobs))
    needs_overlap = any(c.t_o is not None and c.t_o_kind == "overlap" for c in blobs)
    depth = max([k[0] for k in cand_keys if k[0] != "omega"] + [k[2] for k in cand_keys] + [1])

    state = {}

    def ctx():
        """The blob context and the seconds it took to build now (``None`` when it already existed)."""
        if "ctx" in state:
            return state["ctx"], None
        t0 = time.perf_counter()
        tables = (_overlap_table(f1, cache), _overlap_table(f2, cache)) if needs_overlap else None
        state["ctx"] = _SweepContext(f1.desc, f2.desc, kpts1=f1.kpts, kpts2=f2.kpts, shapes1=f1.shapes,
                                     shapes2=f2.shapes, depth=depth, overlap_tables=tables,
                                     distance=f1.distance())
        return state["ctx"], time.perf_counter() - t0

    cands = _candidate_sets(ctx, cand_keys, cache, digest, unit.salt)

    # Labels depend on the match only: label the union of all candidate sets once.
    union = np.unique(np.concatenate([c[0] for c in cands.values()] + [np.empty((0, 2), np.int64)]), axis=0)
    union_lab = label_candidates(pair, f1, f2, union, method=unit.gt_method, threshold=unit.gt_threshold)
    sets = {}
    for key, (matches, dist, t_cand) in cands.items():
        # Candidates ordered by (row, column): a stable sort by score then reproduces blob_matching's
        # order (score, row, column), hence the same tie-break in the AP and for the filters.
        base = np.lexsort((matches[:, 1], matches[:, 0]))
        mt, dt = matches[base], dist[base]
        if len(mt):
            pos = np.searchsorted(union[:, 0] * max(m, 1) + union[:, 1], mt[:, 0] * max(m, 1) + mt[:, 1])
            lab = union_lab[pos]
        else:
            lab = np.zeros(0, bool)
        sets[key] = (mt, dt, lab, normalised_count(mt[lab]), t_cand)
    ref_star = union[union_lab]
    n_gt_star = normalised_count(ref_star)

    filter_params = {name: json.loads(p) for name, p in unit.filter_params}
    fast = not unit.filters and unit.models == ("none",)
    masks, masks_added, mask_path = {}, False, None
    if unit.filters and cache is not None:
        # The salt (the library source digest for eval and the notebooks) keeps masks of edited filters out.
        mask_key = _sha1(_SWEEP_FORMAT, digest, unit.filters, unit.filter_params, unit.salt)
        mask_path = cache / "filters" / f"{mask_key}.npz"
        masks = _load_npz(mask_path) or {}
    rng_seed = pair_seed(unit.seed, pair.pair_id)
    base_row = {"dataset": pair.dataset or unit.dataset, "pair_id": pair.pair_id, "kind": pair.kind,
                "features": unit.features_name, "n_kpts1": n, "n_kpts2": m, "gt_method": unit.gt_method,
                "error": ""}

    ranks: dict = {}
    rows = []
    for cfg in blobs:
        mt, dt, lab, n_gt, t_cand = sets[cfg.candidate_key]
        rk = (cfg.candidate_key, cfg.ratio, cfg.t_o, cfg.t_o_kind)
        if rk not in ranks:
            t0 = time.perf_counter()
            ab = (rank_candidates(ctx()[0], mt, dt, ratio=cfg.ratio, t_o=cfg.t_o, t_o_kind=cfg.t_o_kind)
                  if len(mt) else (np.empty(0), np.empty(0)))
            ranks[rk] = (ab, time.perf_counter() - t0)
        t0 = time.perf_counter()
        scores = combine_ratios(*ranks[rk][0], cfg.combine)
        # The blob method's time: candidates, ratios and scores of this setup (Sec. 5.3's blob row).
        t_blob = t_cand + ranks[rk][1] + time.perf_counter() - t0
        common = {**base_row, **_blob_record(cfg), "n_candidates": len(mt), "n_gt": n_gt, "n_gt_star": n_gt_star}
        if fast:
            correct = int(lab.sum())
            rows.append({**common, "method": "blob", "model": "none",
                         "precision": correct / len(mt) if len(mt) else 0.0,
                         "recall": 1.0 if n_gt else float("nan"),
                         "recall_star": n_gt / n_gt_star if n_gt_star else float("nan"),
                         "ap": _ranked_ap(mt[:, 0], mt[:, 1], lab, scores, n_gt, n, m),
                         "ap_star": _ranked_ap(mt[:, 0], mt[:, 1], lab, scores, n_gt_star, n, m),
                         "correct": correct, "correct_norm": n_gt, "output": len(mt),
                         "failure": len(mt) > 0 and correct == 0, "empty_output": len(mt) == 0,
                         "time_s": t_blob, "model_time_s": 0.0})
            continue
        order = np.argsort(scores, kind="stable")
        sm, ss, sl = mt[order], scores[order], lab[order]
        ref = sm[sl]
        keeps = {"blob": (np.ones(len(sm), bool), t_blob)}
        for name in unit.filters:
            mkey = f"{name}__{_sha1(cfg.kwargs())}"
            if mkey in masks:
                keeps[name] = (masks[mkey].astype(bool), float(masks[f"t_{mkey}"]))
                continue
            try:
                keep, t = run_filter(name, f1, f2, sm, ss, image_size1=pair.image_size1,
                                     image_size2=pair.image_size2, blob_ratio=cfg.ratio,
                                     **filter_params.get(name, {}))
            except Exception as exc:  # one filter failing on one pair is recorded, not fatal
                keeps[name] = (f"filter {name!r} raised {type(exc).__name__}: {exc}", float("nan"))
                continue
            keeps[name] = (keep, t)
            masks[mkey], masks[f"t_{mkey}"], masks_added = keep, np.float64(t), True
        for method, (keep, t_method) in keeps.items():
            for model in unit.models:
                if isinstance(keep, str):
                    rows.append(_error_row(unit, cfg, method, model, keep, n, m, n_candidates=len(mt),
                                           n_gt=n_gt, n_gt_star=n_gt_star))
                    continue
                try:
                    fit, t_model = run_model(model, f1, f2, sm[keep], ss[keep], pair_kind=pair.kind,
                                             threshold=unit.model_threshold, rng=rng_seed)
                except Exception as exc:
                    rows.append(_error_row(unit, cfg, method, model,
                                           f"model {model!r} raised {type(exc).__name__}: {exc}", n, m,
                                           n_candidates=len(mt), n_gt=n_gt, n_gt_star=n_gt_star,
                                           time_s=t_method))
                    continue
                final = keep.copy()
                final[np.flatnonzero(keep)] = fit.keep
                mm = evaluate_matches(sm[final], sl[final], reference=ref, reference_star=ref_star,
                                      scores=ss[final], time_s=t_method)
                rows.append({**common, "method": method, "model": model, "precision": mm.precision,
                             "recall": mm.recall, "recall_star": mm.recall_star, "ap": mm.ap,
                             "ap_star": average_precision(sm[final], sl[final], ss[final], ref_star),
                             "correct": mm.correct, "correct_norm": mm.correct_norm, "output": mm.output,
                             "failure": mm.failure, "empty_output": mm.empty_output, "time_s": mm.time_s,
                             "model_time_s": t_model})
    if masks_added and mask_path is not None:
        _save_npz(mask_path, masks)
    return _frame(pd, rows)


def _frame(pd, rows):
    df = pd.DataFrame(rows, columns=list(SWEEP_COLUMNS))
    return df.astype({**{c: "int64" for c in _INT_COLUMNS}, "failure": "bool", "empty_output": "bool", "t_o": "float64",
                      "precision": "float64", "recall": "float64", "recall_star": "float64", "ap": "float64",
                      "ap_star": "float64", "time_s": "float64", "model_time_s": "float64", "error": "str"})


# ----------------------------------------------------------------------------------------- the sweep


def _check_settings(*, features, blobs, filters, models, gt_method, gt_threshold, model_threshold,
                    filter_params, seed, max_keypoints) -> dict:
    """Validate every setting of an evaluation before any work; returns them resolved."""
    if gt_method not in GT_METHODS:
        raise ValueError(f"gt_method must be one of {GT_METHODS}, got {gt_method!r}")
    for name, value in (("gt_threshold", gt_threshold), ("model_threshold", model_threshold)):
        if isinstance(value, bool) or not (isinstance(value, (int, float, np.number)) and math.isfinite(value)
                                           and value > 0):
            raise ValueError(f"{name} must be a positive number of pixels, got {value!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if max_keypoints is not None and (isinstance(max_keypoints, bool) or max_keypoints < 0
                                      or not isinstance(max_keypoints, (int, np.integer))):
        raise ValueError(f"max_keypoints must be a non-negative integer, got {max_keypoints!r}")
    feats = resolve_features(features)
    if max_keypoints is not None:
        from dataclasses import replace

        feats = {k: replace(v, max_keypoints=int(max_keypoints)) for k, v in feats.items()}
    if isinstance(blobs, Mapping):
        names, blob_cfgs = tuple(blobs), tuple(blobs.values())
        for b in blob_cfgs:
            if not isinstance(b, BlobConfig):
                raise ValueError(f"blobs must map names to BlobConfig, got {type(b).__name__}")
    else:
        blob_cfgs, names = tuple(resolve_blob_configs(blobs)), ()
    filters, models = _check_names(tuple(filters), tuple(models))
    params = dict(filter_params or {})
    unknown = sorted(set(params) - set(filters))
    if unknown:
        raise ValueError(f"filter_params names filters not in the sweep: {', '.join(unknown)}")
    fparams = tuple((k, json.dumps(params[k], sort_keys=True)) for k in filters if k in params)
    return dict(feats=feats, blobs=blob_cfgs, blob_names=names, filters=filters, models=models, fparams=fparams,
                gt_method=gt_method, gt_threshold=float(gt_threshold), model_threshold=float(model_threshold),
                seed=int(seed))


def _units(dataset_name, pairs, st, salt: str = "") -> list[SweepUnit]:
    return [SweepUnit(str(dataset_name), pair, fname, fcfg, st["blobs"], st["filters"], st["models"], st["fparams"],
                      st["gt_method"], st["gt_threshold"], st["model_threshold"], st["seed"],
                      blob_names=st["blob_names"], salt=salt)
            for fname, fcfg in st["feats"].items() for pair in pairs]


def plan_units(pairs, *, features="sift-rootsift", blobs="paper-best", filters=(), models=("none",),
               gt_method: str = "D", gt_threshold: float = GT_THRESHOLD_PX, model_threshold: float = 15.0,
               filter_params: Mapping[str, dict] | None = None, seed: int = 0,
               max_keypoints: int | None = None, salt: str = "") -> list[SweepUnit]:
    """The work units evaluating ``pairs`` (a list of :class:`Pair`), in table order (features, pair).

    The arguments are those of :func:`run_sweep`; ``blobs`` may also be a dict name -> ``BlobConfig``
    (:func:`ctxmatch_lib.pipeline.resolve_blobs`), whose names then fill the ``blob`` column; ``salt``
    joins the units' keys (see :class:`SweepUnit`). Every argument is validated here, before any work.
    """
    st = _check_settings(features=features, blobs=blobs, filters=filters, models=models, gt_method=gt_method,
                         gt_threshold=gt_threshold, model_threshold=model_threshold, filter_params=filter_params,
                         seed=seed, max_keypoints=max_keypoints)
    pairs = list(pairs)
    for p in pairs:
        if not isinstance(p, Pair):
            raise ValueError(f"pairs must hold Pair objects, got {type(p).__name__}")
    return _units("", pairs, st, salt)


def plan_sweep(datasets="embedded", *, features="sift-rootsift", blobs="grid", filters=(), models=("none",),
               pairs=None, kinds=None, gt_method: str = "D", gt_threshold: float = GT_THRESHOLD_PX,
               model_threshold: float = 15.0, filter_params: Mapping[str, dict] | None = None, seed: int = 0,
               max_keypoints: int | None = None, data_root=None) -> list[SweepUnit]:
    """The work units of a sweep, in the order of its result table (dataset, features, pair).

    Every argument is validated here, before any work; see :func:`run_sweep` for their meaning.
    """
    st = _check_settings(features=features, blobs=blobs, filters=filters, models=models, gt_method=gt_method,
                         gt_threshold=gt_threshold, model_threshold=model_threshold, filter_params=filter_params,
                         seed=seed, max_keypoints=max_keypoints)
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
        units.extend(_units(ds_name, chosen, st))
    return units


def _keyed(units: list[SweepUnit]) -> list[SweepUnit]:
    from dataclasses import replace

    digests: dict = {}
    out = []
    for u in units:
        pid = (u.pair.image1, u.pair.image2, u.pair.pair_id, u.pair.dataset)
        if pid not in digests:
            try:
                digests[pid] = _pair_digest(u.pair)
            except OSError as exc:
                # A missing or unreadable file: the unit runs (and reports it), its part is never written.
                digests[pid] = f"unreadable:{exc}"
        out.append(replace(u, key=_unit_key(u, digests[pid])))
    return out


def _unit_task(unit, cache_dir, feature_cache_dir):
    """What a worker runs: the rows of one unit (the driver writes the part file)."""
    t0 = time.perf_counter()
    df = run_unit(unit, cache_dir=cache_dir, feature_cache_dir=feature_cache_dir)
    return unit.key, df, time.perf_counter() - t0


def _connect_dask(dask):
    try:
        from distributed import Client
    except ImportError as exc:  # optional dependency
        raise ImportError("--dask needs the optional 'distributed' package: pip install 'dask[distributed]'") \
            from exc
    if isinstance(dask, Client):
        return dask, False
    if not isinstance(dask, str) or "://" not in dask:
        raise ValueError(f"dask must be a scheduler address like 'tcp://host:8786' or a distributed.Client, "
                         f"got {dask!r}")
    try:
        return Client(dask, timeout="20s"), True
    except OSError as exc:
        raise ConnectionError(f"cannot reach the Dask scheduler at {dask}: {exc}") from exc


def _check_runner(n_jobs, dask):
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, (int, np.integer)) or n_jobs == 0 or n_jobs < -1:
        raise ValueError(f"n_jobs must be a positive int or -1, got {n_jobs!r}")
    if dask is not None and n_jobs != 1:
        raise ValueError("give either n_jobs (local processes) or dask (a cluster), not both")


def _named(df, unit: SweepUnit):
    """The unit's rows with its ``blob_names`` in the ``blob`` column."""
    if unit.blob_names:
        labels = {c.label: name for c, name in zip(unit.blobs, unit.blob_names)}
        df = df.assign(blob=df["blob"].map(labels).fillna(df["blob"]))
    return df


def run_units(units: Sequence[SweepUnit], *, cache_dir=None, feature_cache_dir=None, n_jobs: int = 1, dask=None,
              progress: bool = True, recompute: bool = False, desc: str = "ctxmatch sweep"):
    """Run (or resume) work units and return their rows, in the units' order (:data:`SWEEP_COLUMNS`).

    The one evaluation engine behind :func:`run_sweep`, ``ctxmatch eval``
    (:func:`ctxmatch_lib.pipeline.evaluate_dataset`) and the report notebooks
    (:func:`ctxmatch_lib.evalcache.evaluate_cached`).

    Each finished unit is written as one Parquet part under ``<cache_dir>/results`` (atomically), so a
    run killed at any moment resumes with no lost and no duplicated rows. A unit whose rows carry an
    ``error`` (unreadable image, 0 keypoints, a filter or model step that raised) is reported with a
    ``RuntimeWarning`` naming the pair, the image and the reason; its rows are returned but its part is
    not written, so the next run tries it again. The other units go on.

    Parameters
    ----------
    units : sequence of SweepUnit
        From :func:`plan_sweep` or :func:`plan_units`.
    cache_dir : path, None or False
        The evaluation cache (default ``ctxmatch_lib._paths.cache_dir("sweep")``); ``False``: no cache at
        all (nothing read, nothing written).
    feature_cache_dir : path, optional
        The feature cache (default: that of :mod:`ctxmatch_lib.features`).
    n_jobs, dask, progress, recompute
        As in :func:`run_sweep`; ``desc`` is the progress bar's title.
    """
    import warnings

    import pandas as pd
    from tqdm.auto import tqdm

    _check_runner(n_jobs, dask)
    units = _keyed(list(units))
    if not units:
        return _frame(pd, [])
    use_cache = cache_dir is not False
    if use_cache:
        cache = _sweep_cache(cache_dir)
        parts_dir = cache / "results"
        parts_dir.mkdir(parents=True, exist_ok=True)
        part = {u.key: parts_dir / f"{u.key}.parquet" for u in units}
        todo = list({u.key: u for u in units if recompute or not part[u.key].is_file()}.values())
        cache_arg = cache if cache_dir is not None else None
    else:
        part, cache_arg = {}, False
        todo = list({u.key: u for u in units}.values())
    n_total = len({u.key for u in units})
    in_memory: dict = {}
    failed: list[str] = []

    bar = tqdm(total=n_total, initial=n_total - len(todo), desc=desc, unit="pair", disable=not progress,
               dynamic_ncols=True, smoothing=0.1)

    def done(key, df):
        errors = [e for e in dict.fromkeys(df["error"]) if e]
        if errors or not use_cache:
            in_memory[key] = df
        else:
            # One part per unit, written atomically: a kill leaves whole parts only.
            write_parquet_atomic(df, part[key])
        if errors:
            pid = f"{df['dataset'].iloc[0]}/{df['pair_id'].iloc[0]}" if len(df) else key
            for e in errors:
                failed.append(f"{pid}: {e}")
                msg = f"pair {pid}: {e}"
                if progress:
                    bar.write(f"warning: {msg}")
                warnings.warn(msg, RuntimeWarning, stacklevel=3)
        bar.update(1)

    try:
        if todo and dask is not None:
            client, own = _connect_dask(dask)
            try:
                from distributed import as_completed

                bar.set_postfix_str(f"{len(todo)} pairs on the cluster", refresh=True)
                futures = [client.submit(_unit_task, u, cache_arg, feature_cache_dir, pure=False) for u in todo]
                for fut in as_completed(futures):
                    key, df, _ = fut.result()
                    done(key, df)
            finally:
                if own:
                    client.close()
        elif todo and n_jobs != 1 and len(todo) > 1:
            from joblib import Parallel, delayed

            bar.set_postfix_str(f"{len(todo)} pairs on {n_jobs if n_jobs > 0 else 'all'} workers", refresh=True)
            par = Parallel(n_jobs=n_jobs, backend="loky", return_as="generator_unordered")
            for key, df, _ in par(delayed(_unit_task)(u, cache_arg, feature_cache_dir) for u in todo):
                done(key, df)
        else:
            for u in todo:
                # Named before it runs: the bar shows the pair in progress.
                bar.set_postfix_str(u.label(), refresh=True)
                key, df, _ = _unit_task(u, cache_arg, feature_cache_dir)
                done(key, df)
    finally:
        bar.set_postfix_str("", refresh=False)
        bar.close()

    frames = [_named(in_memory[u.key] if u.key in in_memory else pd.read_parquet(part[u.key]), u) for u in units]
    return pd.concat(frames, ignore_index=True)


def run_sweep(datasets="embedded", *, features="sift-rootsift", blobs="grid", filters=(), models=("none",),
              pairs=None, kinds=None, gt_method: str = "D", gt_threshold: float = GT_THRESHOLD_PX,
              model_threshold: float = 15.0, filter_params: Mapping[str, dict] | None = None, seed: int = 0,
              max_keypoints: int | None = None, n_jobs: int = 1, dask=None, cache_dir=None,
              feature_cache_dir=None, out=None, progress: bool = True, data_root=None, recompute: bool = False):
    """Run (or resume) a sweep and return its rows as a ``pandas.DataFrame`` (:data:`SWEEP_COLUMNS`).

    Parameters
    ----------
    datasets : str or list of str
        Registered dataset names or custom folders (``"embedded"``, ``"planar,nonplanar"``, ...).
    features : str, FeatureConfig, list or dict
        Detector+descriptor configurations (:func:`resolve_features`).
    blobs : str, BlobConfig or list
        ``"grid"`` (the 2430 setups of Sec. 5.2), preset names or configs (:func:`resolve_blob_configs`).
    filters : sequence of str
        Registered filters run on every setup's candidates (the unfiltered candidates are always the
        method ``"blob"``); ``filter_params`` gives extra keyword arguments per filter.
    models : sequence of str
        Model steps (``"none"``, ``"1sac"``, ``"ransac"``, ``"prosac"``) after each method.
    max_keypoints : int, optional
        Override the keypoint cap of every feature configuration (small values for quick runs).
    pairs : None, int or list of str
        Pair subset (:func:`select_pairs`): ``N`` evenly spread pairs, or pair ids; ``kinds`` keeps only
        some pair kinds.
    gt_method, gt_threshold, model_threshold, seed
        As in :func:`ctxmatch_lib.pipeline.evaluate_pair`.
    n_jobs : int
        Local worker processes (joblib, loky backend); ``1`` runs in this process, ``-1`` uses every core.
    dask : str or distributed.Client, optional
        Run the units on a Dask cluster instead: a scheduler address (``"tcp://host:8786"``) or a client.
        Workers must see the data and image paths the driver sees; each worker keeps its own caches.
    cache_dir : path, optional
        The sweep cache (default ``ctxmatch_lib._paths.cache_dir("sweep")``); ``feature_cache_dir`` the
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
        :func:`run_units`).
    """
    _check_runner(n_jobs, dask)
    if out is not None and Path(out).suffix.lower() != ".parquet":
        raise ValueError(f"out must be a .parquet file, got {out}")
    units = plan_sweep(datasets, features=features, blobs=blobs, filters=filters, models=models,
                       pairs=pairs, kinds=kinds, gt_method=gt_method, gt_threshold=gt_threshold,
                       model_threshold=model_threshold, filter_params=filter_params, seed=seed,
                       max_keypoints=max_keypoints, data_root=data_root)
    df = run_units(units, cache_dir=cache_dir, feature_cache_dir=feature_cache_dir, n_jobs=n_jobs, dask=dask,
                   progress=progress, recompute=recompute, desc="ctxmatch sweep")
    if out is not None:
        meta = {"datasets": datasets, "features": {u.features_name: u.features.key() for u in units},
                "blobs": len(units[0].blobs), "filters": list(units[0].filters), "models": list(units[0].models),
                "pairs": len({(u.dataset, u.pair.pair_id) for u in units}), "gt_method": gt_method,
                "gt_threshold": gt_threshold, "model_threshold": model_threshold, "seed": seed,
                "format": _SWEEP_FORMAT}
        write_parquet_atomic(df, out, meta)
    return df


# --------------------------------------------------------------------------------------------- tables


def blob_map(df, *, metric: str = "ap_star", method: str = "blob", model: str = "none"):
    """mAP of every (features, blob setup): the mean over pairs of the AP (NaN APs skipped), in %.

    ``metric="ap_star"`` (default, the heat map of Fig. 5) ranks each setup's candidates against the
    correct matches of *all* setups of the sweep on the pair (the recall* reference), so a setup that
    misses correct matches is penalised: one-to-one matching can score lower than many-to-many.
    ``metric="ap"`` uses each setup's own correct candidates, which rewards small, precise candidate
    sets (mutual nearest neighbours score close to 100 %).

    Returns a frame with the blob fields, ``mAP`` and ``pairs`` (pairs with a defined AP), in the order of
    first appearance (the grid order for a grid sweep).
    """
    import pandas as pd

    if metric not in ("ap", "ap_star"):
        raise ValueError(f"metric must be 'ap' or 'ap_star', got {metric!r}")
    d = df[(df["method"] == method) & (df["model"] == model)]
    keys = ["features", "blob", "f", "prefilter", "f_prime", "ratio", "t_o", "t_o_kind", "combine"]
    g = d.groupby(keys, sort=False, dropna=False)[metric]
    out = pd.DataFrame({"mAP": 100 * g.mean(), "pairs": g.count()}).reset_index()
    return out


def _f_label(f, prefilter) -> str:
    return "Ω" if f == "omega" else f"{f}{'∪' if prefilter == 'cup' else '∩'}"


def _t_o_label(t_o, kind) -> str:
    if t_o is None or (isinstance(t_o, float) and math.isnan(t_o)):
        return "∞"
    return f"{t_o:g}px" if kind == "px" else f"{100 * t_o:g}%"


_RATIO_LABEL = {"D>=": "D≥", "D+>=": "D+≥", "D+": "D+"}


def heatmap_matrix(maps, features: str | None = None):
    """The heat-map layout of Fig. 5 for one detector+descriptor: rows f × f', columns t_o × D × W.

    Parameters
    ----------
    maps : DataFrame
        :func:`blob_map` output.
    features : str, optional
        Which feature configuration; required when ``maps`` holds several.

    Returns
    -------
    DataFrame
        mAP in %, indexed by ``(f, f')`` labels (``"10∪", 5``) and with ``(t_o, D, W)`` label columns,
        both in the grid order of Sec. 5.2 restricted to the setups present; missing setups are NaN.
    """
    import pandas as pd

    d = maps
    if features is None:
        names = list(dict.fromkeys(d["features"]))
        if len(names) != 1:
            raise ValueError(f"maps holds several feature configurations, pick one of {names}")
        features = names[0]
    d = d[d["features"] == features]
    if d.empty:
        raise ValueError(f"no rows for features {features!r}")
    from .blob.config import COMBINES, GRID_F, GRID_T_O

    f_order = {_f_label(str(f), p): i for i, (f, p) in enumerate(GRID_F)}
    t_order = {_t_o_label(t, k): i for i, (t, k) in enumerate(GRID_T_O)}
    row_lab = [_f_label(f, p) for f, p in zip(d["f"], d["prefilter"])]
    col_t = [_t_o_label(t, k) for t, k in zip(d["t_o"], d["t_o_kind"])]
    tab = pd.DataFrame({"f": row_lab, "f'": d["f_prime"].to_numpy(), "t_o": col_t,
                        "D": [_RATIO_LABEL[r] for r in d["ratio"]], "W": d["combine"].to_numpy(),
                        "mAP": d["mAP"].to_numpy()})
    mat = tab.pivot(index=["f", "f'"], columns=["t_o", "D", "W"], values="mAP")
    r_order = {lab: i for i, lab in enumerate(_RATIO_LABEL.values())}
    w_order = {w: i for i, w in enumerate(COMBINES)}
    rows = sorted(mat.index, key=lambda r: (f_order.get(r[0], 99), r[1]))
    cols = sorted(mat.columns, key=lambda c: (t_order.get(c[0], 99), r_order[c[1]], w_order[c[2]]))
    return mat.loc[rows, cols]
