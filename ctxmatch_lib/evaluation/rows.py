"""Result rows of the engine: the columns, the typed frame, error rows, and the fast ranked AP.

Units and meaning of the columns: docs/evaluation.md (Result rows; Geometry after the model step).
"""

from __future__ import annotations

import numpy as np

from ..blob import BlobConfig
from ..metrics import ranked_area
from .steps import EPI_SHARE_AT_PX, POSE_COLUMNS

__all__ = ["SWEEP_COLUMNS", "GEOMETRY_COLUMNS", "INT_COLUMNS", "blob_record", "error_rows", "error_row", "frame",
           "ranked_ap", "ranked_aps"]

#: The columns of the model's accuracy, in :data:`SWEEP_COLUMNS` after ``model_time_s``.
GEOMETRY_COLUMNS = ("model_inliers", "corner_error", "epi_share_mean", *(f"epi_share_{t}" for t in EPI_SHARE_AT_PX),
                    *POSE_COLUMNS)

#: Columns of a sweep row, in order. Blob-setup fields are spelled out so results can be grouped by them.
SWEEP_COLUMNS = (
    "dataset", "pair_id", "kind", "features", "blob", "f", "prefilter", "f_prime", "ratio", "t_o", "t_o_kind",
    "combine", "method", "model", "run", "precision", "recall", "recall_star", "ap", "ap_star", "correct",
    "correct_norm", "output", "failure", "empty_output", "time_s", "model_time_s", *GEOMETRY_COLUMNS, "n_kpts1",
    "n_kpts2", "n_candidates", "n_gt", "n_gt_star", "gt_method", "error",
)


INT_COLUMNS = ("run", "f_prime", "correct", "correct_norm", "output", "n_kpts1", "n_kpts2", "n_candidates", "n_gt",
                "n_gt_star")


def blob_record(cfg: BlobConfig) -> dict:
    return {"blob": cfg.label, "f": str(cfg.f), "prefilter": cfg.prefilter, "f_prime": cfg.f_prime,
            "ratio": cfg.ratio, "t_o": np.nan if cfg.t_o is None else float(cfg.t_o), "t_o_kind": cfg.t_o_kind,
            "combine": cfg.combine}


def error_rows(unit, message: str, n: int = 0, m: int = 0) -> list[dict]:
    """Rows of a unit that could not be evaluated: NaN metrics, zero counts, ``error`` set."""
    return [error_row(unit, cfg, method, model, message, n, m)
            for cfg in unit.blobs for method in ("blob", *unit.filters, *unit.matchers) for model in unit.models]


def error_row(unit, cfg, method, model, message, n, m, **known) -> dict:
    pair = unit.pair
    nan = float("nan")
    row = {"dataset": pair.dataset or unit.dataset, "pair_id": pair.pair_id, "kind": pair.kind,
           "features": unit.features_name, **blob_record(cfg), "method": method, "model": model, "run": 0,
           "precision": nan, "recall": nan, "recall_star": nan, "ap": nan, "ap_star": nan, "correct": 0,
           "correct_norm": 0, "output": 0, "failure": False, "empty_output": False, "time_s": nan, "model_time_s": nan,
           **{c: nan for c in GEOMETRY_COLUMNS}, "n_kpts1": n, "n_kpts2": m, "n_candidates": 0, "n_gt": 0,
           "n_gt_star": 0, "gt_method": unit.gt_method, "error": message}
    row.update(known)
    return row


def frame(rows):
    """The rows as a ``pandas.DataFrame`` with :data:`SWEEP_COLUMNS` and their dtypes."""
    import pandas as pd

    floats = ("t_o", "precision", "recall", "recall_star", "ap", "ap_star", "time_s", "model_time_s",
              *GEOMETRY_COLUMNS)
    df = pd.DataFrame(rows, columns=list(SWEEP_COLUMNS))
    return df.astype({**dict.fromkeys(INT_COLUMNS, "int64"), "failure": "bool", "empty_output": "bool",
                      **dict.fromkeys(floats, "float64"), "error": "str"})


def ranked_ap(rows, cols, lab, scores, den: int, n: int, m: int) -> float:
    """:func:`~ctxmatch_lib.metrics.average_precision` with a precomputed reference size, in O(K log K);
    bit-identical to it (same arithmetic and tie order)."""
    return ranked_aps(rows, cols, lab, scores, (den,))[0]


def ranked_aps(rows, cols, lab, scores, dens) -> list[float]:
    """:func:`ranked_ap` against several reference sizes ``dens``, the ranked area computed once."""
    if all(den == 0 for den in dens):
        return [float("nan")] * len(dens)
    if len(lab) == 0:
        return [float("nan") if den == 0 else 0.0 for den in dens]
    area = ranked_area(rows, cols, lab, np.asarray(scores, np.float64))
    return [float("nan") if den == 0 else float(area / den) for den in dens]
