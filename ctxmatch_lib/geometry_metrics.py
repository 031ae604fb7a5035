"""Accuracy of an estimated two-view model against the ground truth, and its AUC over pairs.

:func:`homography_corner_error` (glue-factory's), :func:`epipolar_consistency` (the WxBS benchmark's share
of ground-truth correspondences consistent with F), :func:`pose_auc` (SuperGlue's AUC) and
:func:`geometry_table`. ``H`` maps image 1 to image 2, ``x2^T F x1 = 0``. See docs/evaluation.md.
"""

from __future__ import annotations

import math

import numpy as np

from ._numerics.docstrings import shared_doc
from ._numerics.validation import as_points
from .datasets.base import EpipolarGT, FlowGT, HomographyGT, PoseGT
from .geometry import epipolar_distances

__all__ = [
    "EPIPOLAR_THRESHOLDS_PX", "CORNER_AUC_THRESHOLDS_PX", "POSE_AUC_THRESHOLDS_DEG", "FLOW_SAMPLE_POINTS",
    "image_corners", "homography_corner_error", "symmetric_epipolar_distance", "epipolar_consistency",
    "gt_correspondences", "pose_auc", "time_to_geometry", "bootstrap_interval", "geometry_table",
    "paired_differences", "BOOTSTRAP_RESAMPLES", "BOOTSTRAP_SEED", "MIN_RESOLVING_PAIRS",
]

#: The thresholds of the epipolar consistency, in pixels: 1 ... 19 (WxBS's 0 gives 0 for any real estimate).
EPIPOLAR_THRESHOLDS_PX = np.arange(1, 20, dtype=np.float64)

#: The thresholds of the AUC of the corner error: glue-factory's HPatches ones (1, 3, 5 px) and 10 px.
CORNER_AUC_THRESHOLDS_PX = (1.0, 3.0, 5.0, 10.0)

#: The thresholds of the AUC of the pose error (degrees) that SuperGlue, LoFTR, glue-factory and fb82/MiHo report.
POSE_AUC_THRESHOLDS_DEG = (5.0, 10.0, 20.0)

#: Resamples and seed of the intervals of :func:`geometry_table` and :func:`paired_differences`.
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0

#: Fewer pairs than this never resolve a paired difference: a bootstrap over so few pairs has too few distinct
#: resamples for its interval to cover the pairs' variation.
MIN_RESOLVING_PAIRS = 5

#: How many correspondences :func:`gt_correspondences` samples from a dense ground truth.
FLOW_SAMPLE_POINTS = 2000


def image_corners(image_size) -> np.ndarray:
    """The four outer corners ``(4, 2)`` of a ``(width, height)`` image, clockwise from the top left.

    Examples
    --------
    >>> image_corners((4, 2))
    array([[-0.5, -0.5],
           [ 3.5, -0.5],
           [ 3.5,  1.5],
           [-0.5,  1.5]])
    """
    size = np.asarray(image_size, dtype=np.float64).reshape(-1)
    if size.shape != (2,) or not np.isfinite(size).all() or (size <= 0).any():
        raise ValueError(f"image_size must be (width, height) in pixels, got {image_size!r}")
    w, h = size
    return np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]) - 0.5


def homography_corner_error(H, H_gt, image_size) -> float:
    """Mean distance between the image-1 corners mapped by ``H`` and by ``H_gt``, in image-2 pixels.

    glue-factory's ``homography_corner_error`` (the HPatches metric) on the corners of :func:`image_corners`.

    Parameters
    ----------
    H : array_like of shape (3, 3) or None
        The estimate; ``None`` when there is no model (error ``inf``).
    H_gt : array_like of shape (3, 3)
    image_size : (int, int)
        (width, height) of image 1.

    Examples
    --------
    >>> import numpy as np
    >>> shift = np.array([[1.0, 0, 3], [0, 1, 4], [0, 0, 1]])
    >>> homography_corner_error(shift, np.eye(3), (640, 480))
    5.0
    """
    corners = image_corners(image_size)
    H_gt = _matrix(H_gt, "H_gt")
    if H is None:
        return float("inf")
    H = _matrix(H, "H")
    dx, dy = _map_by_products(H, corners) - _map_by_products(H_gt, corners)
    d = np.sqrt(dx * dx + dy * dy)
    if not np.isfinite(d).all():
        return float("inf")
    return float(d.mean())


