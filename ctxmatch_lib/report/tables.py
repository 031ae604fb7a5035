"""Tables of evaluation result rows (one per pair, feature setup, blob setup, method, model): pure pandas.

:func:`setup_rows` selects the paper's configurations (Sec. 5.3, :data:`SETUPS`), :func:`method_table` builds
the analogue of Tables 1-3, :func:`markdown_table` renders it, :func:`paper_table` holds the paper's own;
:func:`inlier_bin_table` gives the inlier-ratio histograms.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["METHOD_LABELS", "KIND_LABELS", "FEATURE_LABELS", "MODEL_LABELS", "SETUPS", "SETUP_TITLES", "PAPER_SETUP",
           "TABLE_COLUMNS", "method_label", "method_order", "setup_rows", "method_table", "gt_counts",
           "markdown_table", "paper_table", "PAPER_GT_COUNTS", "with_inlier_ratio", "inlier_bin_table",
           "GEOMETRY_TIME_COLUMNS", "geometry_markdown", "paired_markdown"]

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
                "essential": "MAGSAC on E", "poselib": "PoseLib", "poselib_essential": "PoseLib on E"}

#: Row selections of the paper's configurations (Sec. 5.3, Tables 1-3): column -> value (or tuple of values).
#: "global" pools every feature block under the blob setups of the other two.
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
    """The rows of a :data:`SETUPS` name or a dict column -> value(s); columns ``df`` lacks are ignored."""
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
    """The analogue of the paper's Tables 1-3: means per (kind, model, method), rows with an ``error`` left out.

    ``failures`` and ``empty`` count pairs per pooled (feature, blob) setup (the paper's failures are their
    sum); ``time (s)`` is on the "no model" rows only, as the paper's "--".

    Parameters
    ----------
    df : DataFrame
    models, kinds : sequence of str, optional
        Restrict and order the models / kinds (default: those present).

    Returns
    -------
    DataFrame
        Index (kind, model, method) in the paper's order; columns :data:`TABLE_COLUMNS` plus ``pairs``.
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
    """Mean ``n_gt`` and ``n_gt_star`` per pair and kind, as in the captions of Tables 1-3."""
    d = df[(df["method"] == "blob") & (df["model"] == df["model"].iloc[0])] if len(df) else df
    return d.groupby("kind", sort=False)[["n_gt", "n_gt_star"]].mean()


def _fmt(value, fmt: str, missing: str = "–") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return missing
    return value if isinstance(value, str) else format(value, fmt)


