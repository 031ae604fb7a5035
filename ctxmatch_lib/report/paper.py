"""Our results side by side with the paper's Tables 1-3 (Appendix "DTM evaluation") and the claims of Sec. 5.3.

:func:`parse_paper_tables` / :func:`parse_paper_gt_counts` read Tables 1-3 from the paper's LaTeX
(``python -m ctxmatch_lib.report.paper TEX`` writes them to ``ctxmatch_lib/data``); :func:`side_by_side` and
:func:`method_rank_agreement` compare our tables with them; :func:`check_claims` tests Sec. 5.3 (a)-(h).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from .tables import KIND_LABELS, MODEL_LABELS, PAPER_GT_COUNTS, PAPER_SETUP, SETUP_TITLES, markdown_table, paper_table

__all__ = [
    "PAPER_TABLE_LABELS",
    "PAPER_PAIRS",
    "PAPER_FILTERS",
    "SIDE_COLUMNS",
    "CLAIMS",
    "parse_paper_tables",
    "parse_paper_gt_counts",
    "write_paper_data",
    "paper_tables",
    "side_by_side",
    "method_rank_agreement",
    "check_claims",
    "tables_markdown",
]

#: The ``\\label`` of each of the paper's tables: Table 1 (global), 2 (baseline, SIFT+RootSIFT), 3 (best,
#: HarrisZ+SOSNet).
PAPER_TABLE_LABELS = {"global": "table_all", "baseline": "table_rootsift", "best": "table_sosnet"}
#: Image pairs per kind in the paper (Sec. 5.1 "Setup": "a total of 19×(6-1) = 75 image pairs" planar, "a total
#: of 72+27 = 99 image pairs" non-planar), the denominator of the paper's failure shares.
PAPER_PAIRS = {"planar": 75, "nonplanar": 99}
#: The paper's 17 local spatial filters (Tables 1-3 order; the blob candidates are not a filter).
PAPER_FILTERS = ("th", "dtm1", "dtm2", "lmr", "lpm", "glpm", "gms", "vfc", "llt", "rfm_scan", "adalam", "oanet",
                 "acne", "pfm", "pgm", "scv", "bm")
#: Columns of :func:`side_by_side`.
SIDE_COLUMNS = ("precision ours (%)", "precision paper (%)", "precision Δ", "recall ours (%)", "recall paper (%)",
                "recall Δ", "failures ours (%)", "failures paper (%)", "failures Δ", "blob")

_TABLE_COLUMNS = ("precision", "recall", "recall_star", "correct", "output", "failures", "time_s")
_INT_COLUMNS = ("correct", "output", "failures")
_DECIMALS = {"precision": 2, "recall": 2, "recall_star": 2, "time_s": 3}
_KINDS = {"planar": "planar", "nonplanar": "nonplanar"}
_MODELS = {"nomodel": "none", "1sac": "1sac"}
_DATA = Path(__file__).resolve().parents[1] / "data"


def _norm(text: str) -> str:
    return re.sub(r"[^a-z0-9]", "", text.lower())


# The paper's row names, normalised by _norm ("DTM$_1$" -> "dtm1", "RFM-SCAN" -> "rfmscan"), to ours.
_METHODS = {_norm(m): m for m in ("blob",) + PAPER_FILTERS}


def _read_tex(tex) -> str:
    if isinstance(tex, Path) or (isinstance(tex, str) and "\n" not in tex
                                 and (tex.endswith(".tex") or Path(tex).is_file())):
        path = Path(tex)
        if not path.is_file():
            raise FileNotFoundError(f"tex: no such LaTeX file {str(path)!r}")
        return path.read_text(encoding="utf-8")
    if not isinstance(tex, str):
        raise TypeError(f"tex must be a path or the LaTeX text, got {type(tex).__name__}")
    return tex


def _table_block(text: str, label: str) -> str:
    """The ``table`` environment holding ``\\label{label}``."""
    for block in re.findall(r"\\begin\{table\*?\}(.*?)\\end\{table\*?\}", text, flags=re.S):
        if re.search(r"\\label\{" + re.escape(label) + r"\}", block):
            return block
    raise ValueError(f"tex: no table with \\label{{{label}}} (expected the paper's Tables 1-3)")


def _marker(cell: str):
    """``(span, text)`` of a ``\\multirow{span}{..}{.. {text}}`` cell, or None."""
    m = re.search(r"\\multirow\{(-?\d+)\}", cell)
    if m is None:
        return None
    inner = re.findall(r"\{([^{}]*)\}", cell[m.end():])
    return int(m.group(1)), inner[-1].strip() if inner else ""


def _number(cell: str, label: str, line: str) -> float:
    cell = cell.strip()
    if cell in ("--", "-", "–"):
        return np.nan
    try:
        return float(cell)
    except ValueError:
        raise ValueError(f"tex: table {label}: cannot read {cell!r} as a number in row {line.strip()!r}") from None


def _spread(markers, n: int, names: dict, what: str, label: str) -> list:
    """Each row's value from ``\\multirow`` markers (a negative span covers the rows ending at the marker)."""
    out = [None] * n
    for i, (span, text) in markers:
        value = names.get(_norm(text))
        if value is None:
            raise ValueError(f"tex: table {label}: unknown {what} {text!r} (known: {sorted(set(names.values()))})")
        rows = range(i + span + 1, i + 1) if span < 0 else range(i, i + span)
        for r in rows:
            if not 0 <= r < n or out[r] not in (None, value):
                raise ValueError(f"tex: table {label}: the {what} \\multirow spans overlap or leave the table")
            out[r] = value
    if any(v is None for v in out):
        raise ValueError(f"tex: table {label}: {out.count(None)} rows have no {what} (\\multirow markers)")
    return out


