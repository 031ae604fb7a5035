"""The claims of Sec. 5.3 (a)-(h) checked on our tables and on the paper's (:func:`check_claims`)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .paper import PAPER_FILTERS, failure_count, paper_tables
from .tables import MODEL_LABELS, PAPER_SETUP

__all__ = ["CLAIMS", "check_claims"]


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
    return (failure_count(sub) if col == "failures+empty" else sub[col]).astype(float)


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
