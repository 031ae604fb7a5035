"""``ctxmatch warmup``: compile the kernels ahead, once per machine, so that the first ``ctxmatch match`` (with
``--all``, also ``ctxmatch eval``) does not wait for them."""

from __future__ import annotations

import argparse
import time

DESCRIPTION = """\
Compile ctxmatch's kernels into the user's cache folder, once per machine and per version of the code:
the kernels of 'ctxmatch match' (blob matching, DTM, the model steps) on a small scikit-image pair, and with
--all those of every filter and of the ground truth, through one embedded evaluation pair. The first command
that needs a kernel compiles it anyway; this only moves the wait. 'make figures' runs it."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("warmup", help="compile the kernels ahead, once per machine",
                                   description=DESCRIPTION)
    parser.add_argument("--all", action="store_true",
                        help="also every filter and the ground truth (minutes on a new machine)")
    parser.set_defaults(func=run)
    return parser


def run(args) -> int:
    from ..match import kernels_ready, warm_up

    start = time.perf_counter()
    ready = kernels_ready()
    print("ctxmatch warmup: " + ("loading the compiled kernels of matching" if ready else
                                 "compiling the kernels of matching, once per machine (about half a minute)"),
          flush=True)
    warm_up(models=("none", "1sac", "magsac"))
    if args.all:
        print("ctxmatch warmup: every filter and the ground truth, on one embedded pair", flush=True)
        from ..evaluation import evaluate_cached, select_pairs

        evaluate_cached(select_pairs("embedded")[:1], features=["sift-rootsift"], blobs=["paper-best"],
                        filters="all", models=("none", "1sac", "magsac"), cache=False, progress=False)
    print(f"ctxmatch warmup: done in {time.perf_counter() - start:.1f} s")
    return 0