def _parse_table(block: str, label: str) -> pd.DataFrame:
    rows, kinds, models = [], [], []
    for line in block.split("\\\\"):
        line = re.sub(r"(?m)^\s*\\(toprule|midrule|bottomrule|cmidrule\S*|hline)\s*$", "", line)
        cells = line.split("&")
        if len(cells) != 3 + len(_TABLE_COLUMNS) or "multicolumn" in line:
            continue
        name = cells[2].strip()
        method = _METHODS.get(_norm(name))
        if method is None:
            raise ValueError(f"tex: table {label}: unknown method {name!r} (known: {list(_METHODS.values())})")
        for cell, markers in ((cells[0], kinds), (cells[1], models)):
            if (mk := _marker(cell)) is not None:
                markers.append((len(rows), mk))
        rows.append([method] + [_number(c, label, line) for c in cells[3:]])
    if not rows:
        raise ValueError(f"tex: table {label} has no data rows ('& & name & numbers \\\\')")
    t = pd.DataFrame(rows, columns=["method", *_TABLE_COLUMNS])
    t.insert(0, "model", _spread(models, len(rows), _MODELS, "model", label))
    t.insert(0, "kind", _spread(kinds, len(rows), _KINDS, "kind", label))
    if t.duplicated(["kind", "model", "method"]).any():
        raise ValueError(f"tex: table {label}: a (kind, model, method) row appears twice")
    return t


def parse_paper_tables(tex) -> pd.DataFrame:
    """The paper's Tables 1-3 (Appendix "DTM evaluation") read from its LaTeX source (path or text).

    Returns columns ``setup``, ``kind``, ``model``, ``method`` (our names), ``precision``, ``recall``,
    ``recall_star`` (%), ``correct``, ``output``, ``failures`` and ``time_s`` (NaN for "--"), in the paper's
    row order; a missing table or unreadable row raises ``ValueError``.
    """
    text = _read_tex(tex)
    parts = []
    for setup, label in PAPER_TABLE_LABELS.items():
        t = _parse_table(_table_block(text, label), label)
        parts.append(t.assign(setup=setup))
    out = pd.concat(parts, ignore_index=True)
    out = out[["setup", "kind", "model", "method", *_TABLE_COLUMNS]]
    return out.astype({c: np.int64 for c in _INT_COLUMNS})


def parse_paper_gt_counts(tex) -> pd.DataFrame:
    """Mean ground-truth matches per pair in the captions of Tables 1-3: columns ``setup``, ``kind``,
    ``n_gt`` (recall) and ``n_gt_star`` (recall*)."""
    text = _read_tex(tex)
    rows = []
    for setup, label in PAPER_TABLE_LABELS.items():
        caption = " ".join(_table_block(text, label).split())
        blob = re.search(r"(\d+)\s*/\s*(\d+)\s*\(blob", caption)
        star = re.search(r"(\d+)\s*/\s*(\d+)\s*\(all matches", caption)
        if blob is None or star is None:
            raise ValueError(f"tex: the caption of table {label} has no 'N/M (blob, ...)' and 'N/M (all matches, "
                             "...)' counts")
        for i, kind in enumerate(("planar", "nonplanar")):
            rows.append((setup, kind, int(blob.group(i + 1)), int(star.group(i + 1))))
    return pd.DataFrame(rows, columns=["setup", "kind", "n_gt", "n_gt_star"])


