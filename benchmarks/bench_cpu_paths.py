"""Which numpy functions would round by CPU on the way to a number: every call the library makes to a ufunc whose
float loops numpy dispatches to AVX-512 code.

numpy picks a ufunc's loop by CPU at run time. Its own table (``numpy.lib.introspect.opt_func_info()``) lists,
per function and signature, the targets compiled in; the transcendental functions (``exp``, ``log``, ``sin``,
``arctan2``, ``power``, …) have AVX-512 loops (Intel's SVML on ``X86_V4``) whose last bit differs from the AVX2
and baseline ones. An AVX2 host runs the same code under every emulation of ``bench_blas_kernels.py``, so it
cannot see them: here they are found by name instead. :func:`avx512_ufuncs` reads the table;
:func:`traced` replaces those ufuncs on the ``numpy`` module by recording wrappers, so that a call through
``np.exp`` (the library's, or scipy's or scikit-image's on the library's behalf) is counted with the first
library frame above it. The library computes these functions with ``ctxmatch_lib._numerics.fixedmath``
instead; the only modules allowed to call numpy's are those in :data:`ALLOWED`, with the reason.

Not seen here: ``a ** b`` on arrays (the operator reaches ``np.power`` without the module attribute; the
library's exponents are 2 and 0.5, numpy's exact fast paths), code that imported a ufunc by name before the
patch, and numba kernels (they call the C library, whose variants ``bench_blas_kernels.py`` emulates).

Run::

    .venv/bin/python benchmarks/bench_cpu_paths.py            # the pairs and setups of tests/test_blas_kernels.py
    .venv/bin/python benchmarks/bench_cpu_paths.py --all      # every embedded pair, every feature setup

The exit status is 1 when a library frame outside :data:`ALLOWED` reaches one of them.
"""

from __future__ import annotations

import argparse
import collections
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np

#: ufuncs whose results are exact (no rounding: comparisons, min/max, sign, frexp, …): the same bits
#: whatever loop computes them.
EXACT = frozenset({"absolute", "argmax", "argmin", "equal", "fmax", "fmin", "frexp", "greater", "greater_equal",
                   "ldexp", "less", "less_equal", "maximum", "minimum", "negative", "not_equal", "ceil", "floor",
                   "rint", "trunc", "sqrt", "square", "reciprocal", "sign", "signbit", "isnan", "isinf",
                   "isfinite", "conjugate", "add", "subtract", "multiply", "divide", "logical_and", "logical_or",
                   "logical_xor", "logical_not", "bitwise_and", "bitwise_or", "bitwise_xor", "invert"})
#: Library modules that may call them, and why their numbers need not repeat across CPUs.
ALLOWED = {
    "ctxmatch_lib/filters/lmr/training.py": "training data for LMR's weights, made once and shipped",
    "ctxmatch_lib/filters/learned/data.py": "training data for OANet / ACNe, made once and shipped",
    "ctxmatch_lib/training/blobsets.py": "training sets, made once",
    "ctxmatch_lib/testing.py": "synthetic scenes of the tests and doctests",
    "ctxmatch_lib/plots/palette.py": "CIELAB of the palette's colour-blindness check (tests); no figure reads it, "
                                      "and a drawing primitive imports nothing of the library",
}
#: Pairs and setups of the default run: a planar, a non-planar and a depth pair; SIFT, sGLOH2 (its blur) and the
#: numpy networks; every filter under no model, 1SAC and MAGSAC (the geometry step).
PAIRS = ["planar/lab/1-5", "nonplanar/horse", "depth/motorcycle"]
FEATURES = ["sift-rootsift", "harrisz-rootsgloh2", "harrisz-sosnet"]


def avx512_ufuncs() -> list[str]:
    """Names of the numpy ufuncs that round (not in :data:`EXACT`) and have an AVX-512 loop for a float type
    on this numpy build (whatever the CPU it runs on)."""
    from numpy.lib.introspect import opt_func_info

    out = set()
    for name, sigs in opt_func_info().items():
        for sig, targets in sigs.items():
            if sig[:1] in ("e", "f", "d") and any(t in targets["available"] for t in ("X86_V4", "AVX512")):
                out.add(name)
    return sorted(out - EXACT)


