"""Tables and per-figure summaries of the result rows of :mod:`ctxmatch_lib.pipeline`: pure pandas.

The input everywhere is a results frame with the pipeline's columns (``pair_id``, ``kind``, ``blob``,
``method``, ``model``, ``precision``, ``recall``, ``recall_star``, ``correct``, ``output``, ``failure``,
``time_s``, ...; optionally ``features``), one row per (pair, feature setup, blob setup, method, model), as
written by ``ctxmatch eval`` or :func:`ctxmatch_lib.evaluation.evaluate_cached`.

- :func:`setup_rows` selects the rows of the paper's configurations (Sec. 5.3, :data:`SETUPS`): ``"global"``
  (every evaluated block, baseline and best blob setups), ``"baseline"``, ``"best"`` and ``"best-rootsgloh2"``.
- :func:`method_table` builds the analogue of Tables 1-3 (precision, recall, recall*, correct, output,
  failures, time per kind, model and method); :func:`markdown_table` renders it; :func:`paper_table` holds
  the paper's own Tables 1-3 for comparison; :func:`gt_counts` the numbers of their captions.
- :func:`with_inlier_ratio` and :func:`inlier_bin_table` give the inlier-ratio histograms of ``inl_plot``.
"""

from __future__ import annotations

import io
import math

import numpy as np
import pandas as pd

__all__ = [
    "METHOD_LABELS",
    "KIND_LABELS",
    "MODEL_LABELS",
    "SETUPS",
    "SETUP_TITLES",
    "PAPER_SETUP",
    "TABLE_COLUMNS",
    "method_label",
    "method_order",
    "setup_rows",
    "method_table",
    "gt_counts",
    "markdown_table",
    "paper_table",
    "PAPER_GT_COUNTS",
    "with_inlier_ratio",
    "inlier_bin_table",
]

#: Display names of the methods, as in the paper; models trained here and stand-ins say so in their name.
METHOD_LABELS = {
    "blob": "blob", "th": "th", "dtm": "DTM", "dtm1": "DTM$_1$", "dtm2": "DTM$_2$", "lmr": "LMR (trained here)",
    "lpm": "LPM", "glpm": "GLPM", "gms": "GMS", "vfc": "VFC", "llt": "LLT", "rfm_scan": "RFM-SCAN",
    "adalam": "AdaLAM", "oanet": "OANet (trained here)", "acne": "ACNe (trained here)", "pfm": "PFM",
    "pgm": "PGM", "scv": "SCV (stand-in)", "bm": "BM",
}
#: Row order of the paper's Tables 1-3.
_ORDER = ("blob", "th", "dtm", "dtm1", "dtm2", "lmr", "lpm", "glpm", "gms", "vfc", "llt", "rfm_scan", "adalam",
          "oanet", "acne", "pfm", "pgm", "scv", "bm")
KIND_LABELS = {"planar": "planar", "nonplanar": "non-planar", "depth": "depth (stereo)"}
MODEL_LABELS = {"none": "no model", "1sac": "1SAC", "ransac": "RANSAC"}

#: Row selections of the paper's three configurations (Sec. 5.3, Tables 1-3): column -> required value (or a
#: tuple of accepted values). "global" pools every evaluated feature block under the two blob setups the
#: configurations use (the paper: "averaging the results over all the considered detectors, descriptors and blob
#: matching setups"; its Table 1 counts, 3806 / 3834 candidates and 457 / 382 correct ones, lie near the means
#: of Tables 2 and 3, 3705 / 3652 and 463 / 393, which points to these two setups). "best" is Table 3's
#: HarrisZ + SOSNet (stand-in weights here) and "best-rootsgloh2" the same blob setup on HarrisZ + RootsGLOH2
#: (no stand-in), a second "best" column the paper does not have.
SETUPS = {
    "global": {"blob": ("baseline", "paper-best-overlap")},
    "baseline": {"blob": "baseline", "features": "sift-rootsift"},
    "best": {"blob": "paper-best-overlap", "features": "harrisz-sosnet"},
    "best-rootsgloh2": {"blob": "paper-best-overlap", "features": "harrisz-rootsgloh2"},
}
#: The paper's table each configuration is compared with.
PAPER_SETUP = {"global": "global", "baseline": "baseline", "best": "best", "best-rootsgloh2": "best"}
#: Honest titles: what each setting is here, and what the paper used.
SETUP_TITLES = {
    "global": "global: mean over every evaluated detector+descriptor block, baseline and best blob setups",
    "baseline": "baseline: SIFT+RootSIFT, one-to-one NNR (f = Ω, f' = 1, D≥, W = a)",
    "best": "best: HarrisZ+SOSNet (stand-in weights), f = 10∪, f' = 5, D+, t_o = 75 %, W = 2ab/(a+b)",
    "best-rootsgloh2": "best blob setup on HarrisZ+RootsGLOH2 (no stand-in), f = 10∪, f' = 5, D+, t_o = 75 %, "
                       "W = 2ab/(a+b)",
}
#: Columns of :func:`method_table`, as in the paper's tables.
TABLE_COLUMNS = ("precision (%)", "recall (%)", "recall* (%)", "correct", "output", "failures", "empty",
                 "time (s)")