def _map_by_products(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """``(2, N)`` points mapped by ``H``, one rounding per product and sum: a BLAS product's multiply-adds round
    by CPU (its kernel), and the corner error is a committed number. ``inf`` where a point maps to infinity."""
    x, y = pts[:, 0], pts[:, 1]
    u, v, w = (H[i, 0] * x + H[i, 1] * y + H[i, 2] for i in range(3))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.stack([u / w, v / w])
    out[:, ~np.isfinite(out).all(axis=0) | (np.abs(w) < 1e-12)] = np.inf
    return out


def _matrix(M, name: str) -> np.ndarray:
    M = np.asarray(M, dtype=np.float64)
    if M.shape != (3, 3):
        raise ValueError(f"{name} must be a 3x3 matrix, got shape {M.shape}")
    return M


@shared_doc
def symmetric_epipolar_distance(F, pts1, pts2) -> np.ndarray:
    """``sqrt(d1^2 + d2^2)`` of the two point-to-epipolar-line distances (``inf`` at an epipole).

    kornia's ``symmetrical_epipolar_distance(..., squared=False)``.

    Parameters
    ----------
    F : array_like of shape (3, 3)
    %(pts)s

    Examples
    --------
    >>> import numpy as np
    >>> F = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # a horizontal translation: lines y' = y
    >>> symmetric_epipolar_distance(F, [[0.0, 0.0], [5.0, 2.0]], [[3.0, 0.0], [1.0, 5.0]])
    array([0.        , 4.24264069])
    """
    d2, d1 = epipolar_distances(_matrix(F, "F"), pts1, pts2)
    return np.hypot(d1, d2)


@shared_doc
def epipolar_consistency(F, pts1, pts2, thresholds=EPIPOLAR_THRESHOLDS_PX) -> np.ndarray:
    """Share of ground-truth correspondences within each threshold of ``F``'s epipolar lines (WxBS's score);
    NaN without correspondences.

    Parameters
    ----------
    F : array_like of shape (3, 3) or None
        The estimate; ``None`` when there is no model (every share 0).
    %(pts)s
    thresholds : array_like of shape (T,)
        In pixels.

    Examples
    --------
    >>> import numpy as np
    >>> F = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    >>> epipolar_consistency(F, [[0, 0], [5, 2]], [[3, 0], [1, 5]], thresholds=[1, 5])
    array([0.5, 1. ])
    """
    pts1 = as_points(pts1, "pts1")
    pts2 = as_points(pts2, "pts2", n=len(pts1))
    th = np.asarray(thresholds, dtype=np.float64).reshape(-1)
    if len(pts1) == 0:
        return np.full(len(th), np.nan)
    if F is None:
        return np.zeros(len(th))
    d = symmetric_epipolar_distance(F, pts1, pts2)
    return (d[:, None] <= th[None, :]).mean(axis=0)


def gt_correspondences(gt, *, max_points: int = FLOW_SAMPLE_POINTS):
    """Ground-truth correspondences to score F on: ``EpipolarGT``'s points, up to ``max_points`` evenly spaced
    known pixels of a ``FlowGT`` and their targets, or ``None`` (``HomographyGT``, ``PoseGT``)."""
    if isinstance(gt, EpipolarGT):
        return np.asarray(gt.pts1, np.float64), np.asarray(gt.pts2, np.float64)
    if isinstance(gt, (HomographyGT, PoseGT)):
        return None
    if not isinstance(gt, FlowGT):
        raise TypeError(f"gt must be HomographyGT, EpipolarGT or FlowGT, got {type(gt).__name__}")
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) or max_points < 1:
        raise ValueError(f"max_points must be a positive integer, got {max_points!r}")
    flow = np.asarray(gt.flow12, np.float64)
    known = np.flatnonzero(np.isfinite(flow).all(axis=2).reshape(-1))
    if len(known) > max_points:
        known = known[np.unique(np.round(np.linspace(0, len(known) - 1, int(max_points))).astype(np.int64))]
    row, col = np.divmod(known, flow.shape[1])
    pts1 = np.c_[col, row].astype(np.float64)
    return pts1, pts1 + flow.reshape(-1, 2)[known]


