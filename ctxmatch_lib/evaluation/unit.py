"""One work unit: every blob setup, filter and model of an evaluation on one pair (Sec. 5.1, 5.2).

:func:`run_unit` shares the grid's work: one :class:`~ctxmatch_lib.blob.BlobContext` per pair, one candidate
set per (f, ∩/∪, f'), the ratios once per (t_o, D) for the five W. ``ap_star`` ranks against the correct
candidates of all setups of the unit (the recall* reference).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from ..blob import combine_ratios, rank_candidates
from ..datasets.base import PoseGT
from ..geometry import ROBUST_STEPS
from ..geometry_metrics import gt_correspondences
from ..metrics import average_precision, evaluate_matches, normalised_count
from .cache import FORMAT, candidate_sets, digest, engine_cache, features_digest, load_npz, save_npz
from .overlap import TabulatedContext, overlap_table
from .plan import SweepUnit
from .rows import blob_record, error_row, error_rows, frame, ranked_aps
from .steps import (check_pair_keypoints, label_candidates, model_accuracy, pair_seed, run_filter, run_matcher,
                    run_model, run_seed)

__all__ = ["BlobStage", "PairError", "unit_features", "run_unit"]


@dataclass
class BlobStage:
    """Everything computed for one blob setup on one pair (:func:`run_unit`'s ``stages``).

    ``matches``, ``scores``, ``labels``: the candidates in score order; ``keeps[method]``: a mask over them
    (or an error message); ``fits[(method, model)]``: the :class:`~ctxmatch_lib.geometry.ModelFit` (of run 0).
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


class PairError(RuntimeError):
    """A pair that cannot be evaluated (unreadable image, no keypoints); the message names the image."""


def unit_features(unit: SweepUnit, feature_cache_dir):
    """Features of both images, or :class:`PairError` naming the image that failed and why."""
    from ..features import extract_features

    out = []
    for which, image in (("image1", unit.pair.image1), ("image2", unit.pair.image2)):
        try:
            feats = extract_features(image, unit.features, cache_dir=feature_cache_dir)
        except Exception as exc:  # any decoder or extractor failure is this pair's, not the run's
            raise PairError(f"{which} {image}: cannot be read ({type(exc).__name__}: {exc})") from exc
        if len(feats) == 0:
            raise PairError(f"{which} {image}: 0 keypoints")
        out.append(feats)
    try:
        check_pair_keypoints(unit.pair, *out)
    except ValueError as exc:
        raise PairError(str(exc)) from exc
    return out


@dataclass
class _PairData:
    """What every blob setup of a unit shares: the features, the recall* reference, the fixed row fields."""

    unit: SweepUnit
    f1: object
    f2: object
    ref_star: np.ndarray
    n_gt_star: int
    base_row: dict
    filter_params: dict
    rng_seed: int
    corr: object = None  # the ground-truth correspondences the epipolar share is measured on, or None
    fits: dict = None  # (method, model, run) -> (fit, seconds) of the matcher rows, shared by the blob setups
    matcher_sets: dict = None  # what _matcher_sets returns, once computed


def _context_factory(unit: SweepUnit, f1, f2, cache):
    """A function building the blob context once, on first call (with tabulated overlaps when needed)."""
    blobs = list(unit.blobs)
    cand_keys = list(dict.fromkeys(c.candidate_key for c in blobs))
    needs_overlap = any(c.t_o is not None and c.t_o_kind == "overlap" for c in blobs)
    depth = max([k[0] for k in cand_keys if k[0] != "omega"] + [k[2] for k in cand_keys] + [1])
    # f = Ω walks whole rows: keep them from the one pass over D rather than a second product.
    keep_dense = True if any(k[0] == "omega" for k in cand_keys) else None
    state = {}

    def ctx():
        """The blob context and the seconds its building took."""
        if "ctx" not in state:
            t0 = time.perf_counter()
            tables = (overlap_table(f1, cache), overlap_table(f2, cache)) if needs_overlap else None
            state["ctx"] = TabulatedContext(f1.desc, f2.desc, kpts1=f1.kpts, kpts2=f2.kpts, shapes1=f1.shapes,
                                            shapes2=f2.shapes, depth=depth, overlap_tables=tables,
                                            distance=f1.distance(), keep_dense=keep_dense)
            state["seconds"] = time.perf_counter() - t0
        return state["ctx"], state["seconds"]

    return ctx, cand_keys


def _labelled_sets(unit: SweepUnit, f1, f2, cands: dict):
    """Each candidate set ordered by (row, column) with its labels; the recall* reference and its size."""
    m = len(f2)
    # Labels depend on the match only: label the union of all candidate sets once.
    union = np.unique(np.concatenate([c[0] for c in cands.values()] + [np.empty((0, 2), np.int64)]), axis=0)
    union_lab = label_candidates(unit.pair, f1, f2, union, method=unit.gt_method, threshold=unit.gt_threshold)
    sets = {}
    for key, (matches, dist, t_cand) in cands.items():
        # Ordered by (row, column): a stable sort by score then gives blob_matching's tie-break.
        base = np.lexsort((matches[:, 1], matches[:, 0]))
        mt, dt = matches[base], dist[base]
        if len(mt):
            pos = np.searchsorted(union[:, 0] * max(m, 1) + union[:, 1], mt[:, 0] * max(m, 1) + mt[:, 1])
            lab = union_lab[pos]
        else:
            lab = np.zeros(0, bool)
        sets[key] = (mt, dt, lab, normalised_count(mt[lab]), t_cand)
    ref_star = union[union_lab]
    return sets, ref_star, normalised_count(ref_star)


def _fast_row(d: _PairData, common: dict, mt, lab, scores, n_gt: int, t_blob: float) -> dict:
    """The blob row of a setup of a unit without filters and models (the grid), both APs from one ranking."""
    correct = int(lab.sum())
    ap, ap_star = ranked_aps(mt[:, 0], mt[:, 1], lab, scores, (n_gt, d.n_gt_star))
    return {**common, "method": "blob", "model": "none", "run": 0,
            "precision": correct / len(mt) if len(mt) else 0.0,
            "recall": 1.0 if n_gt else float("nan"),
            "recall_star": n_gt / d.n_gt_star if d.n_gt_star else float("nan"),
            "ap": ap, "ap_star": ap_star,
            "correct": correct, "correct_norm": n_gt, "output": len(mt),
            "failure": len(mt) > 0 and correct == 0, "empty_output": len(mt) == 0,
            "time_s": t_blob, "model_time_s": 0.0, **model_accuracy("none", None, d.unit.pair, None)}


def _filter_keeps(d: _PairData, cfg, sm, ss, t_blob: float, masks: dict) -> dict:
    """Each method's mask (or error) and time, cached in ``masks``."""
    pair = d.unit.pair
    keeps = {"blob": (np.ones(len(sm), bool), t_blob)}
    for name in d.unit.filters:
        mkey = f"{name}__{digest(cfg.kwargs())}"
        if mkey in masks:
            keeps[name] = (masks[mkey].astype(bool), float(masks[f"t_{mkey}"]))
            continue
        try:
            keep, t = run_filter(name, d.f1, d.f2, sm, ss, image_size1=pair.image_size1,
                                 image_size2=pair.image_size2, blob_ratio=cfg.ratio,
                                 **d.filter_params.get(name, {}))
        except Exception as exc:  # one filter failing on one pair is recorded, not fatal
            keeps[name] = (f"filter {name!r} raised {type(exc).__name__}: {exc}", float("nan"))
            continue
        keeps[name] = (keep, t)
        masks[mkey], masks[f"t_{mkey}"] = keep, np.float64(t)
    return keeps


def _method_rows(d: _PairData, cfg, common: dict, keeps: dict, sm, ss, sl, stage=None) -> list[dict]:
    """The rows of every (method, model) of one setup, matchers included; a failed step gives an error row."""
    unit, n, m = d.unit, len(d.f1), len(d.f2)
    known = {"n_candidates": common["n_candidates"], "n_gt": common["n_gt"], "n_gt_star": d.n_gt_star}
    ref = sm[sl]
    sets = [(method, sm, ss, sl, keep, t, False) for method, (keep, t) in keeps.items()]
    sets += [(name, *alt, True) for name, alt in _matcher_sets(d).items()]
    # A random model step runs unit.runs times, each seeded by run_seed; the other steps once.
    steps = [(model, r) for model in unit.models for r in range(unit.runs if model in ROBUST_STEPS else 1)]
    rows = []
    for method, cm, cs, cl, keep, t_method, shared in sets:
        for model, run in steps:
            if isinstance(keep, str):
                rows.append(error_row(unit, cfg, method, model, keep, n, m, **known, run=run))
                continue
            try:
                fit, t_model = _fit(d, method, model, run, cm[keep], cs[keep], shared)
            except Exception as exc:
                rows.append(error_row(unit, cfg, method, model,
                                      f"model {model!r} raised {type(exc).__name__}: {exc}", n, m,
                                      **known, time_s=t_method, run=run))
                continue
            if stage is not None and not shared and run == 0:
                stage.fits[method, model], stage.model_times[method, model] = fit, t_model
            final = keep.copy()
            final[np.flatnonzero(keep)] = fit.keep
            mm = evaluate_matches(cm[final], cl[final], reference=ref, reference_star=d.ref_star,
                                  scores=cs[final], time_s=t_method)
            rows.append({**common, "method": method, "model": model, "run": run, "precision": mm.precision,
                         "recall": mm.recall, "recall_star": mm.recall_star, "ap": mm.ap,
                         "ap_star": average_precision(cm[final], cl[final], cs[final], d.ref_star),
                         "correct": mm.correct, "correct_norm": mm.correct_norm, "output": mm.output,
                         "failure": mm.failure, "empty_output": mm.empty_output, "time_s": mm.time_s,
                         "model_time_s": t_model,
                         **model_accuracy(model, fit, unit.pair, d.corr, _points(d, cm[keep]))})
    return rows


def _fit(d: _PairData, method: str, model: str, run: int, matches, scores, shared: bool):
    """Run ``run`` of the model step on a method's output (seeded by
    :func:`~ctxmatch_lib.evaluation.steps.run_seed`); a matcher's (the same for every blob setup) is fitted once."""
    if shared and (method, model, run) in d.fits:
        return d.fits[method, model, run]
    unit = d.unit
    gt = unit.pair.gt
    out = run_model(model, d.f1, d.f2, matches, scores, pair_kind=unit.pair.kind, threshold=unit.model_threshold,
                    rng=run_seed(d.rng_seed, method, model, run), estimator=unit.estimator,
                    intrinsics=(gt.K1, gt.K2) if isinstance(gt, PoseGT) else None)
    if shared:
        d.fits[method, model, run] = out
    return out


def _points(d: _PairData, matches: np.ndarray):
    """The matched points ``(pts1, pts2)`` of a calibrated pair (for its pose), else ``None``."""
    if not isinstance(d.unit.pair.gt, PoseGT):
        return None
    return d.f1.kpts[matches[:, 0]], d.f2.kpts[matches[:, 1]]


def _matcher_sets(d: _PairData) -> dict:
    """Each alternative matcher's (matches, scores, labels, all-True mask, time), once per unit."""
    if d.matcher_sets is None:
        out = {}
        for name in d.unit.matchers:
            matches, scores, t = run_matcher(name, d.f1, d.f2)
            lab = label_candidates(d.unit.pair, d.f1, d.f2, matches, method=d.unit.gt_method,
                                   threshold=d.unit.gt_threshold)
            out[name] = (matches, scores, lab, np.ones(len(matches), bool), t)
        d.matcher_sets = out
    return d.matcher_sets


def _mask_store(unit: SweepUnit, feats_digest: str, cache):
    """The cached filter masks of the unit's pair and filters, and the file they live in."""
    if not unit.filters or cache is None:
        return {}, None
    # The salt (the library source digest) keeps masks of edited filters out.
    mask_key = digest(FORMAT, feats_digest, unit.filters, unit.filter_params, unit.salt)
    path = cache / "filters" / f"{mask_key}.npz"
    return load_npz(path) or {}, path


def run_unit(unit: SweepUnit, *, cache_dir=None, feature_cache_dir=None, features=None, stages=None):
    """Evaluate one :class:`~ctxmatch_lib.evaluation.plan.SweepUnit` into a ``pandas.DataFrame`` of
    :data:`~ctxmatch_lib.evaluation.rows.SWEEP_COLUMNS`: per blob setup, method ``"blob"`` then each filter,
    each with the unit's models (a random one ``unit.runs`` times, column ``run``).

    A pair or method that fails gives rows with NaN metrics and an ``error``, never an exception.
    ``cache_dir``: ``None`` the default, ``False`` none; ``features``: the two images' features, used as
    given; ``stages``: a dict receiving a :class:`BlobStage` per blob setup. BLAS runs on one thread.
    """
    with threadpool_limits(1):
        return _run_unit(unit, cache_dir=cache_dir, feature_cache_dir=feature_cache_dir, features=features,
                         stages=stages)


def _run_unit(unit: SweepUnit, *, cache_dir, feature_cache_dir, features, stages):
    cache = None if cache_dir is False else engine_cache(cache_dir)
    pair = unit.pair
    if features is not None:
        f1, f2 = features
    else:
        try:
            f1, f2 = unit_features(unit, feature_cache_dir)
        except PairError as exc:
            return frame(error_rows(unit, str(exc)))
    feats_digest = features_digest(f1, f2)
    ctx, cand_keys = _context_factory(unit, f1, f2, cache)
    sets, ref_star, n_gt_star = _labelled_sets(unit, f1, f2, candidate_sets(ctx, cand_keys, cache, feats_digest,
                                                                             unit.salt))
    base_row = {"dataset": pair.dataset or unit.dataset, "pair_id": pair.pair_id, "kind": pair.kind,
                "features": unit.features_name, "n_kpts1": len(f1), "n_kpts2": len(f2),
                "gt_method": unit.gt_method, "error": ""}
    d = _PairData(unit, f1, f2, ref_star, n_gt_star, base_row,
                  {name: json.loads(p) for name, p in unit.filter_params}, pair_seed(unit.seed, pair.pair_id),
                  gt_correspondences(pair.gt) if any(m != "none" for m in unit.models) else None, {})
    fast = not unit.filters and not unit.matchers and unit.models == ("none",) and stages is None
    names = unit.blob_names or tuple(cfg.label for cfg in unit.blobs)
    masks, mask_path = _mask_store(unit, feats_digest, cache)
    n_masks = len(masks)
    ranks: dict = {}
    rows = []
    for name, cfg in zip(names, unit.blobs):
        mt, dt, lab, n_gt, t_cand = sets[cfg.candidate_key]
        rk = (cfg.candidate_key, cfg.ratio, cfg.t_o, cfg.t_o_kind)
        if rk not in ranks:
            # Built outside the timer: the candidates' time holds it.
            context = ctx()[0] if len(mt) else None
            t0 = time.perf_counter()
            ab = (rank_candidates(context, mt, dt, ratio=cfg.ratio, t_o=cfg.t_o, t_o_kind=cfg.t_o_kind)
                  if len(mt) else (np.empty(0), np.empty(0)))
            ranks[rk] = (ab, time.perf_counter() - t0)
        t0 = time.perf_counter()
        scores = combine_ratios(*ranks[rk][0], cfg.combine)
        # The blob method's time: candidates, ratios and scores of this setup (Sec. 5.3's blob row).
        t_blob = t_cand + ranks[rk][1] + time.perf_counter() - t0
        common = {**base_row, **blob_record(cfg), "n_candidates": len(mt), "n_gt": n_gt, "n_gt_star": n_gt_star}
        if fast:
            rows.append(_fast_row(d, common, mt, lab, scores, n_gt, t_blob))
            continue
        order = np.argsort(scores, kind="stable")
        sm, ss, sl = mt[order], scores[order], lab[order]
        keeps = _filter_keeps(d, cfg, sm, ss, t_blob, masks)
        stage = None
        if stages is not None:
            stage = stages[name] = BlobStage(name, cfg, sm, ss, sl, t_blob, {m: k for m, (k, _) in keeps.items()},
                                             {m: t for m, (_, t) in keeps.items()})
        rows.extend(_method_rows(d, cfg, common, keeps, sm, ss, sl, stage))
    if len(masks) > n_masks and mask_path is not None:
        save_npz(mask_path, masks)
    return frame(rows)