def _csv(df: pd.DataFrame) -> str:
    """Deterministic CSV text: the paper's decimals, an empty cell for NaN, ``\\n`` line ends."""
    df = df.copy()
    for col, dec in _DECIMALS.items():
        if col in df.columns:
            text = df[col].map(lambda v, d=dec: "" if pd.isna(v) else f"{v:.{d}f}")
            lost = [v for v, s in zip(df[col], text) if s and float(s) != v]
            if lost:
                raise ValueError(f"{col}: values with more than {dec} decimals would be rounded: {lost[:3]}")
            df[col] = text
    return df.to_csv(index=False, lineterminator="\n")


def write_paper_data(tex, out_dir=None) -> list:
    """Write ``paper_tables.csv`` and ``paper_gt_counts.csv`` parsed from ``tex`` to ``out_dir`` (default
    ``ctxmatch_lib/data``), deterministically; return the paths."""
    out_dir = _DATA if out_dir is None else Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, frame in (("paper_tables.csv", parse_paper_tables(tex)), ("paper_gt_counts.csv",
                                                                          parse_paper_gt_counts(tex))):
        path = out_dir / name
        path.write_bytes(_csv(frame).encode("utf-8"))
        paths.append(path)
    return paths


def paper_tables(setups) -> dict:
    """``{configuration: the paper's table it is compared with}`` (:data:`~ctxmatch_lib.report.PAPER_SETUP`),
    in the layout of :func:`~ctxmatch_lib.report.method_table`."""
    unknown = [s for s in setups if s not in PAPER_SETUP]
    if unknown:
        raise ValueError(f"setups: {unknown} have no paper table (known: {list(PAPER_SETUP)})")
    return {s: paper_table(PAPER_SETUP[s]) for s in setups}


def _failure_count(t: pd.DataFrame) -> pd.Series:
    """The paper's failures: pairs without a correct match, empty outputs included."""
    empty = t["empty"] if "empty" in t.columns else 0.0
    return t["failures"] + pd.Series(empty, index=t.index).fillna(0.0)


def side_by_side(tables: dict, pairs: dict | None = None, *, paper: dict | None = None) -> pd.DataFrame:
    """The rows of our tables and the paper's Tables 1-3 side by side (:data:`SIDE_COLUMNS`): ours, paper,
    Δ = ours - paper, failures as shares of the pairs in % (the pair counts differ).

    Parameters
    ----------
    tables : dict
        ``{configuration: frame}`` of :func:`~ctxmatch_lib.report.method_table`.
    pairs : dict, optional
        The paper's pairs per kind (default :data:`PAPER_PAIRS`, Sec. 5.1).
    paper : dict, optional
        ``{configuration: the paper's frame}``; default :func:`paper_tables`.
    """
    pairs = dict(PAPER_PAIRS if pairs is None else pairs)
    paper = paper_tables(list(tables)) if paper is None else paper
    parts = []
    for setup, ours in tables.items():
        if setup not in paper:
            raise ValueError(f"paper: no paper table for configuration {setup!r}")
        theirs = paper[setup]
        idx = [i for i in ours.index if i in theirs.index and i[0] in pairs]
        o, p = ours.loc[idx], theirs.loc[idx]
        kinds = np.array([i[0] for i in idx])
        part = pd.DataFrame(index=pd.MultiIndex.from_tuples([(setup, *i) for i in idx],
                                                            names=["setup", "kind", "model", "method"]))
        for metric in ("precision", "recall"):
            part[f"{metric} ours (%)"] = o[f"{metric} (%)"].to_numpy(float)
            part[f"{metric} paper (%)"] = p[f"{metric} (%)"].to_numpy(float)
            part[f"{metric} Δ"] = part[f"{metric} ours (%)"] - part[f"{metric} paper (%)"]
        part["failures ours (%)"] = 100 * (_failure_count(o) / o["pairs"]).to_numpy(float)
        part["failures paper (%)"] = 100 * p["failures"].to_numpy(float) / np.array([pairs[k] for k in kinds],
                                                                                     float)
        part["failures Δ"] = part["failures ours (%)"] - part["failures paper (%)"]
        part["blob"] = [i[2] == "blob" for i in idx]
        parts.append(part)
    if not parts:
        return pd.DataFrame(columns=list(SIDE_COLUMNS))
    return pd.concat(parts)[list(SIDE_COLUMNS)]