def pose_auc(errors, thresholds) -> np.ndarray:
    """Area under the cumulative error curve up to each threshold, divided by the threshold.

    SuperGlue's ``pose_auc``: every pair stays in the denominator (NaN counts as ``inf``); NaN without pairs.

    Parameters
    ----------
    errors : array_like of shape (N,)
        Non-negative, one per pair (``inf`` for a failure).
    thresholds : array_like of shape (T,)
        Positive.

    Examples
    --------
    >>> pose_auc([0.0, 2.0, float("inf"), 1.0], [1.0, 2.0])
    array([0.25  , 0.4375])
    """
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    th = np.asarray(thresholds, dtype=np.float64).reshape(-1)
    if (th <= 0).any() or not np.isfinite(th).all():
        raise ValueError(f"thresholds must be positive and finite, got {th.tolist()}")
    if (e < 0).any():
        raise ValueError("errors must be non-negative (inf or NaN for a pair without a model)")
    n = len(e)
    if n == 0:
        return np.full(len(th), np.nan)
    e = np.sort(np.where(np.isnan(e), np.inf, e))
    out = np.empty(len(th))
    for i, t in enumerate(th):
        k = int(np.searchsorted(e, t, side="left"))  # pairs with an error below t
        x = np.r_[0.0, e[:k], t]
        r = np.r_[0.0, np.arange(1, k + 1) / n, k / n]
        out[i] = np.sum(np.diff(x) * (r[1:] + r[:-1])) / 2.0 / t
    return out


def time_to_geometry(rows, *, standalone=("blob", "opencv_ratio", "opencv_mnn")):
    """Seconds from the features to the model per row: ``time_s + model_time_s``, plus the ``blob`` row's
    ``time_s`` for a filter (not for ``standalone`` methods); NaN for model ``none``."""
    keys = ["dataset", "pair_id", "features", "blob"]
    blob_time = rows[rows["method"] == "blob"].groupby(keys)["time_s"].first().rename("_blob_time_s")
    base = rows[keys].join(blob_time, on=keys)["_blob_time_s"].where(~rows["method"].isin(standalone), 0.0)
    total = rows["time_s"] + rows["model_time_s"] + base
    return total.where(rows["model"] != "none")


def _auc_sorted(e: np.ndarray, t: float) -> np.ndarray:
    """:func:`pose_auc` at ``t`` of each row of ``e`` (B, M), sorted ascending (``inf`` for a failure)."""
    m = e.shape[1]
    below = e < t
    k = below.sum(axis=1)
    prev = np.concatenate([np.zeros((len(e), 1)), e[:, :-1]], axis=1)
    with np.errstate(invalid="ignore"):
        steps = np.where(below, e - prev, 0.0)
    area = steps @ ((2 * np.arange(1, m + 1) - 1) / (2 * m)) if m else np.zeros(len(e))
    last = np.take_along_axis(e, np.maximum(k - 1, 0)[:, None], axis=1)[:, 0] if m else np.zeros(len(e))
    area += (t - np.where(k > 0, last, 0.0)) * k / max(m, 1)
    return area / t


def _statistic(values: np.ndarray, auc_at: float | None) -> np.ndarray:
    """Each row's statistic in %: the mean of ``values`` (B, M), or their AUC at ``auc_at`` (no NaN)."""
    if auc_at is None:
        return 100 * values.mean(axis=1)
    return 100 * _auc_sorted(np.sort(values, axis=1), auc_at)