def method_label(name: str) -> str:
    """Display name of a method (``"dtm2"`` -> ``"DTM$_2$"``); unknown names are returned unchanged.

    Examples
    --------
    >>> method_label("rfm_scan"), method_label("mine")
    ('RFM-SCAN', 'mine')
    """
    return METHOD_LABELS.get(name, name)


def method_order(names) -> list:
    """``names`` (distinct) in the paper's table order, unknown ones last in their given order.

    Examples
    --------
    >>> method_order(["adalam", "mine", "dtm2", "blob"])
    ['blob', 'dtm2', 'adalam', 'mine']
    """
    rank = {n: i for i, n in enumerate(_ORDER)}
    names = list(dict.fromkeys(names))
    return sorted(names, key=lambda n: (rank.get(n, len(rank)), names.index(n)))


def setup_rows(df: pd.DataFrame, setup="global") -> pd.DataFrame:
    """The rows of one setting: a name of :data:`SETUPS` or a dict column -> value (or a tuple of values).

    A required column that the frame lacks (``features`` in a ``ctxmatch eval`` file, which has one feature
    setup) is ignored.
    """
    if isinstance(setup, str) and setup not in SETUPS:
        raise ValueError(f"setup must be one of {list(SETUPS)} or a dict column -> value, got {setup!r}")
    cond = SETUPS[setup] if isinstance(setup, str) else dict(setup)
    mask = np.ones(len(df), bool)
    for col, value in cond.items():
        if col in df.columns:
            accepted = list(value) if isinstance(value, (tuple, list, set, frozenset)) else [value]
            mask &= df[col].isin(accepted).to_numpy()
    return df[mask]


def _config_keys(df: pd.DataFrame) -> list:
    return [c for c in ("features", "blob") if c in df.columns]


def method_table(df: pd.DataFrame, *, models=None, kinds=None) -> pd.DataFrame:
    """The analogue of the paper's Tables 1-3 for the given rows.

    Means over the rows of each (kind, model, method) group: precision, recall and recall* in %, correct
    and output match counts. An empty output enters the means as 0 % precision and 0 % recall (the
    paper's convention). ``failures`` is the number of pairs whose output is not empty but holds no correct
    match and ``empty`` the number of pairs with an empty output (the paper's failures are their sum),
    each divided by the number of (feature, blob) setups pooled in the group (so it is the plain count for
    one setup, and the mean count per setup for the global setting). Rows with an ``error`` (pairs that
    could not be evaluated) are left out; ``time (s)`` is the mean running time of
    the method itself, shown on the "no model" rows only (the paper's "--" on the 1SAC rows). ``pairs`` is
    the number of distinct pairs. Recall means skip NaN (pairs without any correct candidate).

    Parameters
    ----------
    df : DataFrame
        Result rows.
    models, kinds : sequence of str, optional
        Restrict and order the models / kinds (default: those present, kinds in the order planar,
        nonplanar, depth; models none, 1sac, ransac).

    Returns
    -------
    DataFrame
        Index (kind, model, method) with raw names, ordered as the paper (blob first); columns
        :data:`TABLE_COLUMNS` plus ``pairs``.
    """
    cols = list(TABLE_COLUMNS) + ["pairs"]
    if df.empty:
        return pd.DataFrame(columns=cols, index=pd.MultiIndex.from_tuples([], names=["kind", "model", "method"]))
    if kinds is None:
        present = list(dict.fromkeys(df["kind"]))
        known = [k for k in KIND_LABELS if k in present]
        kinds = known + [k for k in present if k not in known]
    kinds = list(kinds)
    models = [m for m in ("none", "1sac", "ransac") if m in set(df["model"])] if models is None else list(models)
    methods = method_order(df["method"])
    d = df[df["kind"].isin(kinds) & df["model"].isin(models)]
    if "error" in d.columns:
        d = d[d["error"].fillna("").astype(str) == ""]
    empty = d["empty_output"] if "empty_output" in d.columns else d["output"] == 0
    d = d.assign(_empty=empty, _failure=d["failure"] & ~empty)
    cfg = _config_keys(d)
    g = d.groupby(["kind", "model", "method"], sort=False)
    n_cfg = g[cfg].apply(lambda x: len(x.drop_duplicates())) if cfg else g.size() * 0 + 1
    out = pd.DataFrame({
        "precision (%)": 100 * g["precision"].mean(),
        "recall (%)": 100 * g["recall"].mean(),
        "recall* (%)": 100 * g["recall_star"].mean(),
        "correct": g["correct"].mean(),
        "output": g["output"].mean(),
        "failures": g["_failure"].sum() / n_cfg,
        "empty": g["_empty"].sum() / n_cfg,
        "time (s)": g["time_s"].mean(),
        "pairs": g["pair_id"].nunique(),
    })
    out.loc[out.index.get_level_values("model") != "none", "time (s)"] = np.nan
    order = pd.MultiIndex.from_product([kinds, models, methods], names=["kind", "model", "method"])
    return out.reindex(order).dropna(how="all")


