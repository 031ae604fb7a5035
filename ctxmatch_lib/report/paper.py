"""The paper's Tables 1-3 (Appendix "DTM evaluation") read from its LaTeX.

:func:`parse_paper_tables` / :func:`parse_paper_gt_counts` parse them (``python -m ctxmatch_lib.report.paper TEX``
writes them to ``ctxmatch_lib/data``), :func:`paper_tables` reads the shipped copy. Ours beside them:
:mod:`.side_by_side`; the claims of Sec. 5.3: :mod:`.claims`.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from .tables import _PAPER_DATA, PAPER_SETUP, paper_table

__all__ = ["PAPER_TABLE_LABELS", "PAPER_PAIRS", "PAPER_FILTERS", "parse_paper_tables", "parse_paper_gt_counts",
           "write_paper_data", "paper_tables", "failure_count"]

#: The ``\\label`` of each of the paper's tables: Table 1 (global), 2 (baseline, SIFT+RootSIFT), 3 (best,
#: HarrisZ+SOSNet).
PAPER_TABLE_LABELS = {"global": "table_all", "baseline": "table_rootsift", "best": "table_sosnet"}
#: Image pairs per kind in the paper (Sec. 5.1 "Setup": "a total of 19×(6-1) = 75 image pairs" planar, "a total
#: of 72+27 = 99 image pairs" non-planar), the denominator of the paper's failure shares.
PAPER_PAIRS = {"planar": 75, "nonplanar": 99}
#: The paper's 17 local spatial filters (Tables 1-3 order; the blob candidates are not a filter).
PAPER_FILTERS = ("th", "dtm1", "dtm2", "lmr", "lpm", "glpm", "gms", "vfc", "llt", "rfm_scan", "adalam", "oanet",
                 "acne", "pfm", "pgm", "scv", "bm")

_TABLE_COLUMNS = ("precision", "recall", "recall_star", "correct", "output", "failures", "time_s")
_INT_COLUMNS = ("correct", "output", "failures")
_DECIMALS = {"precision": 2, "recall": 2, "recall_star": 2, "time_s": 3}
_KINDS = {"planar": "planar", "nonplanar": "nonplanar"}
_MODELS = {"nomodel": "none", "1sac": "1sac"}


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
    parts = [_parse_table(_table_block(text, label), label).assign(setup=setup)
             for setup, label in PAPER_TABLE_LABELS.items()]
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
    out_dir = _PAPER_DATA if out_dir is None else Path(out_dir)
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


def failure_count(t: pd.DataFrame) -> pd.Series:
    """The paper's failures: pairs without a correct match, empty outputs included."""
    empty = t["empty"] if "empty" in t.columns else 0.0
    return t["failures"] + pd.Series(empty, index=t.index).fillna(0.0)


#: Names this module held before the side-by-side tables and the claims got modules of their own; they keep
#: working, with a FutureWarning, until the next release.
_MOVED = {"side_by_side": "side_by_side", "method_rank_agreement": "side_by_side", "tables_markdown": "side_by_side",
          "SIDE_COLUMNS": "side_by_side", "check_claims": "claims", "CLAIMS": "claims"}


def __getattr__(name: str):
    if name in _MOVED:
        import importlib
        import warnings

        where = f"ctxmatch_lib.report.{_MOVED[name]}"
        warnings.warn(f"ctxmatch_lib.report.paper.{name} moved to {where}; the old path goes in the next release",
                      FutureWarning, stacklevel=2)
        return getattr(importlib.import_module(where), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