def _by_pair(g, column: str):
    """``column`` of rows ``g`` as a (pairs, runs) array, pairs and runs sorted, NaN where a run is missing, and
    the number of runs of each pair. Rows where ``column`` is NaN are left out."""
    g = g[g[column].notna()]
    if g.empty:
        return np.empty((0, 1)), np.zeros(0, np.int64)
    keys = list(zip(g["dataset"], g["pair_id"]))
    pairs = sorted(set(keys))
    index = {p: i for i, p in enumerate(pairs)}
    rank = g.assign(_p=[index[k] for k in keys]).sort_values(["_p", "run"], kind="stable")
    counts = np.bincount(rank["_p"].to_numpy(), minlength=len(pairs))
    out = np.full((len(pairs), counts.max()), np.nan)
    col = np.concatenate([np.arange(c) for c in counts])
    out[rank["_p"].to_numpy(), col] = rank[column].to_numpy(np.float64)
    return out, counts


def _resamples(counts: np.ndarray, n_resamples: int, seed: int, runs: int):
    """Two-stage bootstrap indices: pairs drawn with replacement, then ``runs`` runs within each drawn pair
    (among its own), (B, P) and (B, P, runs); a fixed ``seed``, so an interval repeats."""
    rng = np.random.default_rng(seed)
    n = len(counts)
    pi = rng.integers(0, n, (n_resamples, n))
    si = np.floor(rng.random((n_resamples, n, runs)) * counts[pi][..., None]).astype(np.int64)
    return pi, si


def bootstrap_interval(values, counts=None, *, auc_at: float | None = None, confidence: float = 0.95,
                       n_resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED):
    """The 95 % (``confidence``) percentile bootstrap interval of a statistic over pairs and runs, in %.

    Pairs are resampled with replacement, then runs within each drawn pair (a two-stage bootstrap: the pairs
    and the estimator's seeds both vary); the statistic is the mean of the values pooled over pairs and runs,
    or (``auc_at``) :func:`pose_auc` of the pooled errors at ``auc_at``.

    Parameters
    ----------
    values : array_like of shape (P, R)
        One row per pair, one column per run; NaN pads a pair with fewer runs (``counts``).
    counts : array_like of shape (P,), optional
        Runs of each pair (default: its non-NaN values, which must come first).

    Returns
    -------
    tuple of float
        ``(lo, hi)``; NaN without pairs.

    Examples
    --------
    >>> lo, hi = bootstrap_interval(np.full((10, 3), 0.5))
    >>> float(lo), float(hi)
    (50.0, 50.0)
    """
    v = np.atleast_2d(np.asarray(values, dtype=np.float64))
    counts = (~np.isnan(v)).sum(axis=1) if counts is None else np.asarray(counts, np.int64)
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
    if len(v) == 0 or v.size == 0 or (counts < 1).any():
        return float("nan"), float("nan")
    pi, si = _resamples(counts, n_resamples, seed, v.shape[1])
    stats = _statistic(v[pi[..., None], si].reshape(n_resamples, -1), auc_at)
    lo, hi = np.quantile(stats, [(1 - confidence) / 2, (1 + confidence) / 2])
    return float(lo), float(hi)


def _fitted(rows):
    """The rows with a model and no error, with a ``run`` column (0 where the rows have none)."""
    if "run" not in rows.columns:
        rows = rows.assign(run=0)
    return rows[(rows["model"] != "none") & (rows["error"] == "")]


def _metrics(rows, thresholds, pose_thresholds) -> list[tuple[str, str, float | None]]:
    """``(name, row column, AUC threshold or None for a mean)`` of each metric of :func:`geometry_table`."""
    shares = [c for c in rows.columns if c.startswith("epi_share_")]
    return [*((f"auc_{t:g}px", "corner_error", float(t)) for t in thresholds), *((c, c, None) for c in shares),
            *((f"auc_{t:g}deg", "pose_err", float(t)) for t in pose_thresholds)]


