"""Helpers shared by the benchmark scripts (the folder is not a package: a script run as
``python benchmarks/<name>.py`` has this folder on its path and imports ``from _common import ...``)."""

from __future__ import annotations

import time

import numpy as np


def best_of(fn, repeat=3, *, warmup=False):
    """``(seconds, result)``: the best wall time of ``repeat`` calls of ``fn()`` and the last call's result,
    after one untimed call first when ``warmup`` (with ``repeat=0``: its result)."""
    out = fn() if warmup else None
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def canonical_candidates(dataset: str, features: str, blob: str, n_pairs: int, max_keypoints):
    """``(pair, f1, f2, matches, scores, labels)`` of ``n_pairs`` pairs of ``dataset`` spread evenly: the blob
    candidates of the feature and blob presets at the keypoint budget ``max_keypoints`` (``None``: the preset's),
    rows in the canonical order our filters decide in, labelled by the ground truth (method D)."""
    from dataclasses import replace

    from ctxmatch_lib.blob import BLOB_PRESETS
    from ctxmatch_lib.evaluation import select_pairs
    from ctxmatch_lib.evaluation.steps import blob_candidates, label_candidates, pair_features
    from ctxmatch_lib.features import FEATURE_PRESETS, keypoint_budget
    from ctxmatch_lib.filters._common import canonical_order

    fcfg = FEATURE_PRESETS[features]
    budget = keypoint_budget(max_keypoints)
    if budget is not None:
        fcfg = replace(fcfg, max_keypoints=budget)
    for pair in select_pairs(dataset, select=n_pairs):
        f1, f2 = pair_features(pair, fcfg)
        matches, scores, _ = blob_candidates(f1, f2, BLOB_PRESETS[blob])
        order, _ = canonical_order(f1.kpts[matches[:, 0], :2], f2.kpts[matches[:, 1], :2], matches, scores)
        matches, scores = matches[order], scores[order]  # the scores keep their blob ratio
        yield pair, f1, f2, matches, scores, label_candidates(pair, f1, f2, matches)