class _Recorder:
    """Wraps a ufunc: counts calls with a float argument by (ufunc, the first library frame above it)."""

    def __init__(self, ufunc, hits, root: str):
        self._ufunc, self._hits, self._root = ufunc, hits, root

    def __getattr__(self, name):
        return getattr(self._ufunc, name)

    def __call__(self, *args, **kwargs):
        if any(np.asarray(a).dtype.kind == "f" for a in args[:2]):
            frame = sys._getframe(1)
            while frame is not None and not frame.f_code.co_filename.startswith(self._root):
                frame = frame.f_back
            if frame is not None:
                rel = Path(frame.f_code.co_filename).relative_to(Path(self._root).parent).as_posix()
                self._hits[self._ufunc.__name__, f"{rel}:{frame.f_lineno}"] += 1
        return self._ufunc(*args, **kwargs)


@contextmanager
def traced(names=None):
    """Within the block, ``np.<name>`` for every name of :func:`avx512_ufuncs` (or ``names``) records its
    calls from the library; yields the counter ``{(ufunc, "ctxmatch_lib/…:line"): calls}``."""
    import ctxmatch_lib

    root = str(Path(ctxmatch_lib.__file__).resolve().parent)
    hits: collections.Counter = collections.Counter()
    names = avx512_ufuncs() if names is None else list(names)
    saved = {n: getattr(np, n) for n in names}
    try:
        for n in names:
            setattr(np, n, _Recorder(saved[n], hits, root))
        yield hits
    finally:
        for n, f in saved.items():
            setattr(np, n, f)


def offending(hits) -> dict:
    """The calls of ``hits`` from modules not in :data:`ALLOWED`."""
    return {k: v for k, v in hits.items() if k[1].rsplit(":", 1)[0] not in ALLOWED}


def run(pair_ids=None, features=None, models=("none", "1sac", "magsac")):
    """The embedded evaluation of ``pair_ids`` under ``features`` (every filter, ``models``), from an empty
    cache of its own, traced: ``(rows, hits)``."""
    import os
    import tempfile

    from ctxmatch_lib.evaluation import evaluate_cached, select_pairs
    from ctxmatch_lib.evaluation.steps import PAPER_FILTER_ORDER  # the library's filters, not a test's own

    with tempfile.TemporaryDirectory() as tmp:
        old = os.environ.get("CTXMATCH_CACHE")
        os.environ["CTXMATCH_CACHE"] = tmp
        try:
            with traced() as hits:
                pairs = select_pairs("embedded", pair_ids=pair_ids)
                df = evaluate_cached(pairs, features=list(features or FEATURES), blobs=["paper-best-overlap"],
                                     filters=list(PAPER_FILTER_ORDER), models=models, cache=False, progress=False)
        finally:
            if old is None:
                os.environ.pop("CTXMATCH_CACHE", None)
            else:
                os.environ["CTXMATCH_CACHE"] = old
    failed = df[df["error"].fillna("").astype(str) != ""]
    if len(failed):
        raise RuntimeError(f"{len(failed)} rows failed under the trace: {failed['error'].iloc[0]}")
    return df, hits


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--all", action="store_true", help="every embedded pair and feature setup")
    args = parser.parse_args(argv)
    names = avx512_ufuncs()
    print(f"numpy {np.__version__}: {len(names)} ufuncs round and have AVX-512 float loops: {', '.join(names)}")
    from ctxmatch_lib.features import FEATURE_PRESETS

    df, hits = run(None if args.all else PAIRS, list(FEATURE_PRESETS) if args.all else FEATURES)
    print(f"{len(df)} rows evaluated; calls from the library:")
    for (name, where), n in sorted(hits.items(), key=lambda kv: kv[0][1]):
        why = ALLOWED.get(where.rsplit(":", 1)[0], "NOT ALLOWED")
        print(f"  {name:10s} {n:7d}  {where:60s} {why}")
    bad = offending(hits)
    print(f"{len(bad)} call sites outside the allowed modules")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