def geometry_table(rows, *, by=("kind", "blob", "method", "model"), thresholds=CORNER_AUC_THRESHOLDS_PX,
                   pose_thresholds=POSE_AUC_THRESHOLDS_DEG, confidence: float = 0.95,
                   n_resamples: int = BOOTSTRAP_RESAMPLES):
    """The model's accuracy over pairs and runs, per group of ``by`` columns, with bootstrap intervals.

    Parameters
    ----------
    rows : pandas.DataFrame
        Evaluation rows; those with model ``none`` or an ``error`` are left out. A random model step's runs
        (column ``run``) are pooled: every (pair, run) error enters the AUC, every share the mean.
    by : sequence of str
    thresholds : sequence of float
        Of the AUC of the corner error, in pixels.
    pose_thresholds : sequence of float
        Of the AUC of the pose error, in degrees.
    confidence, n_resamples
        Of the intervals (:func:`bootstrap_interval`, pairs then runs resampled, a fixed seed).

    Returns
    -------
    pandas.DataFrame
        Indexed by ``by``: ``pairs``, ``runs`` (per pair, at most), then per metric its value ``<m>_pct`` and
        interval ``<m>_lo``, ``<m>_hi``: ``auc_<t>px`` (planar), ``epi_share_*`` (other kinds),
        ``auc_<t>deg`` (calibrated), all in %; ``no_model`` (fits, over pairs and runs, without a model); mean
        and median :func:`time_to_geometry`.
    """
    import pandas as pd

    by = list(by)
    ok = _fitted(rows).copy()
    ok["_t"] = time_to_geometry(rows).loc[ok.index]
    metrics = _metrics(ok, thresholds, pose_thresholds)
    out = []
    for key, g in ok.groupby(by, sort=False):
        rec = dict(zip(by, key if isinstance(key, tuple) else (key,)))
        rec["pairs"] = len(set(zip(g["dataset"], g["pair_id"])))
        rec["runs"] = int(g.groupby(["dataset", "pair_id"])["run"].nunique().max())
        for name, column, auc_at in metrics:
            values, counts = _by_pair(g, column) if column in g.columns else (None, [])
            if not len(counts):
                rec.update({f"{name}_pct": np.nan, f"{name}_lo": np.nan, f"{name}_hi": np.nan})
                continue
            pooled = g.loc[g[column].notna(), column]
            rec[f"{name}_pct"] = 100 * (pooled.mean() if auc_at is None else pose_auc(pooled.to_numpy(), [auc_at])[0])
            rec[f"{name}_lo"], rec[f"{name}_hi"] = bootstrap_interval(values, counts, auc_at=auc_at,
                                                                      confidence=confidence, n_resamples=n_resamples)
        rec["no_model"] = int((g["model_inliers"] == 0).sum())
        rec["geometry_time_s"] = g["_t"].mean()
        rec["geometry_time_median_s"] = g["_t"].median()
        out.append(rec)
    cols = [*by, "pairs", "runs", *(f"{name}_{s}" for name, _, _ in metrics for s in ("pct", "lo", "hi")),
            "no_model", "geometry_time_s", "geometry_time_median_s"]
    return pd.DataFrame(out, columns=cols).set_index(by)


