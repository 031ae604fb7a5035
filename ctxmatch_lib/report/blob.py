"""Tables of a blob-matching sweep (Sec. 5.2): the mAP of every setup (:func:`blob_map`) and the heat-map
layout of Fig. 5 (:func:`heatmap_matrix`), which :mod:`ctxmatch_lib.plots.blob` draws."""

from __future__ import annotations

import math

__all__ = ["blob_map", "heatmap_matrix"]


def blob_map(df, *, metric: str = "ap_star", method: str = "blob", model: str = "none"):
    """mAP in % of every (features, blob setup), NaN APs skipped.

    ``metric="ap_star"`` (Fig. 5) measures against the correct matches of all setups, so a setup that misses
    some is penalised; ``"ap"`` against each setup's own, which rewards small, precise sets.
    """
    import pandas as pd

    if metric not in ("ap", "ap_star"):
        raise ValueError(f"metric must be 'ap' or 'ap_star', got {metric!r}")
    d = df[(df["method"] == method) & (df["model"] == model)]
    keys = ["features", "blob", "f", "prefilter", "f_prime", "ratio", "t_o", "t_o_kind", "combine"]
    g = d.groupby(keys, sort=False, dropna=False)[metric]
    return pd.DataFrame({"mAP": 100 * g.mean(), "pairs": g.count()}).reset_index()


def _f_label(f, prefilter) -> str:
    return "Ω" if f == "omega" else f"{f}{'∪' if prefilter == 'cup' else '∩'}"


def _t_o_label(t_o, kind) -> str:
    if t_o is None or (isinstance(t_o, float) and math.isnan(t_o)):
        return "∞"
    return f"{t_o:g}px" if kind == "px" else f"{100 * t_o:g}%"


_RATIO_LABEL = {"D>=": "D≥", "D+>=": "D+≥", "D+": "D+"}


def heatmap_matrix(maps, features: str | None = None):
    """The heat-map layout of Fig. 5 for one detector+descriptor: rows f × f', columns t_o × D × W.

    Parameters
    ----------
    maps : DataFrame
        :func:`blob_map` output.
    features : str, optional
        Required when ``maps`` holds several feature configurations.

    Returns
    -------
    DataFrame
        mAP in %, ``(f, f')`` rows and ``(t_o, D, W)`` columns in the grid order of Sec. 5.2.
    """
    import pandas as pd

    d = maps
    if features is None:
        names = list(dict.fromkeys(d["features"]))
        if len(names) != 1:
            raise ValueError(f"maps holds several feature configurations, pick one of {names}")
        features = names[0]
    d = d[d["features"] == features]
    if d.empty:
        raise ValueError(f"no rows for features {features!r}")
    from ..blob.config import COMBINES, GRID_F, GRID_T_O

    f_order = {_f_label(str(f), p): i for i, (f, p) in enumerate(GRID_F)}
    t_order = {_t_o_label(t, k): i for i, (t, k) in enumerate(GRID_T_O)}
    row_lab = [_f_label(f, p) for f, p in zip(d["f"], d["prefilter"])]
    col_t = [_t_o_label(t, k) for t, k in zip(d["t_o"], d["t_o_kind"])]
    tab = pd.DataFrame({"f": row_lab, "f'": d["f_prime"].to_numpy(), "t_o": col_t,
                        "D": [_RATIO_LABEL[r] for r in d["ratio"]], "W": d["combine"].to_numpy(),
                        "mAP": d["mAP"].to_numpy()})
    mat = tab.pivot(index=["f", "f'"], columns=["t_o", "D", "W"], values="mAP")
    r_order = {lab: i for i, lab in enumerate(_RATIO_LABEL.values())}
    w_order = {w: i for i, w in enumerate(COMBINES)}
    rows = sorted(mat.index, key=lambda r: (f_order.get(r[0], 99), r[1]))
    cols = sorted(mat.columns, key=lambda c: (t_order.get(c[0], 99), r_order[c[1]], w_order[c[2]]))
    return mat.loc[rows, cols]
