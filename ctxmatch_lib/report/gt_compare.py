"""Comparing the ground-truth methods A, B, C and D (Sec. 5.1, Appendix "Ground truth estimation methods").

For the notebook ``fig_gt_methods``: :func:`method_groups`, the disjoint groups of matches the caption of
the Appendix figure ``setup_imgs`` colours; :func:`correct_per_pair`, mean correct matches per pair under
each method; :func:`setup_rank_agreement`, the Spearman correlation of the blob setups' mAP under two
methods (Sec. 5.2: "for method C a similar ranking has been obtained"). By construction
(:mod:`ctxmatch_lib.groundtruth`) ``C = B ∩ {centre <= 30 px}`` and D's centre rule implies C's, so
``B ∩ D ⊆ C``: the groups "B ∖ C" and "D ∖ C" never share a match.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

__all__ = ["GROUP_SCHEMES", "method_groups", "worst_in_groups", "correct_per_pair", "setup_rank_agreement"]

#: The caption's groupings: rows 1 and 4 of the figure compare B, C and D; row 3 compares A and D.
GROUP_SCHEMES = {
    "BCD": (("C ∩ D", ("C", "D"), ()), ("C ∖ D", ("C",), ("D",)), ("B ∖ C", ("B",), ("C",)),
            ("D ∖ C", ("D",), ("C",))),
    "AD": (("A ∩ D", ("A", "D"), ()), ("A ∖ D", ("A",), ("D",)), ("D ∖ A", ("D",), ("A",))),
}


def method_groups(labels: Mapping[str, np.ndarray], scheme: str = "BCD") -> dict[str, np.ndarray]:
    """Disjoint boolean masks of the matches, grouped as the Appendix figure's caption groups them.

    Parameters
    ----------
    labels : mapping of str to ndarray of shape (K,), bool
        Labels of the same K matches under the methods the scheme names ("A", "B", "C", "D").
    scheme : {"BCD", "AD"}
        ``"BCD"``: C ∩ D, C ∖ D, B ∖ C, D ∖ C (rows 1 and 4); ``"AD"``: A ∩ D, A ∖ D, D ∖ A (row 3).

    Returns
    -------
    dict of str to ndarray of shape (K,), bool
        In the scheme's order.

    Examples
    --------
    >>> import numpy as np
    >>> lab = {"B": np.array([1, 1, 0, 1], bool), "C": np.array([1, 0, 0, 0], bool),
    ...        "D": np.array([1, 0, 1, 0], bool)}
    >>> {k: np.flatnonzero(v).tolist() for k, v in method_groups(lab).items()}
    {'C ∩ D': [0], 'C ∖ D': [], 'B ∖ C': [1, 3], 'D ∖ C': [2]}
    """
    if scheme not in GROUP_SCHEMES:
        raise ValueError(f"scheme must be one of {tuple(GROUP_SCHEMES)}, got {scheme!r}")
    out = {}
    for name, inside, outside in GROUP_SCHEMES[scheme]:
        missing = [m for m in inside + outside if m not in labels]
        if missing:
            raise ValueError(f"labels lacks method(s) {missing} needed by scheme {scheme!r}")
        mask = np.logical_and.reduce([np.asarray(labels[m], bool) for m in inside])
        for m in outside:
            mask = mask & ~np.asarray(labels[m], bool)
        out[name] = mask
    return out


def worst_in_groups(groups: Mapping[str, np.ndarray], error) -> dict[str, int]:
    """Index of the match with the largest ``error`` in each non-empty group (the caption's "worst match
    according to the reprojection error"); NaN errors are never the worst unless all are NaN."""
    error = np.asarray(error, np.float64)
    out = {}
    for name, mask in groups.items():
        idx = np.flatnonzero(mask)
        if len(idx):
            e = np.where(np.isnan(error[idx]), -np.inf, error[idx])
            out[name] = int(idx[np.argmax(e)])
    return out


def correct_per_pair(rows: pd.DataFrame, *, method: str = "blob", model: str = "none") -> pd.DataFrame:
    """Mean correct matches per pair, per dataset kind, feature block and ground-truth method.

    ``rows`` are sweep rows of runs that differ by ``gt_method``, one blob setup per feature block;
    ``method`` and ``model`` select the rows counted (default: the blob candidates). Index (kind, features),
    one column per ground-truth method (A, B, C, D), plus ``pairs``.
    """
    need = {"kind", "features", "gt_method", "correct", "pair_id", "method", "model"}
    if missing := need - set(rows.columns):
        raise ValueError(f"rows lacks columns {sorted(missing)}")
    sel = rows[(rows["method"] == method) & (rows["model"] == model)]
    table = sel.pivot_table(index=["kind", "features"], columns="gt_method", values="correct", aggfunc="mean",
                            sort=False)
    table = table[sorted(table.columns)]
    table.columns.name = None
    pairs = sel.groupby(["kind", "features"], sort=False)["pair_id"].nunique()
    return table.assign(pairs=pairs.reindex(table.index).to_numpy())


def setup_rank_agreement(map_a: pd.DataFrame, map_b: pd.DataFrame, *, value: str = "mAP") -> pd.DataFrame:
    """Spearman rank correlation of the blob setups' ``value`` under two ground-truth methods, per block.

    ``map_a``, ``map_b`` are :func:`ctxmatch_lib.report.blob.blob_map` tables; one row per feature block:
    ``setups`` (compared), ``spearman`` and the best setup under each.
    """
    from scipy.stats import spearmanr

    m = map_a.merge(map_b, on=["features", "blob"], suffixes=("_a", "_b"))
    out = []
    for name, g in m.groupby("features", sort=False):
        rho = spearmanr(g[f"{value}_a"], g[f"{value}_b"]).statistic if len(g) > 1 else np.nan
        out.append({"features": name, "setups": len(g), "spearman": float(rho),
                    "best_a": g.loc[g[f"{value}_a"].idxmax(), "blob"], "best_b": g.loc[g[f"{value}_b"].idxmax(), "blob"]})
    return pd.DataFrame(out).set_index("features")
