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

import math
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = [
    "METHOD_LABELS",
    "KIND_LABELS",
    "FEATURE_LABELS",
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
    "GEOMETRY_TIME_COLUMNS",
    "geometry_markdown",
]

#: Display names of the methods, as in the paper; models trained here and stand-ins say so in their name.
METHOD_LABELS = {
    "blob": "blob", "th": "th", "dtm": "DTM", "dtm1": "DTM$_1$", "dtm2": "DTM$_2$", "lmr": "LMR (trained here)",
    "lpm": "LPM", "glpm": "GLPM", "gms": "GMS", "vfc": "VFC", "llt": "LLT", "rfm_scan": "RFM-SCAN",
    "adalam": "AdaLAM", "oanet": "OANet (trained here)", "acne": "ACNe (trained here)", "pfm": "PFM",
    "pgm": "PGM", "scv": "SCV (stand-in)", "bm": "BM",
    "opencv_ratio": "OpenCV ratio 0.8", "opencv_mnn": "OpenCV MNN",  # the matchers a user would pick instead
}
#: Row order of the paper's Tables 1-3.
_ORDER = ("blob", "th", "dtm", "dtm1", "dtm2", "lmr", "lpm", "glpm", "gms", "vfc", "llt", "rfm_scan", "adalam",
          "oanet", "acne", "pfm", "pgm", "scv", "bm", "opencv_ratio", "opencv_mnn")
#: Short names of the feature presets for titles and tables; the stand-ins say so (full lines:
#: :data:`ctxmatch_lib.features.FEATURE_DESCRIPTIONS`).
FEATURE_LABELS = {
    "sift-rootsift": "SIFT+RootSIFT", "sift-rootsift-upright": "upright SIFT+RootSIFT", "sift": "SIFT+SIFT",
    "sift-rootsgloh2": "SIFT+RootsGLOH2", "harrisz-rootsift": "HarrisZ+RootSIFT",
    "harrisz-rootsgloh2": "HarrisZ+RootsGLOH2", "sift-hardnet2": "SIFT+HardNet2 (stand-in)",
    "sift-sosnet": "SIFT+SOSNet (stand-in)", "harrisz-hardnet2": "HarrisZ+HardNet2 (stand-in)",
    "harrisz-sosnet": "HarrisZ+SOSNet (stand-in)",
}
KIND_LABELS = {"planar": "planar", "nonplanar": "non-planar", "depth": "depth (stereo)", "calibrated": "calibrated"}
MODEL_LABELS = {"none": "no model", "1sac": "1SAC", "ransac": "RANSAC", "prosac": "PROSAC", "magsac": "MAGSAC",
                "essential": "MAGSAC on E"}

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


def _fmt(value, fmt: str, missing: str = "–") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return missing
    return value if isinstance(value, str) else format(value, fmt)