def _spearman(x, y) -> float:
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return np.nan
    return float(stats.spearmanr(x, y)[0])


def method_rank_agreement(side: pd.DataFrame) -> pd.DataFrame:
    """Spearman's ρ of our and the paper's precision and recall over the filters, per (setup, kind, model)
    of a :func:`side_by_side` frame, with the mean absolute differences and ``n``."""
    d = side[~side["blob"].astype(bool)]
    rows = {}
    for key, g in d.groupby(level=["setup", "kind", "model"], sort=False):
        rows[key] = {
            "ρ precision": _spearman(g["precision ours (%)"], g["precision paper (%)"]),
            "ρ recall": _spearman(g["recall ours (%)"], g["recall paper (%)"]),
            "mean |ΔP|": float(g["precision Δ"].abs().mean()),
            "mean |ΔR|": float(g["recall Δ"].abs().mean()),
            "n": len(g),
        }
    out = pd.DataFrame.from_dict(rows, orient="index")
    if out.empty:
        return pd.DataFrame(columns=["ρ precision", "ρ recall", "mean |ΔP|", "mean |ΔR|", "n"])
    out.index = pd.MultiIndex.from_tuples(out.index, names=["setup", "kind", "model"])
    return out


def tables_markdown(tables: dict, counts: dict, side: pd.DataFrame, rho: pd.DataFrame, *, provenance: dict,
                    data_label: str, pairs_per_kind: pd.Series, features, blobs, max_keypoints=None) -> str:
    """``tables.md``: Tables 1-3's analogues next to the paper's; the same inputs give the same bytes.

    Parameters
    ----------
    tables, counts : dict
        ``{configuration: frame}`` of :func:`~ctxmatch_lib.report.method_table` (no time column) and
        :func:`~ctxmatch_lib.report.gt_counts`.
    side, rho : DataFrame
        :func:`side_by_side` and :func:`method_rank_agreement`.
    provenance, data_label, pairs_per_kind, features, blobs, max_keypoints
        What the text names (``max_keypoints=None``: the presets' 8000).
    """
    kinds = ", ".join(f"{n} {KIND_LABELS[k]}" for k, n in pairs_per_kind.items())
    parts = [
        "# Analogues of Tables 1-3 of *SIFT Matching by Context Exposed*\n",
        "Provenance: " + "; ".join(f"{k} {v}" for k, v in provenance.items()) + "\n",
        f"Data: `{data_label}` ({int(pairs_per_kind.sum())} pairs: {kinds}); features " + ", ".join(features)
        + " (SOSNet/HardNet2: stand-in weights); keypoint budget "
        + f"{max_keypoints if max_keypoints is not None else 'the presets (8000)'}; blob setups "
        + ", ".join(blobs) + ". Means per pair; precision, recall and recall* in %; failures = pairs whose "
        "non-empty output holds no correct match, empty = pairs with an empty output (per setup). Running times are "
        "not here (they change from run to run): `ctxmatch figures` writes them to `executed/times.md` of the figure "
        "folder.\n",
    ]
    table_number = {name: k for k, name in enumerate(PAPER_GT_COUNTS, start=1)}  # global 1, baseline 2, best 3
    for s, t in tables.items():
        c, paper_gt = counts[s], PAPER_GT_COUNTS[PAPER_SETUP[s]]
        gt, gt_star = (" / ".join(f"{c.loc[k, col]:.0f}" for k in c.index) for col in ("n_gt", "n_gt_star"))
        parts += [f"## Table {table_number[PAPER_SETUP[s]]} analogue: {SETUP_TITLES[s]}\n",
                  f"Mean ground-truth matches per pair ({' / '.join(KIND_LABELS[k] for k in c.index)}): {gt} "
                  "among the candidates of the setup "
                  f"(recall), {gt_star} among all the setups (recall*); the paper: {paper_gt['n_gt'][0]}/"
                  f"{paper_gt['n_gt'][1]} and {paper_gt['n_gt_star'][0]}/{paper_gt['n_gt_star'][1]} "
                  "(planar/non-planar).\n",
                  markdown_table(t)]
    cells = pd.DataFrame({f"{w} (%)": [f"{r[f'{w} ours (%)']:.1f} / {r[f'{w} paper (%)']:.1f} / {r[f'{w} Δ']:+.1f}"
                                       for _, r in side.iterrows()]
                          for w in ("precision", "recall", "failures")}, index=side.index)
    parts += ["## Next to the paper: ours / paper / Δ\n",
              "Each cell: ours / the paper's / the difference. Precision, recall and failures (failures + empty "
              "outputs, as a share of the pairs: ours over "
              + ", ".join(f"{n} {KIND_LABELS[k]}" for k, n in pairs_per_kind.items() if k in PAPER_PAIRS)
              + " pairs, the paper's over " + ", ".join(f"{n} {KIND_LABELS[k]}" for k, n in PAPER_PAIRS.items())
              + "), in %; Δ = ours − paper. best-rootsgloh2 is compared with Table 3 (best) too.\n"]
    for s in dict.fromkeys(cells.index.get_level_values("setup")):
        parts += [f"### {SETUP_TITLES[s]} (paper: Table {table_number[PAPER_SETUP[s]]})\n",
                  markdown_table(cells.xs(s, level="setup"))]
    parts += ["## Rank agreement with the paper\n",
              "Spearman ρ of the 17 filters' precision and recall, ours against the paper's, and the mean absolute "
              "difference in points, per configuration, kind and model (n: filters in both).\n",
              markdown_table(rho.rename(columns=lambda c: c.replace("|", "\\|")),  # a bare | splits a cell
                             formats={"ρ precision": ".2f", "ρ recall": ".2f", "mean \\|ΔP\\|": ".1f",
                                      "mean \\|ΔR\\|": ".1f", "n": ".0f"})]
    return "\n".join(parts)


