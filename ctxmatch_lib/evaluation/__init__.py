"""The evaluation engine of Sec. 5: plan units, key and cache them, run them (here, joblib or Dask), collect rows.

Modules, each importing only those before it: ``steps``, ``cache``, ``rows``, ``overlap``, ``plan``, ``unit``
(one pair), ``run`` (many units), ``frontends`` (:func:`run_sweep`, :func:`evaluate_cached`). Every front end
shares its unit keys and cache (docs/evaluation.md).
"""

from .cache import source_digest
from .frontends import check_output, evaluate_cached, run_sweep
from .plan import SweepUnit, plan_sweep, plan_units, resolve_blob_configs, resolve_feature_configs, select_pairs
from .rows import SWEEP_COLUMNS
from .run import run_units
from .steps import PAPER_FILTER_ORDER, resolve_blobs, resolve_filters
from .unit import PairError, run_unit

__all__ = ["PAPER_FILTER_ORDER", "SWEEP_COLUMNS", "PairError", "SweepUnit", "check_output", "evaluate_cached",
           "plan_sweep", "plan_units", "resolve_blob_configs", "resolve_blobs", "resolve_feature_configs",
           "resolve_filters", "run_sweep", "run_unit", "run_units", "select_pairs", "source_digest"]
