"""Compatibility face of the evaluation engine (``ctxmatch sweep``'s names before :mod:`ctxmatch_lib.evaluation`).

The engine now lives in :mod:`ctxmatch_lib.evaluation` (one module per job: ``plan``, ``cache``, ``unit``,
``run``, ``frontends``) and the sweep's tables in :mod:`ctxmatch_lib.report_blob`. This module re-exports
the names it used to define, so ``from ctxmatch_lib.sweep import run_sweep, blob_map`` and the README's
examples keep working; new code should import from the new places. It sits on top of the engine and the
report modules, and nothing inside ``ctxmatch_lib`` imports it.

Keypoints are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import warnings

from ._paths import write_parquet_atomic
from .evaluation.cache import source_digest
from .evaluation.frontends import run_sweep
from .evaluation.overlap import TabulatedContext as _SweepContext  # noqa: F401  (old private names)
from .evaluation.overlap import overlap_table as _overlap_table  # noqa: F401
from .evaluation.plan import (SweepUnit, plan_sweep, plan_units, resolve_blob_configs, resolve_features,
                              select_pairs)
from .evaluation.rows import SWEEP_COLUMNS
from .evaluation.rows import ranked_ap as _ranked_ap  # noqa: F401
from .evaluation.run import run_units
from .evaluation.unit import PairError, run_unit
from .report_blob import blob_map, heatmap_matrix

__all__ = [
    "SWEEP_COLUMNS",
    "PairError",
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

warnings.warn("ctxmatch_lib.sweep is a compatibility face: import from ctxmatch_lib.evaluation (the engine) and "
              "ctxmatch_lib.report_blob (blob_map, heatmap_matrix) instead",
              FutureWarning, stacklevel=2)
