"""Helpers shared by the filter tests (``test_filters.py``, ``test_filters_graph.py``, ``test_filters_ref*.py``):
the common call with its output checks, identity matches, the translated grid with one outlier, the
many-to-many case and the planted similarity with uniform outliers."""

from __future__ import annotations

import numpy as np

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.testing import planted_homography_matches

SIZE = (640, 480)


def run_filter(name, kpts1, kpts2, matches, scores=None, size1=SIZE, size2=SIZE, **kw):
    """``FILTERS[name]`` on the inputs; asserts the output is a ``(K,)`` bool mask and returns it."""
    keep = FILTERS[name](kpts1, kpts2, matches, scores, image_size1=size1, image_size2=size2, **kw)
    assert isinstance(keep, np.ndarray) and keep.dtype == bool and keep.shape == (len(matches),)
    return keep


def identity_matches(n):
    return np.repeat(np.arange(n, dtype=np.int64)[:, None], 2, axis=1)


def grid_translation(n_side=8, step=20.0, offset=(40.0, 30.0), shift=(7.0, -3.0)):
    """A regular grid moved by a translation, with match 0 replaced by a far-away outlier."""
    g = np.stack(np.meshgrid(np.arange(n_side) * step, np.arange(n_side) * step), -1).reshape(-1, 2)
    x = g + offset
    y = x + shift
    y[0] = (600.0, 450.0)
    return x, y


def many_to_many_case(name):
    """``(keep, truth)`` of ``FILTERS[name]`` on 800 planted matches, every image-1 keypoint matched to its
    true image-2 keypoint and to a random one (informative scores: the true ones lower)."""
    pm = planted_homography_matches(800, 1.0, noise=0.3, image_size=SIZE, rng=7)
    rng = np.random.default_rng(7)
    wrong = np.c_[np.arange(800), rng.permutation(800)]
    matches = np.vstack([pm.matches, wrong])
    truth = np.r_[np.ones(800, bool), wrong[:, 0] == wrong[:, 1]]
    scores = np.r_[rng.uniform(0, 0.6, 800), rng.uniform(0.3, 1.0, 800)]
    return run_filter(name, pm.kpts1, pm.kpts2, matches, scores), truth


def planted_similarity(n, outliers, seed):
    """``(x, y, matches)``: ``n`` one-to-one matches under a scaled translation with noise, the first
    ``outliers`` of them replaced by uniform points."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 600, (n, 2))
    y = x * 1.05 + (12.0, -7.0) + rng.normal(0, 0.5, (n, 2))
    y[:outliers] = rng.uniform(0, 600, (outliers, 2))
    return x, y, np.c_[np.arange(n), np.arange(n)]