def paired_differences(rows, *, references=("th", "dtm2"), by=("kind", "blob", "model"), metrics=None,
                       confidence: float = 0.95, n_resamples: int = BOOTSTRAP_RESAMPLES):
    """Each method against each of ``references`` on the same pairs and runs: the mean paired difference of a
    metric with its bootstrap interval, and whether the interval excludes 0.

    Parameters
    ----------
    rows : pandas.DataFrame
        Evaluation rows, as :func:`geometry_table`; a method and a reference are compared on the (pair, run)
        rows both have.
    references : sequence of str
        Methods compared against (those absent from a group are skipped).
    by : sequence of str
        The groups (``method`` is not one of them).
    metrics : sequence of str, optional
        Metric names of :func:`geometry_table` (``auc_5px``, ``epi_share_mean``, ``auc_5deg``, ...); default:
        ``auc_5px``, ``epi_share_mean`` and ``auc_5deg``, each where its rows have values.
    confidence, n_resamples
        As :func:`geometry_table`; both sides are resampled with the same pairs and runs.

    Returns
    -------
    pandas.DataFrame
        One row per (``by``, method, reference, metric): ``pairs``, ``runs``, ``value`` and ``reference_value``
        (% as :func:`geometry_table`), ``difference``, ``lo``, ``hi`` and ``resolved`` (the interval excludes 0,
        over at least :data:`MIN_RESOLVING_PAIRS` pairs).
    """
    import pandas as pd

    by = list(by)
    ok = _fitted(rows)
    chosen = list(metrics) if metrics is not None else ["auc_5px", "epi_share_mean", "auc_5deg"]
    known = {m: (m, None) if m.startswith("epi_share_") else _auc_metric(m) for m in chosen}
    out = []
    for key, g in ok.groupby(by, sort=False):
        group = dict(zip(by, key if isinstance(key, tuple) else (key,)))
        present = list(dict.fromkeys(g["method"]))
        for name in chosen:
            column, auc_at = known[name]
            if column not in g.columns or g[column].isna().all():
                continue
            for ref in (r for r in references if r in present):
                for method in (m for m in present if m != ref):
                    rec = _paired(g, method, ref, column, auc_at, confidence, n_resamples)
                    if rec is not None:
                        out.append({**group, "method": method, "reference": ref, "metric": name, **rec})
    cols = [*by, "method", "reference", "metric", "pairs", "runs", "value", "reference_value", "difference", "lo",
            "hi", "resolved"]
    return pd.DataFrame(out, columns=cols)


def _auc_metric(name: str) -> tuple[str, float]:
    """``(column, threshold)`` of a metric ``auc_<t>px`` or ``auc_<t>deg``, any positive ``t``."""
    unit = "px" if name.endswith("px") else "deg" if name.endswith("deg") else None
    try:
        t = float(name[len("auc_"):-len(unit)]) if name.startswith("auc_") else None
    except (TypeError, ValueError):
        t = None
    if t is None or not (math.isfinite(t) and t > 0):
        raise ValueError(f"metrics must be auc_<t>px, auc_<t>deg or epi_share_* (geometry_table's), got {name!r}")
    return ("corner_error" if unit == "px" else "pose_err"), t


def _paired(g, method, ref, column, auc_at, confidence, n_resamples) -> dict | None:
    """:func:`paired_differences`' record of one method against one reference (None: no common rows)."""
    a = g[g["method"] == method]
    b = g[g["method"] == ref]
    common = a[["dataset", "pair_id", "run", column]].merge(b[["dataset", "pair_id", "run", column]],
                                                            on=["dataset", "pair_id", "run"], suffixes=("", "_ref"))
    common = common[common[column].notna() & common[f"{column}_ref"].notna()]
    if common.empty:
        return None
    va, counts = _by_pair(common, column)
    vb, _ = _by_pair(common.drop(columns=column).rename(columns={f"{column}_ref": column}), column)
    pi, si = _resamples(counts, n_resamples, BOOTSTRAP_SEED, va.shape[1])
    diff = (_statistic(va[pi[..., None], si].reshape(n_resamples, -1), auc_at)
            - _statistic(vb[pi[..., None], si].reshape(n_resamples, -1), auc_at))
    lo, hi = np.quantile(diff, [(1 - confidence) / 2, (1 + confidence) / 2])
    value = _statistic(va[~np.isnan(va)][None], auc_at)[0]
    reference = _statistic(vb[~np.isnan(vb)][None], auc_at)[0]
    return {"pairs": len(counts), "runs": int(counts.max()), "value": value, "reference_value": reference,
            "difference": value - reference, "lo": float(lo), "hi": float(hi),
            "resolved": bool((lo > 0 or hi < 0) and len(counts) >= MIN_RESOLVING_PAIRS)}