def gt_counts(df: pd.DataFrame) -> pd.DataFrame:
    """Mean number of ground-truth matches per pair and kind, as in the captions of Tables 1-3:
    ``n_gt`` among the candidates of the blob setup (the recall reference) and ``n_gt_star`` among all the
    setups evaluated on the pair (the recall* reference). One row per kind."""
    d = df[(df["method"] == "blob") & (df["model"] == df["model"].iloc[0])] if len(df) else df
    return d.groupby("kind", sort=False)[["n_gt", "n_gt_star"]].mean()


def _fmt(value, fmt: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return format(value, fmt)


def markdown_table(table: pd.DataFrame, *, formats=None, labels: bool = True) -> str:
    """Render a :func:`method_table` (or any frame with a (kind, model, method) index) as a Markdown table.

    ``formats`` maps column -> format spec (default: 2 decimals for %, 0 for counts, 1 for failures, 3 for
    time). With ``labels`` the kind, model and method names are the paper's display names; repeated
    kind/model cells are left blank, as in the paper's tables.
    """
    fmts = {"precision (%)": ".2f", "recall (%)": ".2f", "recall* (%)": ".2f", "correct": ".0f", "output": ".0f",
            "failures": ".3g", "empty": ".3g", "time (s)": ".3f", "pairs": ".0f", "n": ".0f"}
    fmts.update(formats or {})
    names = list(table.index.names)
    head = names + list(table.columns)
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join([":--"] * len(names) + ["--:"] * len(table.columns)) + "|"]
    prev = (None,) * len(names)
    for idx, row in table.iterrows():
        idx = idx if isinstance(idx, tuple) else (idx,)
        shown = []
        for lvl, (name, value) in enumerate(zip(names, idx)):
            text = value
            if labels:
                text = {"kind": KIND_LABELS, "model": MODEL_LABELS}.get(name, {}).get(value, value)
                if name == "method":
                    text = method_label(value).replace("$_1$", "<sub>1</sub>").replace("$_2$", "<sub>2</sub>")
            shown.append("" if idx[: lvl + 1] == prev[: lvl + 1] and lvl < len(names) - 1 else str(text))
        prev = idx
        cells = [_fmt(row[c], fmts.get(c, ".4g")) for c in table.columns]
        lines.append("| " + " | ".join(shown + cells) + " |")
    return "\n".join(lines) + "\n"


#: Mean numbers of ground-truth matches per pair in the captions of the paper's Tables 1-3:
#: (planar, non-planar) for the recall reference (blob) and the recall* reference (all matches).
PAPER_GT_COUNTS = {
    "global": {"n_gt": (457, 382), "n_gt_star": (792, 602)},
    "baseline": {"n_gt": (293, 214), "n_gt_star": (740, 519)},
    "best": {"n_gt": (632, 572), "n_gt_star": (844, 685)},
}


def paper_table(setup: str | None = None) -> pd.DataFrame:
    """The paper's Tables 1-3 (Appendix "DTM evaluation"), transcribed: ``setup`` is ``"global"`` (Table 1),
    ``"baseline"`` (Table 2, SIFT+RootSIFT) or ``"best"`` (Table 3, HarrisZ+SOSNet); ``None`` gives all three
    with a ``setup`` column. Same layout as :func:`method_table` (kinds ``planar`` / ``nonplanar``, models
    ``none`` / ``1sac``, the paper's 18 methods); ``time (s)`` is NaN where the paper prints "--". The paper
    does not count empty outputs apart: its ``failures`` are pairs without a correct match, empty outputs
    included, and ``empty`` is NaN."""
    t = pd.read_csv(io.StringIO(_PAPER_TABLES_CSV))
    t = t.rename(columns={"precision": "precision (%)", "recall": "recall (%)", "recall_star": "recall* (%)",
                          "time_s": "time (s)"})
    t.insert(list(t.columns).index("failures") + 1, "empty", np.nan)
    if setup is not None:
        if setup not in PAPER_GT_COUNTS:
            raise ValueError(f"setup must be one of {list(PAPER_GT_COUNTS)}, got {setup!r}")
        t = t[t["setup"] == setup].drop(columns="setup")
        return t.set_index(["kind", "model", "method"])
    return t.set_index(["setup", "kind", "model", "method"])


