"""The LMR filter (:func:`lmr_filter`): every match classified from its neighbourhood features."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._common import MatchSet, check_positive, match_filter
from ._network import load_network
from .features import MPC_SCALES, lmr_features, mpc_features
from .model import LMRModel, _shipped_model

__all__ = ["lmr_filter"]


@match_filter(label="LMR", merge="merge_coincident")
def lmr_filter(
    ms: MatchSet,
    *,
    threshold: float = 0.5,
    model: LMRModel | None = None,
    features: str = "mpc",
    network: str | Path | None = None,
) -> np.ndarray:
    """LMR: classify every match from its multi-scale neighbourhood features.

    %(parameters_unused)s
    threshold, model : float, default 0.5, and LMRModel, optional
        Inlier probability above which a match is kept; the classifiers (default: the shipped model).
    features : {"mpc", "lpm"}, default "mpc"
        :func:`mpc_features` in one pass, as the authors' code, or :func:`lmr_features` in two passes.
    network : path-like, optional
        The authors' ``Trained_Model/Net.mat`` (not shipped), classifying ``mpc_features(..., exact=True)``
        instead of ``model`` (first output above the second: inlier).
    %(merge_keep_coincident)s
    ``MPC.m`` counts every row, so there the copies of a wrong match are each other's shared neighbours.
    Agreement with the authors' code and with the paper's Table 2: ``docs/filters.md``.

    References
    ----------
    J. Ma et al., "LMR: learning a two-class classifier for mismatch removal", IEEE TIP 28(8), 2019.
    J. Ma et al., "Locality preserving matching", IJCV 127(5), 2019.
    """
    threshold = check_positive(threshold, "threshold", allow_zero=True)
    if features not in ("mpc", "lpm"):
        raise ValueError(f"features must be 'mpc' or 'lpm', got {features!r}")
    if network is not None:
        if features != "mpc":
            raise ValueError(f"network classifies the 'mpc' features; got features={features!r}")
        net = load_network(network, 3 * len(MPC_SCALES))
    model = _shipped_model() if model is None and network is None else model
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    # Rows best score first, ties by coordinates, the mask mapped back: equidistant neighbours (one image-1
    # keypoint in several candidates) are taken best first whatever the input order.
    order = np.lexsort((ms.y[:, 1], ms.y[:, 0], ms.x[:, 1], ms.x[:, 0], ms.scores))
    x, y = ms.x[order], ms.y[order]
    if network is not None:
        out = net.forward(mpc_features(x, y, exact=True))
        decided = out[:, 0] > out[:, 1]
    elif features == "mpc":
        decided = model.proba(3, mpc_features(x, y)) > threshold
    else:
        decided = model.proba(1, lmr_features(x, y)) > threshold
        if decided.sum() >= 2:
            decided = model.proba(2, lmr_features(x, y, np.flatnonzero(decided))) > threshold
    keep = np.empty(n, bool)
    keep[order] = decided
    return keep
