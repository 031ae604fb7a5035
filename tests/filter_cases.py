"""Helpers shared by the filter tests (``test_filters.py``, ``test_filters_graph.py``): the common call
with its output checks, identity matches and the translated grid with one outlier."""

from __future__ import annotations

import numpy as np

from ctxmatch_lib.filters import FILTERS

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
