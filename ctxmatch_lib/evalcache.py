"""Compatibility face: cached evaluation runs for the report notebooks (Fig. 7 ``pr_plot``, ``inl_plot``,
Tables 1-3).

The functions live in the evaluation engine, :mod:`ctxmatch_lib.evaluation`
(:func:`~ctxmatch_lib.evaluation.frontends.evaluate_cached`,
:func:`~ctxmatch_lib.evaluation.steps.resolve_filters`, ...); this module re-exports the names it used
to define, so ``from ctxmatch_lib.evalcache import evaluate_cached, select_pairs`` keeps working. One
Parquet part of result rows per (pair, feature setup, evaluation settings), shared with ``ctxmatch eval``
and ``ctxmatch sweep``; its key includes a digest of the library source that produces the numbers, so
editing a filter invalidates its results instead of serving stale ones.

``dtm1`` (DTM1 only) and ``dtm2`` (DTM1 + DTM2, the same as ``dtm``) are filter names everywhere (built-in
names of :data:`~ctxmatch_lib.filters.FILTERS`), so that Tables 1-3 can list both as the paper does;
``register_dtm_stages`` is kept as a no-op.
"""

from __future__ import annotations

import warnings

from .evaluation.cache import source_digest
from .evaluation.frontends import evaluate_cached
from .evaluation.plan import select_pairs
from .evaluation.steps import PAPER_FILTER_ORDER, register_dtm_stages, resolve_filters

__all__ = [
    "PAPER_FILTER_ORDER",
    "register_dtm_stages",
    "resolve_filters",
    "select_pairs",
    "source_digest",
    "evaluate_cached",
]

warnings.warn("ctxmatch_lib.evalcache is a compatibility face: import from ctxmatch_lib.evaluation instead",
              FutureWarning, stacklevel=2)