def markdown_table(table: pd.DataFrame, *, formats=None, labels: bool = True, blank_repeats: bool = True,
                   missing: str = "–") -> str:
    """Render a :func:`method_table` (or any frame with a (kind, model, method) index) as a Markdown table.

    Parameters
    ----------
    table : DataFrame
        One row per table row; every index level becomes a left-aligned column, every column a right-aligned
        one.
    formats : dict, optional
        Column -> format spec (default: 2 decimals for %, 0 for counts, 3 significant digits for failures,
        3 decimals for time, ``.4g`` for any other column).
    labels : bool
        Show the kind, model and method names as the paper's display names.
    blank_repeats : bool
        Leave an index cell blank where it repeats the row above (every level but the last), as in the
        paper's tables.
    missing : str
        The cell of a missing (NaN) value.

    Returns
    -------
    str
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
            repeated = blank_repeats and idx[: lvl + 1] == prev[: lvl + 1] and lvl < len(names) - 1
            text = value
            if labels:
                text = {"kind": KIND_LABELS, "model": MODEL_LABELS}.get(name, {}).get(value, value)
                if name == "method":
                    text = method_label(value).replace("$_1$", "<sub>1</sub>").replace("$_2$", "<sub>2</sub>")
            shown.append("" if repeated else str(text))
        prev = idx
        cells = [_fmt(row[c], fmts.get(c, ".4g"), missing) for c in table.columns]
        lines.append("| " + " | ".join(shown + cells) + " |")
    return "\n".join(lines) + "\n"


#: The paper's Tables 1-3 and caption counts, parsed from its LaTeX source by ``python -m
#: ctxmatch_lib.report.paper TEX`` (:func:`ctxmatch_lib.report.paper.parse_paper_tables`), shipped as package data.
_PAPER_DATA = Path(__file__).resolve().parents[1] / "data"
_PAPER_TABLES_CSV = _PAPER_DATA / "paper_tables.csv"
_PAPER_GT_COUNTS_CSV = _PAPER_DATA / "paper_gt_counts.csv"


def _read_gt_counts() -> dict:
    c = pd.read_csv(_PAPER_GT_COUNTS_CSV)
    kinds = ("planar", "nonplanar")
    return {setup: {col: tuple(int(g.set_index("kind").loc[k, col]) for k in kinds)
                    for col in ("n_gt", "n_gt_star")}
            for setup, g in c.groupby("setup", sort=False)}


#: Mean numbers of ground-truth matches per pair in the captions of the paper's Tables 1-3:
#: (planar, non-planar) for the recall reference (blob) and the recall* reference (all matches).
PAPER_GT_COUNTS = _read_gt_counts()


def paper_table(setup: str | None = None) -> pd.DataFrame:
    """The paper's Tables 1-3 (Appendix "DTM evaluation"): ``setup`` is ``"global"`` (Table 1),
    ``"baseline"`` (Table 2, SIFT+RootSIFT) or ``"best"`` (Table 3, HarrisZ+SOSNet); ``None`` gives all three
    with a ``setup`` column. Same layout as :func:`method_table` (kinds ``planar`` / ``nonplanar``, models
    ``none`` / ``1sac``, the paper's 18 methods); ``time (s)`` is NaN where the paper prints "--". The paper
    does not count empty outputs apart: its ``failures`` are pairs without a correct match, empty outputs
    included, and ``empty`` is NaN. Read from the package data ``ctxmatch_lib/data/paper_tables.csv``, parsed
    from the paper's LaTeX source (:mod:`ctxmatch_lib.report.paper`)."""
    t = pd.read_csv(_PAPER_TABLES_CSV)
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


#: Columns of :func:`~ctxmatch_lib.geometry_metrics.geometry_table` that hold running times: they change from
#: run to run, so the tracked geometry tables leave them out (the notebook writes them under ``executed/``).
GEOMETRY_TIME_COLUMNS = ("geometry_time_s", "geometry_time_median_s")


def geometry_markdown(table: pd.DataFrame, *, title: str, provenance: dict, notes: str = "",
                      keep_times: bool = False) -> str:
    """A :func:`~ctxmatch_lib.geometry_metrics.geometry_table` as a Markdown report (``geometry.md``), the
    running times left out (:data:`GEOMETRY_TIME_COLUMNS`) unless ``keep_times``: the same numbers give the
    same bytes.

    Parameters
    ----------
    table : DataFrame
        Indexed by (setup, kind, method, model) or any index; AUCs and shares in %, ``pairs``, ``no_model``.
    title : str
        The first heading.
    provenance : dict
        Printed on the provenance line.
    notes : str
        A paragraph under the provenance line.
    keep_times : bool
        Keep the running-time columns (seconds, 3 decimals): the report of the times themselves, which
        changes from run to run (``executed/geometry_times.md``).

    Returns
    -------
    str
    """
    dropped = () if keep_times else GEOMETRY_TIME_COLUMNS
    t = table.drop(columns=[c for c in dropped if c in table.columns]).dropna(axis=1, how="all")
    # Each line names its setup, kind, method and model in full, so that a line read alone (grep, diff) says
    # what it is.
    for level, names in (("kind", KIND_LABELS), ("model", MODEL_LABELS), ("method", METHOD_LABELS)):
        if level in t.index.names:
            t = t.rename(index=names, level=level)
    formats = {c: ".0f" if c in ("pairs", "no_model") else ".3f" if c in GEOMETRY_TIME_COLUMNS else ".2f"
               for c in t.columns}
    lines = [f"# {title}\n", "Provenance: " + "; ".join(f"{k} {v}" for k, v in provenance.items()) + "\n"]
    if notes:
        lines.append(notes + "\n")
    return "\n".join(lines) + "\n" + markdown_table(t, formats=formats, labels=False, blank_repeats=False,
                                                     missing="")
