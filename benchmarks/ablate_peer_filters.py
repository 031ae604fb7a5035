"""Sweeps of one constant of a peer filter on the shared real pairs: which setting moves us to the paper's row.

Where the authors' code of a filter is not public or cannot run here (BM, SCV, PFM; LMR
runs, see ``benchmarks/ref_lmr.py``), the filter's Notes explain its distance from the paper's Table 2 with a
measurement. This script prints it: for every ``--sweep NAME:KEY=V1,V2,...`` it runs the registered filter
``NAME`` with ``KEY`` set to each value (every other keyword at its default, or as ``--param NAME:KEY=JSON``)
on the same blob candidates of the shared real pairs (``CTXMATCH_DATA``; the candidates and labels of
``bench_filters_ref.py``: configuration ``baseline`` = SIFT + RootSIFT with the ``baseline`` blob preset,
``best`` = HarrisZ + SOSNet stand-in with ``paper-best-overlap``, at ``--max-keypoints paper``), and prints per
dataset the mean precision / recall (percent; the library's normalised recall; an empty output counts as 0 %
precision and 0 % recall, as in the paper's averages and in ``figures/paper/tables.md``), the number of empty
outputs and the mean number of kept rows. The default setting is marked ``*``.

The paper's Table 2 row (baseline, no model) is printed beside the sweep for the baseline configuration
(the values quoted from Bellavia, TPAMI 2022, Table 2: planar / non-planar precision and recall).

Run (about a minute per setting and filter over the 55 pairs on one core; PFM more)::

    OMP_NUM_THREADS=1 CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/ablate_peer_filters.py \\
        --sweep bm:tau=0.1,0.15,0.25 --sweep scv:p1=0.15,0.25,0.4 --pairs 40
"""

from __future__ import annotations

import argparse
import importlib.util
import inspect
import json
import os
import sys
from pathlib import Path

import numpy as np

#: Table 2 of the paper, baseline configuration, no model: (planar P, planar R, non-planar P, non-planar R), %.
PAPER_BASELINE = {"bm": (83.91, 57.48, 85.25, 61.61), "scv": (84.15, 47.13, 81.93, 55.10),
                  "pfm": (75.38, 35.38, 75.95, 35.13), "lmr": (70.29, 79.58, 64.29, 76.50)}


def _bench():
    path = Path(__file__).resolve().parent / "bench_filters_ref.py"
    spec = importlib.util.spec_from_file_location("bench_filters_ref", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def parse_sweep(text: str) -> tuple[str, str, list]:
    """``NAME:KEY=V1,V2`` -> ``(name, key, [v1, v2])``; each value is JSON (``0.5``, ``true``, ``[4, 8]``)
    and values are split at top-level commas."""
    name, _, kv = text.partition(":")
    key, sep, vals = kv.partition("=")
    if not name or not key or not sep or not vals:
        raise ValueError(f"--sweep must be NAME:KEY=V1,V2,..., got {text!r}")
    out, depth, cur = [], 0, ""
    for ch in vals:
        depth += ch in "[("
        depth -= ch in "])"
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    out.append(cur)
    return name, key, [json.loads(v) for v in out]


def evaluate(bench, name: str, data, params: dict) -> dict:
    """Mean P / R (%), empty outputs and mean kept rows of filter ``name`` with ``params`` over ``data``."""
    from ctxmatch_lib.evaluation.steps import run_filter

    prec, rec, kept, empty = [], [], [], 0
    for pair, f1, f2, m, s, lab in data:
        keep, _ = run_filter(name, f1, f2, m, s, image_size1=pair.image_size1, image_size2=pair.image_size2,
                             **params)
        p, r = bench.precision_recall(m, lab, keep)  # precision 0 on an empty output (metrics.precision)
        empty += not keep.any()
        prec.append(p)
        rec.append(r)
        kept.append(int(keep.sum()))
    return dict(P=float(np.mean(prec)), R=float(np.nanmean(rec)), empty=empty,
                kept=float(np.mean(kept)), pairs=len(data))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sweep", action="append", required=True, metavar="NAME:KEY=V1,V2,...")
    parser.add_argument("--param", action="append", default=[], metavar="NAME:KEY=JSON",
                        help="a fixed keyword of filter NAME during every sweep of NAME (repeatable)")
    parser.add_argument("--config", default="baseline", choices=("baseline", "best"))
    parser.add_argument("--datasets", nargs="+", default=["planar", "nonplanar"])
    parser.add_argument("--pairs", type=int, default=40, help="pairs per dataset, evenly spread (default 40: all "
                                                             "of the shared planar 31 and non-planar 24)")
    parser.add_argument("--max-keypoints", default="paper")
    args = parser.parse_args(argv)
    from ctxmatch_lib.filters import FILTERS

    try:
        sweeps = [parse_sweep(s) for s in args.sweep]
    except ValueError as exc:
        parser.error(str(exc))
    fixed: dict[str, dict] = {}
    for p in args.param:
        name, _, kv = p.partition(":")
        key, sep, val = kv.partition("=")
        if not sep:
            parser.error(f"--param must be NAME:KEY=JSON, got {p!r}")
        fixed.setdefault(name, {})[key] = json.loads(val)
    for name, key, _ in sweeps:
        if name not in FILTERS:
            parser.error(f"--sweep: unknown filter {name!r}")
        if key not in inspect.signature(FILTERS[name]).parameters:
            parser.error(f"--sweep {name}: the filter has no keyword {key!r}")
    if args.pairs < 1:
        parser.error(f"--pairs must be a positive integer, got {args.pairs}")
    if not os.environ.get("CTXMATCH_DATA"):
        print("CTXMATCH_DATA is not set: nothing to measure", file=sys.stderr)
        return 2
    bench = _bench()
    print("command: " + " ".join([Path(sys.argv[0]).name] + (sys.argv[1:] if argv is None else list(argv))))
    data = {ds: list(bench._inputs(ds, args.config, args.pairs, args.max_keypoints)) for ds in args.datasets}
    cols = "".join(f" {ds + ' P / R (empty, kept)':>34}" for ds in args.datasets)
    for name, key, values in sweeps:
        default = inspect.signature(FILTERS[name]).parameters[key].default
        others = ", ".join(f"{k}={v}" for k, v in fixed.get(name, {}).items() if k != key)
        print(f"\n{name}: {key} ({others or 'other keywords at their defaults'})")
        print(f"{'value':>16}{cols}")
        if args.config == "baseline" and name in PAPER_BASELINE:
            pp, pr, np_, nr = PAPER_BASELINE[name]
            paper = {"planar": (pp, pr), "nonplanar": (np_, nr)}
            print(f"{'paper Table 2':>16}" + "".join(f" {paper[ds][0]:>13.1f} / {paper[ds][1]:<5.1f}{'':>13}"
                                                      for ds in args.datasets if ds in paper))
        for v in values:
            params = dict(fixed.get(name, {}), **{key: v})
            res = [evaluate(bench, name, data[ds], params) for ds in args.datasets]
            mark = "*" if v == default else " "
            print(f"{json.dumps(v) + mark:>16}" + "".join(
                f" {r['P']:>13.1f} / {r['R']:<5.1f} ({r['empty']:>2}, {r['kept']:>5.0f})" for r in res), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
