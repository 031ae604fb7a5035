"""Comparing the ground-truth methods A, B, C and D (Sec. 5.1, Appendix "Ground truth estimation methods").

:func:`method_groups` (the disjoint groups the Appendix figure ``setup_imgs`` colours; ``B ∩ D ⊆ C`` by
construction, so "B ∖ C" and "D ∖ C" never share a match), :func:`correct_per_pair` and
:func:`setup_rank_agreement` (Sec. 5.2: "for method C a similar ranking has been obtained").
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
        Labels of the same matches under methods "A" ... "D".
    scheme : {"BCD", "AD"}
        :data:`GROUP_SCHEMES`.

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
    """Index of the match with the largest ``error`` (NaN last) in each non-empty group."""
    error = np.asarray(error, np.float64)
    out = {}
    for name, mask in groups.items():
        idx = np.flatnonzero(mask)
        if len(idx):
            e = np.where(np.isnan(error[idx]), -np.inf, error[idx])
            out[name] = int(idx[np.argmax(e)])
    return out


def correct_per_pair(rows: pd.DataFrame, *, method: str = "blob", model: str = "none") -> pd.DataFrame:
    """Mean correct matches per pair of ``method`` and ``model``: index (kind, features), one column per
    ``gt_method`` of ``rows``, plus ``pairs``."""
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
    """Spearman correlation of the blob setups' ``value`` in two :func:`~ctxmatch_lib.report.blob.blob_map`
    tables, per feature block, with the best setup of each."""
    from scipy.stats import spearmanr

    m = map_a.merge(map_b, on=["features", "blob"], suffixes=("_a", "_b"))
    out = []
    for name, g in m.groupby("features", sort=False):
        rho = spearmanr(g[f"{value}_a"], g[f"{value}_b"]).statistic if len(g) > 1 else np.nan
        out.append({"features": name, "setups": len(g), "spearman": float(rho),
                    "best_a": g.loc[g[f"{value}_a"].idxmax(), "blob"], "best_b": g.loc[g[f"{value}_b"].idxmax(), "blob"]})
    return pd.DataFrame(out).set_index("features")