def with_inlier_ratio(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with an ``inlier_ratio`` column: the precision of the unfiltered blob candidates (method
    ``blob``, model ``none``) of the same pair and setup, i.e. the share of correct candidates (Sec. 5.3: "blob
    matching precision gives an indication of the average inlier ratio")."""
    keys = ["pair_id"] + _config_keys(df)
    ref = df[(df["method"] == "blob") & (df["model"] == "none")][keys + ["precision"]]
    ref = ref.rename(columns={"precision": "inlier_ratio"}).drop_duplicates(keys)
    return df.drop(columns=["inlier_ratio"], errors="ignore").merge(ref, on=keys, how="left")


def inlier_bin_table(df: pd.DataFrame, bins=(0.0, 0.1, 0.2, 0.3, 0.5, 1.0)) -> pd.DataFrame:
    """Precision and recall by inlier-ratio bin (the histograms of ``inl_plot``).

    Parameters
    ----------
    df : DataFrame
        Result rows (with or without ``inlier_ratio``; it is added by :func:`with_inlier_ratio`).
    bins : sequence of float
        Increasing bin edges on the inlier ratio in [0, 1]; bins are closed on the left, the last one on
        both sides.

    Returns
    -------
    DataFrame
        Index (bin, model, method), bins labelled like ``"10-20 %"``; columns ``precision (%)``,
        ``recall (%)`` (means over the pairs and setups in the bin), ``n`` (how many) and ``share (%)``
        (the share of all (pair, setup) cases that fall in the bin, the same on every row of a bin). Empty
        bins are kept with NaN means, ``n`` = 0.
    """
    edges = np.asarray(bins, np.float64)
    if edges.ndim != 1 or len(edges) < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(f"bins must be at least two increasing edges, got {list(bins)}")
    d = with_inlier_ratio(df) if "inlier_ratio" not in df.columns else df
    labels = [f"{100 * a:g}-{100 * b:g} %" for a, b in zip(edges[:-1], edges[1:])]
    # Closed on the left; the last bin also takes its right edge.
    idx = np.searchsorted(edges, d["inlier_ratio"].to_numpy(), side="right") - 1
    idx = np.where(d["inlier_ratio"].to_numpy() == edges[-1], len(labels) - 1, idx)
    valid = (idx >= 0) & (idx < len(labels))
    d = d[valid].assign(bin=pd.Categorical(np.asarray(labels)[idx[valid]], categories=labels, ordered=True))
    models = [m for m in ("none", "1sac", "ransac") if m in set(d["model"])]
    methods = method_order(d["method"])
    g = d.groupby(["bin", "model", "method"], observed=False)
    out = pd.DataFrame({"precision (%)": 100 * g["precision"].mean(), "recall (%)": 100 * g["recall"].mean(),
                        "n": g.size()})
    cases = d[(d["method"] == "blob") & (d["model"] == "none")] if "blob" in methods else d.drop_duplicates(
        ["pair_id", *_config_keys(d)])
    share = 100 * cases.groupby("bin", observed=False).size() / max(len(cases), 1)
    order = pd.MultiIndex.from_product([labels, models, methods], names=["bin", "model", "method"])
    out = out.reindex(order)
    out["n"] = out["n"].fillna(0).astype(int)
    out["share (%)"] = share.reindex(labels).to_numpy().repeat(len(models) * len(methods))
    return out


# Tables 1-3 of the paper, transcribed from its LaTeX source (setup: Table 1 global, 2 baseline, 3 best).
_PAPER_TABLES_CSV = """\
setup,kind,model,method,precision,recall,recall_star,correct,output,failures,time_s
global,planar,none,blob,23.48,99.79,56.23,457,3806,0,
global,planar,none,th,90.29,61.21,36.49,310,370,0,0.000
global,planar,none,dtm1,78.78,67.84,40.05,356,593,1,0.283
global,planar,none,dtm2,79.82,78.85,45.84,399,651,0,0.519
global,planar,none,lmr,74.14,74.32,43.11,384,588,2,0.065
global,planar,none,lpm,69.05,49.26,27.99,259,362,4,0.017
global,planar,none,glpm,69.48,76.34,45.46,398,952,3,0.029
global,planar,none,gms,56.51,27.62,18.37,200,365,28,0.253
global,planar,none,vfc,78.91,89.48,51.52,440,781,4,0.031
global,planar,none,llt,46.39,52.47,31.63,298,591,28,1.665
global,planar,none,rfm_scan,57.71,92.84,52.65,438,1237,0,0.774
global,planar,none,adalam,93.11,78.23,46.40,395,542,3,0.226
global,planar,none,oanet,83.47,75.06,42.22,362,552,1,0.082
global,planar,none,acne,74.69,78.61,45.33,385,638,0,0.047
global,planar,none,pfm,85.40,36.39,21.79,180,195,8,0.114
global,planar,none,pgm,71.10,78.06,43.78,341,486,6,5.051
global,planar,none,scv,55.52,40.30,24.35,240,916,4,0.658
global,planar,none,bm,85.27,55.35,33.06,328,445,9,0.892
global,planar,1sac,blob,89.94,84.15,49.54,418,620,4,
global,planar,1sac,th,91.35,55.81,33.76,294,340,5,
global,planar,1sac,dtm1,89.68,60.72,36.57,333,482,5,
global,planar,1sac,dtm2,90.61,70.26,41.72,372,529,5,
global,planar,1sac,lmr,89.64,69.35,40.69,366,475,6,
global,planar,1sac,lpm,80.62,46.18,26.51,248,311,12,
global,planar,1sac,glpm,91.54,71.87,42.98,378,534,4,
global,planar,1sac,gms,59.58,26.73,17.79,193,316,29,
global,planar,1sac,vfc,89.56,83.11,48.39,417,614,5,
global,planar,1sac,llt,59.60,48.94,29.77,281,408,28,
global,planar,1sac,rfm_scan,93.43,84.57,49.13,414,612,2,
global,planar,1sac,adalam,94.41,75.59,44.86,380,513,3,
global,planar,1sac,oanet,91.95,70.67,40.21,346,472,4,
global,planar,1sac,acne,91.10,72.79,42.67,366,493,5,
global,planar,1sac,pfm,85.38,34.15,20.63,174,186,10,
global,planar,1sac,pgm,86.48,69.92,40.02,318,365,7,
global,planar,1sac,scv,78.80,37.10,22.55,228,277,14,
global,planar,1sac,bm,85.00,53.69,32.11,316,419,10,
global,nonplanar,none,blob,19.86,100.00,60.99,382,3834,0,
global,nonplanar,none,th,82.26,44.89,28.71,185,235,1,0.000
global,nonplanar,none,dtm1,73.01,64.77,41.34,269,501,0,0.271
global,nonplanar,none,dtm2,72.76,72.71,45.90,298,546,0,0.512
global,nonplanar,none,lmr,68.60,66.21,40.85,269,471,1,0.067
global,nonplanar,none,lpm,65.92,46.48,26.73,177,264,3,0.017
global,nonplanar,none,glpm,65.26,62.86,40.62,271,644,4,0.018
global,nonplanar,none,gms,69.98,29.54,20.40,161,304,21,0.251
global,nonplanar,none,vfc,58.20,81.63,51.75,345,897,6,0.037
global,nonplanar,none,llt,45.01,61.68,40.20,279,737,23,1.602
global,nonplanar,none,rfm_scan,54.03,92.71,57.27,365,1145,0,0.735
global,nonplanar,none,adalam,91.21,58.95,37.50,254,339,3,0.165
global,nonplanar,none,oanet,79.83,72.00,44.49,282,468,1,0.083
global,nonplanar,none,acne,65.47,70.86,43.98,281,564,0,0.047
global,nonplanar,none,pfm,82.27,28.81,18.46,112,125,8,0.100
global,nonplanar,none,pgm,67.62,80.37,50.02,312,539,1,7.119
global,nonplanar,none,scv,54.99,44.20,28.35,186,812,2,0.729
global,nonplanar,none,bm,86.24,53.59,35.00,244,351,5,0.729
global,nonplanar,1sac,blob,61.91,80.71,51.25,334,740,1,
global,nonplanar,1sac,th,88.80,40.77,26.46,172,204,2,
global,nonplanar,1sac,dtm1,85.08,58.01,37.57,248,394,2,
global,nonplanar,1sac,dtm2,84.92,64.78,41.50,273,427,1,
global,nonplanar,1sac,lmr,82.89,60.92,38.00,253,351,3,
global,nonplanar,1sac,lpm,77.19,43.01,24.93,167,218,6,
global,nonplanar,1sac,glpm,78.79,58.55,37.98,255,410,5,
global,nonplanar,1sac,gms,68.63,27.88,19.28,153,267,25,
global,nonplanar,1sac,vfc,73.39,74.14,47.31,318,573,7,
global,nonplanar,1sac,llt,59.41,56.94,37.28,260,463,24,
global,nonplanar,1sac,rfm_scan,74.42,81.51,51.33,333,631,1,
global,nonplanar,1sac,adalam,91.50,56.32,35.85,243,322,3,
global,nonplanar,1sac,oanet,83.33,66.98,41.65,267,409,1,
global,nonplanar,1sac,acne,75.58,66.27,41.41,267,440,1,
global,nonplanar,1sac,pfm,85.46,26.93,17.41,106,116,8,
global,nonplanar,1sac,pgm,80.59,72.88,45.76,290,402,2,
global,nonplanar,1sac,scv,76.81,40.53,26.25,173,265,4,
global,nonplanar,1sac,bm,86.28,51.35,33.56,234,325,7,
baseline,planar,none,blob,20.63,100.00,37.60,293,1329,0,
baseline,planar,none,th,85.02,61.62,25.99,212,227,1,0.000
baseline,planar,none,dtm1,84.23,63.99,25.69,228,244,2,0.168
baseline,planar,none,dtm2,85.19,77.91,31.02,265,284,2,0.240
baseline,planar,none,lmr,70.29,79.58,31.90,274,320,6,0.036
baseline,planar,none,lpm,71.61,74.84,29.54,266,311,3,0.008
baseline,planar,none,glpm,84.71,68.62,29.37,258,275,7,0.014
baseline,planar,none,gms,45.48,15.69,7.31,92,94,40,0.260
baseline,planar,none,vfc,87.12,89.57,34.56,282,298,4,0.019
baseline,planar,none,llt,40.34,39.94,16.89,190,227,37,0.485
baseline,planar,none,rfm_scan,59.56,94.78,35.96,283,482,0,0.075
baseline,planar,none,adalam,91.45,78.08,32.41,266,273,5,0.090
baseline,planar,none,oanet,85.96,81.80,30.78,248,267,2,0.043
baseline,planar,none,acne,77.48,84.92,33.13,266,313,0,0.023
baseline,planar,none,pfm,75.38,35.38,14.92,122,127,15,0.076
baseline,planar,none,pgm,78.24,84.82,32.65,259,283,7,2.759
baseline,planar,none,scv,84.15,47.13,19.92,198,209,6,0.445
baseline,planar,none,bm,83.91,57.48,24.36,238,245,11,0.532
baseline,planar,1sac,blob,81.07,75.11,31.20,263,270,12,
baseline,planar,1sac,th,82.39,52.84,23.18,200,205,12,
baseline,planar,1sac,dtm1,84.62,55.10,22.89,212,218,9,
baseline,planar,1sac,dtm2,85.61,67.27,27.75,246,252,8,
baseline,planar,1sac,lmr,85.78,72.99,29.78,259,265,9,
baseline,planar,1sac,lpm,82.44,68.23,27.84,252,259,12,
baseline,planar,1sac,glpm,86.70,66.24,28.44,248,254,9,
baseline,planar,1sac,gms,45.93,15.61,7.28,91,93,40,
baseline,planar,1sac,vfc,91.47,84.42,32.93,268,274,5,
baseline,planar,1sac,llt,48.31,38.39,16.29,183,188,37,
baseline,planar,1sac,rfm_scan,88.36,79.95,32.29,266,272,7,
baseline,planar,1sac,adalam,91.83,75.75,31.47,256,262,5,
baseline,planar,1sac,oanet,90.57,75.76,29.42,238,243,5,
baseline,planar,1sac,acne,90.40,76.44,31.08,252,257,6,
baseline,planar,1sac,pfm,74.92,32.62,14.02,118,121,18,
baseline,planar,1sac,pgm,81.96,73.75,29.46,238,245,12,
baseline,planar,1sac,scv,80.16,43.87,18.70,189,194,14,
baseline,planar,1sac,bm,78.92,55.83,23.72,230,236,15,
baseline,nonplanar,none,blob,16.41,100.00,38.91,214,1370,0,
baseline,nonplanar,none,th,75.17,53.09,22.95,130,155,2,0.000
baseline,nonplanar,none,dtm1,78.93,64.57,27.04,155,179,2,0.166
baseline,nonplanar,none,dtm2,78.08,75.28,31.30,178,209,2,0.241
baseline,nonplanar,none,lmr,64.29,76.50,31.95,182,257,4,0.040
baseline,nonplanar,none,lpm,67.36,74.63,31.33,180,240,2,0.008
baseline,nonplanar,none,glpm,82.37,60.41,27.19,161,180,4,0.010
baseline,nonplanar,none,gms,68.75,15.22,7.54,55,56,30,0.266
baseline,nonplanar,none,vfc,66.94,78.26,32.25,189,243,7,0.018
baseline,nonplanar,none,llt,45.50,53.14,23.45,154,227,28,0.531
baseline,nonplanar,none,rfm_scan,57.61,90.48,35.60,200,370,0,0.070
baseline,nonplanar,none,adalam,90.24,66.81,28.78,168,176,4,0.064
baseline,nonplanar,none,oanet,81.66,77.16,30.30,167,192,1,0.043
baseline,nonplanar,none,acne,67.16,75.56,30.78,175,242,1,0.023
baseline,nonplanar,none,pfm,75.95,35.13,15.53,83,91,12,0.075
baseline,nonplanar,none,pgm,75.23,88.81,36.34,204,256,2,3.732
baseline,nonplanar,none,scv,81.93,55.10,23.72,136,156,2,0.455
baseline,nonplanar,none,bm,85.25,61.61,26.68,163,177,6,0.424
baseline,nonplanar,1sac,blob,62.87,80.34,33.83,194,269,2,
baseline,nonplanar,1sac,th,85.52,47.78,21.33,124,132,4,
baseline,nonplanar,1sac,dtm1,87.61,58.72,25.18,147,157,2,
baseline,nonplanar,1sac,dtm2,87.23,69.04,29.26,169,182,2,
baseline,nonplanar,1sac,lmr,79.46,70.05,29.97,174,191,5,
baseline,nonplanar,1sac,lpm,82.10,70.23,29.89,174,192,3,
baseline,nonplanar,1sac,glpm,81.59,57.97,26.31,157,167,11,
baseline,nonplanar,1sac,gms,52.14,14.63,7.31,54,55,47,
baseline,nonplanar,1sac,vfc,78.29,74.22,30.87,181,201,8,
baseline,nonplanar,1sac,llt,56.95,50.47,22.39,148,169,29,
baseline,nonplanar,1sac,rfm_scan,76.32,79.06,32.86,189,225,1,
baseline,nonplanar,1sac,adalam,89.59,64.51,27.85,164,171,5,
baseline,nonplanar,1sac,oanet,85.30,73.76,29.32,163,178,1,
baseline,nonplanar,1sac,acne,77.22,72.62,29.86,170,202,1,
baseline,nonplanar,1sac,pfm,79.97,32.42,14.64,79,84,13,
baseline,nonplanar,1sac,pgm,83.54,81.13,33.78,191,214,3,
baseline,nonplanar,1sac,scv,86.84,51.50,22.49,130,139,3,
baseline,nonplanar,1sac,bm,86.15,60.41,26.25,160,170,7,
best,planar,none,blob,27.18,100.00,74.59,632,6081,0,
best,planar,none,th,95.17,66.38,50.93,449,758,0,0.000
best,planar,none,dtm1,76.75,77.48,59.05,526,1510,0,0.477
best,planar,none,dtm2,77.45,83.94,63.57,561,1592,0,0.902
best,planar,none,lmr,82.77,65.04,49.39,448,929,0,0.096
best,planar,none,lpm,79.02,39.27,30.69,288,684,0,0.026
best,planar,none,glpm,77.05,76.81,58.77,523,1518,0,0.062
best,planar,none,gms,72.71,54.69,43.07,433,1329,9,0.246
best,planar,none,vfc,79.13,95.09,71.88,626,1877,1,0.035
best,planar,none,llt,44.49,56.98,43.67,328,1354,26,3.583
best,planar,none,rfm_scan,60.18,92.96,69.89,610,2525,0,1.534
best,planar,none,adalam,92.98,80.22,61.24,536,1175,1,0.429
best,planar,none,oanet,86.50,78.58,58.77,525,1173,0,0.119
best,planar,none,acne,79.21,79.33,60.47,524,1308,0,0.067
best,planar,none,pfm,93.90,36.65,28.39,236,293,3,0.165
best,planar,none,pgm,68.78,72.63,54.10,420,728,5,4.974
best,planar,none,scv,21.14,45.54,35.79,353,2136,0,1.203
best,planar,none,bm,86.26,54.88,42.69,439,954,8,1.654
best,planar,1sac,blob,94.59,92.54,69.53,593,1527,1,
best,planar,1sac,th,96.75,63.42,48.66,431,715,1,
best,planar,1sac,dtm1,95.35,72.95,55.80,500,1211,1,
best,planar,1sac,dtm2,95.40,78.96,60.03,532,1278,1,
best,planar,1sac,lmr,94.13,60.04,45.79,417,793,2,
best,planar,1sac,lpm,91.31,36.40,28.60,270,577,4,
best,planar,1sac,glpm,95.24,73.16,56.10,498,1218,1,
best,planar,1sac,gms,82.35,51.73,40.84,410,1077,10,
best,planar,1sac,vfc,92.69,88.75,67.37,588,1510,2,
best,planar,1sac,llt,62.13,53.63,41.14,307,825,26,
best,planar,1sac,rfm_scan,94.69,86.62,65.54,574,1485,1,
best,planar,1sac,adalam,96.25,76.58,58.44,512,1085,1,
best,planar,1sac,oanet,94.94,74.08,55.64,500,1037,2,
best,planar,1sac,acne,92.35,74.60,57.12,499,1073,3,
best,planar,1sac,pfm,94.54,35.65,27.56,230,284,3,
best,planar,1sac,pgm,89.74,67.95,50.76,393,545,5,
best,planar,1sac,scv,81.88,41.76,32.89,335,548,12,
best,planar,1sac,bm,86.46,52.75,41.04,420,881,9,
best,nonplanar,none,blob,24.01,100.00,81.61,572,5933,0,
best,nonplanar,none,th,90.37,42.26,36.15,262,424,0,0.000
best,nonplanar,none,dtm1,70.25,71.38,59.59,432,1291,0,0.430
best,nonplanar,none,dtm2,70.25,75.44,62.88,455,1348,0,0.856
best,nonplanar,none,lmr,75.29,53.49,44.65,328,698,0,0.093
best,nonplanar,none,lpm,74.09,29.90,25.29,180,451,1,0.024
best,nonplanar,none,glpm,69.64,55.79,47.42,348,1002,3,0.032
best,nonplanar,none,gms,76.84,57.30,48.49,379,1131,5,0.237
best,nonplanar,none,vfc,57.76,86.87,72.55,535,2055,4,0.037
best,nonplanar,none,llt,40.50,57.53,49.15,376,1646,27,3.243
best,nonplanar,none,rfm_scan,52.30,95.06,77.99,557,2508,0,1.305
best,nonplanar,none,adalam,92.15,54.95,46.67,353,691,2,0.295
best,nonplanar,none,oanet,83.54,71.94,59.18,423,949,0,0.114
best,nonplanar,none,acne,69.94,67.33,55.65,396,1047,0,0.063
best,nonplanar,none,pfm,91.80,24.73,21.15,145,177,2,0.131
best,nonplanar,none,pgm,67.76,72.30,59.92,417,829,1,7.961
best,nonplanar,none,scv,22.66,40.03,34.16,248,1530,1,1.024
best,nonplanar,none,bm,88.58,51.39,44.14,349,737,4,1.261
best,nonplanar,1sac,blob,66.97,82.58,68.72,497,1624,0,
best,nonplanar,1sac,th,93.05,38.48,32.99,240,379,1,
best,nonplanar,1sac,dtm1,85.71,62.32,52.51,387,976,1,
best,nonplanar,1sac,dtm2,85.40,65.59,55.22,407,1018,0,
best,nonplanar,1sac,lmr,89.08,48.10,40.48,301,560,0,
best,nonplanar,1sac,lpm,85.54,27.57,23.47,169,375,3,
best,nonplanar,1sac,glpm,84.01,50.91,43.42,318,782,3,
best,nonplanar,1sac,gms,83.66,51.43,43.67,340,917,5,
best,nonplanar,1sac,vfc,74.84,75.19,63.26,472,1351,4,
best,nonplanar,1sac,llt,57.15,52.21,44.77,344,1002,27,
best,nonplanar,1sac,rfm_scan,75.16,80.64,67.08,489,1466,0,
best,nonplanar,1sac,adalam,92.85,50.94,43.32,324,628,2,
best,nonplanar,1sac,oanet,86.86,63.55,52.70,381,811,1,
best,nonplanar,1sac,acne,79.01,60.91,50.67,365,850,0,
best,nonplanar,1sac,pfm,92.89,23.17,19.84,137,165,2,
best,nonplanar,1sac,pgm,80.57,65.48,54.63,388,646,1,
best,nonplanar,1sac,scv,67.69,35.99,30.89,225,473,2,
best,nonplanar,1sac,bm,87.80,47.29,40.65,319,659,6,
"""
