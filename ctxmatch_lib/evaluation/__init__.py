"""The evaluation engine: plan units, key and cache them, run them (here, with joblib or on Dask), collect rows.

One module per job, each importing only those listed before it (and the method modules below the engine):

* :mod:`~ctxmatch_lib.evaluation.steps`: the per-pair steps (features, blob candidates, filters, model,
  ground-truth labels) and the argument checks shared with the command line;
* :mod:`~ctxmatch_lib.evaluation.cache`: deterministic keys and atomic cache files;
* :mod:`~ctxmatch_lib.evaluation.rows`: the row columns, error rows, the fast ranked AP;
* :mod:`~ctxmatch_lib.evaluation.overlap`: FGINN by overlap, tabulated per image;
* :mod:`~ctxmatch_lib.evaluation.plan`: settings checked once, pairs selected, units keyed;
* :mod:`~ctxmatch_lib.evaluation.unit`: one unit (one pair, every setup, filter and model);
* :mod:`~ctxmatch_lib.evaluation.run`: many units, resumable, local or on Dask;
* :mod:`~ctxmatch_lib.evaluation.frontends`: :func:`run_sweep` (a grid) and :func:`evaluate_cached`
  (named presets), with :func:`check_output`.

``ctxmatch eval``, ``ctxmatch sweep``, :func:`ctxmatch_lib.pipeline.evaluate_dataset` and the report
notebooks all run here, with the same unit keys, so each reuses what the others computed.

Keypoints are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel.
"""

from .cache import source_digest
from .frontends import check_output, evaluate_cached, run_sweep
from .plan import SweepUnit, plan_sweep, plan_units, resolve_blob_configs, resolve_feature_configs, select_pairs
from .rows import SWEEP_COLUMNS
from .run import run_units
from .steps import PAPER_FILTER_ORDER, resolve_blobs, resolve_filters
from .unit import PairError, run_unit

__all__ = [
    "PAPER_FILTER_ORDER",
    "SWEEP_COLUMNS",
    "PairError",
    "SweepUnit",
    "check_output",
    "evaluate_cached",
    "plan_sweep",
    "plan_units",
    "resolve_blob_configs",
    "resolve_blobs",
    "resolve_feature_configs",
    "resolve_filters",
    "run_sweep",
    "run_unit",
    "run_units",
    "select_pairs",
    "source_digest",
]