# ----------------------------------------------------------------------------------------------------------------
# The claims of Sec. 5.3.

class _Missing(Exception):
    """A row a claim needs is not in the table."""


def _val(t, kind, model, method, col):
    try:
        v = t.loc[(kind, model, method), col]
    except KeyError:
        raise _Missing(f"no {method} row ({kind}, {model})") from None
    return float(v)


def _filters(t, kind, model, col) -> pd.Series:
    """``col`` of the paper's filters present in ``t`` for (kind, model), indexed by method."""
    try:
        sub = t.xs((kind, model), level=("kind", "model"))
    except KeyError:
        raise _Missing(f"no rows ({kind}, {model})") from None
    sub = sub[sub.index.isin(PAPER_FILTERS)]
    if sub.empty:
        raise _Missing(f"no filter rows ({kind}, {model})")
    return (_failure_count(sub) if col == "failures+empty" else sub[col]).astype(float)


def _rank(values: pd.Series, method: str, *, high: bool) -> int:
    """1 + the number of methods strictly better (ties share the best rank)."""
    v = values[method]
    return 1 + int((values > v).sum() if high else (values < v).sum())


def _claim_a(tabs, setup, kind, model):
    t = tabs[setup]
    blob = _val(t, kind, "none", "blob", "precision (%)")
    p = _filters(t, kind, "none", "precision (%)")
    worst = p.idxmin()
    return bool((p > blob).all()), f"lowest filter P {p[worst]:.2f} ({worst}) vs blob {blob:.2f}; " \
                                   f"{int((p > blob).sum())}/{len(p)} above"


def _claim_b(tabs, setup, kind, model):
    t = tabs[setup]
    p1, p2 = (_val(t, kind, "none", m, "precision (%)") for m in ("dtm1", "dtm2"))
    r1, r2 = (_val(t, kind, "none", m, "recall (%)") for m in ("dtm1", "dtm2"))
    return abs(p2 - p1) <= 5 and r2 > r1, f"P DTM2 {p2:.2f} vs DTM1 {p1:.2f} (|Δ| {abs(p2 - p1):.2f}); " \
                                          f"R DTM2 {r2:.2f} vs DTM1 {r1:.2f}"