def markdown_table(table: pd.DataFrame, *, formats=None, labels: bool = True, blank_repeats: bool = True,
                   missing: str = "–") -> str:
    """Render a :func:`method_table` (or any indexed frame) as a Markdown table.

    ``formats`` maps columns to format specs; ``labels`` shows the paper's display names; ``blank_repeats``
    blanks an index cell repeating the row above; ``missing`` is the cell of a NaN.
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


#: The paper's Tables 1-3 and caption counts as package data, written by ``python -m ctxmatch_lib.report.paper TEX``.
_PAPER_DATA = Path(__file__).resolve().parents[1] / "data"
_PAPER_TABLES_CSV = _PAPER_DATA / "paper_tables.csv"
_PAPER_GT_COUNTS_CSV = _PAPER_DATA / "paper_gt_counts.csv"


def _read_gt_counts() -> dict:
    c = pd.read_csv(_PAPER_GT_COUNTS_CSV)
    kinds = ("planar", "nonplanar")
    return {setup: {col: tuple(int(g.set_index("kind").loc[k, col]) for k in kinds)
                    for col in ("n_gt", "n_gt_star")}
            for setup, g in c.groupby("setup", sort=False)}


#: Mean ground-truth matches per pair in the captions of Tables 1-3: setup -> {"n_gt" (recall), "n_gt_star"
#: (recall*)} -> (planar, non-planar).
PAPER_GT_COUNTS = _read_gt_counts()


def paper_table(setup: str | None = None) -> pd.DataFrame:
    """The paper's Table 1 (``"global"``), 2 (``"baseline"``) or 3 (``"best"``) in :func:`method_table`'s
    layout; ``None`` gives all three. ``empty`` is NaN (the paper's failures include empty outputs)."""
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
    """``df`` with an ``inlier_ratio`` column: the blob candidates' precision on the same pair and setup
    (Sec. 5.3)."""
    keys = ["pair_id"] + _config_keys(df)
    ref = df[(df["method"] == "blob") & (df["model"] == "none")][keys + ["precision"]]
    ref = ref.rename(columns={"precision": "inlier_ratio"}).drop_duplicates(keys)
    return df.drop(columns=["inlier_ratio"], errors="ignore").merge(ref, on=keys, how="left")


def inlier_bin_table(df: pd.DataFrame, bins=(0.0, 0.1, 0.2, 0.3, 0.5, 1.0)) -> pd.DataFrame:
    """``precision (%)``, ``recall (%)``, ``n`` and ``share (%)`` per (inlier-ratio bin, model, method).

    Parameters
    ----------
    df : DataFrame
        Result rows (:func:`with_inlier_ratio` is applied when needed).
    bins : sequence of float
        Increasing edges in [0, 1]; closed on the left, the last bin on both sides.
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


#: Running-time columns of :func:`~ctxmatch_lib.geometry_metrics.geometry_table`, left out of tracked tables.
GEOMETRY_TIME_COLUMNS = ("geometry_time_s", "geometry_time_median_s")


def geometry_markdown(table: pd.DataFrame, *, title: str, provenance: dict, notes: str = "",
                      keep_times: bool = False) -> str:
    """A :func:`~ctxmatch_lib.geometry_metrics.geometry_table` as a Markdown report, without the running
    times (:data:`GEOMETRY_TIME_COLUMNS`) unless ``keep_times``; a metric with its interval is one cell,
    ``value [lo, hi]``."""
    dropped = () if keep_times else GEOMETRY_TIME_COLUMNS
    t = table.drop(columns=[c for c in dropped if c in table.columns]).dropna(axis=1, how="all")
    for c in [c for c in t.columns if c.endswith("_pct")]:
        lo, hi = c[:-len("pct")] + "lo", c[:-len("pct")] + "hi"
        if lo in t.columns and hi in t.columns:
            t[c] = [f"{v:.2f} [{a:.1f}, {b:.1f}]" if np.isfinite(v) else "" for v, a, b in zip(t[c], t[lo], t[hi])]
            t = t.drop(columns=[lo, hi])
    # Every line names its setup, kind, method and model in full (readable alone in grep or diff).
    for level, names in (("kind", KIND_LABELS), ("model", MODEL_LABELS), ("method", METHOD_LABELS)):
        if level in t.index.names:
            t = t.rename(index=names, level=level)
    formats = {c: ".0f" if c in ("pairs", "runs", "no_model") else ".3f" if c in GEOMETRY_TIME_COLUMNS else ".2f"
               for c in t.columns}
    lines = [f"# {title}\n", "Provenance: " + "; ".join(f"{k} {v}" for k, v in provenance.items()) + "\n"]
    if notes:
        lines.append(notes + "\n")
    return "\n".join(lines) + "\n" + markdown_table(t, formats=formats, labels=False, blank_repeats=False,
                                                     missing="")


def paired_markdown(table: pd.DataFrame, *, title: str, provenance: dict, notes: str = "") -> str:
    """A :func:`~ctxmatch_lib.geometry_metrics.paired_differences` table as a Markdown report: per comparison
    the two values, ``difference [lo, hi]`` and whether the interval excludes 0 (``resolved``; "too few pairs"
    under :data:`~ctxmatch_lib.geometry_metrics.MIN_RESOLVING_PAIRS`)."""
    t = table.copy()
    for level, names in (("kind", KIND_LABELS), ("model", MODEL_LABELS), ("method", METHOD_LABELS),
                         ("reference", METHOD_LABELS)):
        if level in t.columns:
            t[level] = t[level].map(lambda v, names=names: names.get(v, v))
    t["difference"] = [f"{d:+.2f} [{a:+.1f}, {b:+.1f}]" for d, a, b in zip(t["difference"], t["lo"], t["hi"])]
    from ..geometry_metrics import MIN_RESOLVING_PAIRS

    t["resolved"] = ["yes" if r else "too few pairs" if n < MIN_RESOLVING_PAIRS else "not resolved"
                     for r, n in zip(t["resolved"], t["pairs"])]
    t = t.drop(columns=["lo", "hi"])
    lines = [f"# {title}\n", "Provenance: " + "; ".join(f"{k} {v}" for k, v in provenance.items()) + "\n"]
    if notes:
        lines.append(notes + "\n")
    formats = {"pairs": ".0f", "runs": ".0f", "value": ".2f", "reference_value": ".2f"}
    return "\n".join(lines) + "\n" + markdown_table(t.set_index(list(t.columns[:1])), formats=formats, labels=False,
                                                     blank_repeats=False, missing="")
