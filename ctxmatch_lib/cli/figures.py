"""``ctxmatch figures``: run the figure notebooks through papermill."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def add_parser(sub) -> None:
    p = sub.add_parser("figures", help="regenerate the paper's figures and tables by running the notebooks",
                       description="Execute notebooks/*.ipynb with papermill; figures (PNG + PDF) and tables go to "
                                   "figures/ of the checkout, replacing the committed ones, the executed notebooks "
                                   "to figures/executed/.")
    p.add_argument("--params", choices=["default", "paper"], default="default",
                   help="default: the embedded offline dataset (minutes); paper: notebooks/params/<stem>.yaml, "
                        "real data under CTXMATCH_DATA")
    p.add_argument("--only", default="", help="comma-separated notebook stems (default: all)")
    p.add_argument("--output", type=Path, default=None, help="figure folder (default: figures/ of the checkout)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import papermill as pm
    import yaml
    from tqdm.auto import tqdm

    from .._paths import repo_root

    root = repo_root()
    if root is None or not (root / "notebooks").is_dir():
        print("ctxmatch figures needs the repository checkout (notebooks/ not found)", file=sys.stderr)
        return 2
    nb_dir = root / "notebooks"
    out_dir = (args.output or root / "figures").resolve()
    (out_dir / "executed").mkdir(parents=True, exist_ok=True)
    stems = sorted(p.stem for p in nb_dir.glob("*.ipynb"))
    if args.only:
        wanted = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = sorted(set(wanted) - set(stems))
        if unknown:
            print(f"unknown notebook(s): {', '.join(unknown)}; known: {', '.join(stems)}", file=sys.stderr)
            return 2
        stems = [s for s in stems if s in wanted]
    failed = []
    start = time.perf_counter()
    for stem in tqdm(stems, desc="notebooks", unit="nb"):
        params = {"output_dir": str(out_dir)}
        if args.params == "paper":
            yml = nb_dir / "params" / f"{stem}.yaml"
            if yml.exists():
                params.update(yaml.safe_load(yml.read_text()) or {})
        t0 = time.perf_counter()
        try:
            pm.execute_notebook(str(nb_dir / f"{stem}.ipynb"), str(out_dir / "executed" / f"{stem}.ipynb"),
                                parameters=params, cwd=str(nb_dir), progress_bar=False, kernel_name="python3")
        except Exception as exc:  # keep going: one broken notebook should not hide the others
            failed.append(stem)
            tqdm.write(f"{stem}: FAILED ({type(exc).__name__}: {str(exc).splitlines()[0][:200]})")
        else:
            tqdm.write(f"{stem}: ok in {time.perf_counter() - t0:.1f} s")
    print(f"{len(stems) - len(failed)} of {len(stems)} notebooks ran in {time.perf_counter() - start:.0f} s; "
          f"figures and tables in {out_dir}")
    if failed:
        print(f"{len(failed)} notebook(s) failed: {', '.join(failed)}; see figures/executed/", file=sys.stderr)
        return 1
    return 0