def _claim_c(tabs, setup, kind, model):
    t = tabs[setup]
    p = _filters(t, kind, "none", "precision (%)")
    if "adalam" not in p.index:
        raise _Missing("no adalam row")
    rank = _rank(p, "adalam", high=True)
    r, r2 = _val(t, kind, "none", "adalam", "recall (%)"), _val(t, kind, "none", "dtm2", "recall (%)")
    return rank <= 3 and r < r2, f"AdaLAM P {p['adalam']:.2f} (rank {rank}/{len(p)}); R {r:.2f} vs DTM2 {r2:.2f}"


def _claim_d(tabs, setup, kind, model):
    t = tabs[setup]
    pp, pt = _val(t, kind, "none", "pfm", "precision (%)"), _val(t, kind, "none", "th", "precision (%)")
    rp, rt = _val(t, kind, "none", "pfm", "recall (%)"), _val(t, kind, "none", "th", "recall (%)")
    return rp < rt and abs(pp - pt) <= 10, f"R PFM {rp:.2f} vs th {rt:.2f}; P PFM {pp:.2f} vs th {pt:.2f} " \
                                           f"(|Δ| {abs(pp - pt):.2f})"


def _claim_e(tabs, setup, kind, model):
    if "baseline" not in tabs:
        raise _Missing("no baseline configuration")
    gap = {}
    for s in ("baseline", setup):
        g, th = (_val(tabs[s], kind, "none", m, "recall (%)") for m in ("gms", "th"))
        gap[s] = (g, th, g - th)
    gb, tb, db = gap["baseline"]
    return gb < tb and gap[setup][2] > db, f"baseline R GMS {gb:.2f} vs th {tb:.2f}; GMS - th recall {db:+.2f} " \
                                           f"(baseline) vs {gap[setup][2]:+.2f} ({setup})"


def _claim_f(tabs, setup, kind, model):
    t = tabs[setup]

    def moves(method):
        p0, p1 = (_val(t, kind, m, method, "precision (%)") for m in ("none", "1sac"))
        r0, r1 = (_val(t, kind, m, method, "recall (%)") for m in ("none", "1sac"))
        return p1 > p0 and r1 < r0, (p0, p1, r0, r1)

    blob_ok, (p0, p1, r0, r1) = moves("blob")
    both = _filters(t, kind, "none", "precision (%)").index.intersection(
        _filters(t, kind, "1sac", "precision (%)").index)
    n_ok = sum(moves(m)[0] for m in both)
    return blob_ok and n_ok >= 0.8 * len(both), f"blob P {p0:.2f}→{p1:.2f}, R {r0:.2f}→{r1:.2f}; " \
                                                f"{n_ok}/{len(both)} filters raise P and lower R"


def _claim_g(tabs, setup, kind, model):
    t = tabs[setup]
    p, r = (pd.concat([_filters(t, kind, "1sac", c), pd.Series({"blob": _val(t, kind, "1sac", "blob", c)})])
            for c in ("precision (%)", "recall (%)"))
    best_r = r.drop("blob").idxmax()
    best_p = p.idxmax()
    ok = r["blob"] >= r.max() and p["blob"] >= p.max() - 5
    return ok, f"blob+1SAC R {r['blob']:.2f} (best filter {best_r} {r[best_r]:.2f}); P {p['blob']:.2f} " \
               f"(best {best_p} {p[best_p]:.2f})"


def _claim_h(tabs, setup, kind, model):
    f = _filters(tabs[setup], kind, model, "failures+empty")
    if "dtm2" not in f.index:
        raise _Missing("no dtm2 row")
    rank = _rank(f, "dtm2", high=False)
    return rank <= 6, f"DTM2 failures {f['dtm2']:.3g} (rank {rank}/{len(f)}; 6th lowest {np.sort(f)[5]:.3g})" \
        if len(f) >= 6 else f"DTM2 failures {f['dtm2']:.3g} (rank {rank}/{len(f)})"


