"""Our tables beside the paper's Tables 1-3: :func:`side_by_side` (per method, kind and model, with the
differences), :func:`method_rank_agreement` (Spearman's ρ over the filters) and :func:`tables_markdown` (the
``tables.md`` of the gallery)."""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from .paper import PAPER_PAIRS, failure_count, paper_tables
from .tables import KIND_LABELS, PAPER_GT_COUNTS, PAPER_SETUP, SETUP_TITLES, markdown_table

__all__ = ["SIDE_COLUMNS", "side_by_side", "method_rank_agreement", "tables_markdown"]

#: Columns of :func:`side_by_side`.
SIDE_COLUMNS = ("precision ours (%)", "precision paper (%)", "precision Δ", "recall ours (%)", "recall paper (%)",
                "recall Δ", "failures ours (%)", "failures paper (%)", "failures Δ", "blob")


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
        part["failures ours (%)"] = 100 * (failure_count(o) / o["pairs"]).to_numpy(float)
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