#: The observations of Sec. 5.3 checked by :func:`check_claims`: id -> (the paper's words, the test, the scope:
#: kinds, models, configurations ("all" or the "best" ones, compared with "baseline")).
CLAIMS = {
    "a": ("all methods improve the precision with respect to the blob matching", _claim_a,
          ("planar", "nonplanar"), ("none",), "all"),
    "b": ("the precision of DTM1 is similar to that of the complete DTM, but the recall is lower", _claim_b,
          ("planar", "nonplanar"), ("none",), "all"),
    "c": ("AdaLAM achieves very high precision but lower recall [than DTM], unless running on planar scenes",
          _claim_c, ("nonplanar",), ("none",), "all"),
    "d": ("PFM obtains a lower recall than the simple thresholding for a similar precision", _claim_d,
          ("planar", "nonplanar"), ("none",), "all"),
    "e": ("GMS improves upon the simple thresholding in the case of the best configuration", _claim_e,
          ("planar", "nonplanar"), ("none",), "best"),
    "f": ("1SAC is able to improve the precision with an acceptable loss in terms of recall", _claim_f,
          ("planar", "nonplanar"), ("none→1sac",), "all"),
    "g": ("blob matching after 1SAC achieves almost the best results in terms of both precision and recall in "
          "the planar case", _claim_g, ("planar",), ("1sac",), "all"),
    "h": ("DTM, OANet, ACNe and PGM are among those methods which fail less", _claim_h,
          ("planar", "nonplanar"), ("none", "1sac"), "all"),
}


def _verdict(fn, tabs, setup, kind, model):
    if tabs is None or setup not in tabs:
        return "not testable", "no table"
    try:
        ok, evidence = fn(tabs, setup, kind, model)
    except _Missing as e:
        return "not testable", str(e)
    return ("supported" if ok else "contradicted"), evidence


def check_claims(tables: dict, *, paper: dict | None = None) -> pd.DataFrame:
    """The observations of Sec. 5.3 (Fig. 7, Tables 1-3) checked on our tables and on the paper's own.

    Criteria (P, R in %; ranks among the 17 :data:`PAPER_FILTERS`, ties sharing the best rank):
    (a) no model: every filter's P > blob's; (b) no model: |P(DTM2) - P(DTM1)| <= 5, R(DTM2) > R(DTM1);
    (c) non-planar, no model: AdaLAM's P in the top 3, R(AdaLAM) < R(DTM2); (d) no model: R(PFM) < R(th),
    |P(PFM) - P(th)| <= 10; (e) R(GMS) < R(th) in "baseline" and the gap R(GMS) - R(th) larger in "best";
    (f) no model -> 1SAC raises P and lowers R for blob and >= 80 % of the filters; (g) planar, 1SAC: blob's R
    the highest, its P within 5 of the highest; (h) DTM2's failures + empty among the 6 lowest.

    Parameters
    ----------
    tables : dict
        ``{configuration: method_table frame}``.
    paper : dict, optional
        ``{configuration: the paper's frame}``; default :func:`paper_tables`.

    Returns
    -------
    DataFrame
        One row per claim and scope: ``claim``, ``statement``, ``scope``, ``verdict`` ("supported",
        "contradicted", "not testable"), ``evidence``, ``paper_verdict``, ``paper_evidence``.
    """
    if paper is None:
        paper = paper_tables([s for s in tables if s in PAPER_SETUP])
    rows = []
    for cid, (statement, fn, kinds, models, which) in CLAIMS.items():
        setups = [s for s in tables if which == "all" or PAPER_SETUP.get(s) == "best"]
        for setup in setups:
            for kind in kinds:
                for model in models:
                    verdict, evidence = _verdict(fn, tables, setup, kind, model)
                    p_verdict, p_evidence = _verdict(fn, paper, setup, kind, model)
                    label = "→".join(MODEL_LABELS.get(m, m) for m in model.split("→"))  # "no model→1SAC"
                    rows.append((cid, statement, f"{setup}, {kind}, {label}", verdict, evidence, p_verdict,
                                 p_evidence))
    return pd.DataFrame(rows, columns=["claim", "statement", "scope", "verdict", "evidence", "paper_verdict",
                                       "paper_evidence"])


def main(argv=None) -> int:
    """``python -m ctxmatch_lib.report.paper TEX [OUT_DIR]``: write the paper's tables and counts as CSV."""
    argv = sys.argv[1:] if argv is None else argv
    if not 1 <= len(argv) <= 2:
        print("usage: python -m ctxmatch_lib.report.paper TEX [OUT_DIR]", file=sys.stderr)
        return 2
    for path in write_paper_data(argv[0], argv[1] if len(argv) > 1 else None):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
