"""LLT's reference for ``bench_filters_ref.py --ref llt=DIR``: the authors' MATLAB code under GNU Octave.

``DIR`` is a checkout of jiayi-ma/LLT (Ma et al., "Robust feature matching for remote sensing image
registration via locally linear transforming", IEEE TGRS 2015), outside this repository, read at run time and
never copied. Its ``demo.m`` sets ``conf.lambda`` and ``conf.Kn``, normalises the matches with ``norm2``, fills
the remaining defaults with ``LLT_init`` and selects ``LLTA`` (affine), ``LLTR`` (rigid) or ``LLTV`` (non-rigid)
by ``method``. The driver reads the demo's ``conf.*`` lines and its filtering block (from ``norm2`` through the
``switch method ... end``) from the checkout and runs it with ``method = 'nonrigid'``: ``LLTV`` is the variant
the demo selects and the one ``ctxmatch_lib.filters.llt`` implements (a Gaussian-RKHS field with control
points); Bellavia's paper (Sec. 5.2) names LLT without a variant. ``LLTV`` needs no compiled code (its
neighbours come from a dense distance sort), so there is no ``compile_mex``.

The random state is reset by the bench before each call (``LLTV`` draws its control points with ``randperm``
among the distinct rows of ``X``); our filter draws its own, so the two runs differ by that draw.
"""

from __future__ import annotations

from pathlib import Path

#: bench_filters_ref's shared helpers, set by ``bench_filters_ref.plugin`` before this module runs.
host: object

#: Files a checkout must hold.
FILES = ("demo.m", "LLTV.m", "LLT_init.m", "norm2.m")

#: Files whose folders go on Octave's path (norm2 and LLT_init sit beside LLTV in the checkout).
FUNC_FILES = ("LLTV.m", "LLT_init.m", "norm2.m")

#: Our keyword -> the reference's ``conf`` field, for ``--param llt:KEY=VALUE`` given to both sides.
OPTIONS = {
    "lam": ("conf.lambda",), "n_neighbors": ("conf.Kn",), "n_control": ("conf.M",), "beta": ("conf.beta",),
    "tau": ("conf.theta",), "gamma": ("conf.gamma",), "a": ("conf.a",), "max_iter": ("conf.MaxIter",),
    "tol": ("conf.ecr",), "min_p": ("conf.minP",),
}


def demo_parts(demo: str) -> tuple[str, str]:
    """(``conf.*`` lines, filtering block) of the authors' ``demo.m``.

    The block runs from the ``norm2`` call to the ``end`` of the ``switch method`` (the de-normalisation and
    evaluation after it need the demo's ground truth); a ValueError names a missing marker.
    """
    lines = demo.splitlines()
    strip = [ln.strip() for ln in lines]
    conf = [ln for ln, s in zip(lines, strip) if s.startswith("conf.")]
    if not conf:
        raise ValueError("LLT demo.m: no conf.* lines")
    try:
        i = next(n for n, s in enumerate(strip) if "norm2(" in s and not s.startswith("%"))
        j = next(n for n in range(i, len(lines)) if strip[n].startswith("switch method"))
        k = next(n for n in range(j, len(lines)) if strip[n] == "end")
    except StopIteration:
        raise ValueError("LLT demo.m: no block norm2(...) ... switch method ... end") from None
    return "\n".join(conf), "\n".join(lines[i:k + 1])


def octave_body(root: Path, params: dict) -> str:
    """Body of ``ref_filter(X, Y, small, info)``: the demo's configuration and filtering block with
    ``method = 'nonrigid'`` (``LLTV``); ``keep`` = ``VecFld.VFCIndex``; ``cpu`` around the block only."""
    conf, block = demo_parts(host.find_reference_file(Path(root), "demo.m").read_text(errors="replace"))
    return (f"conf = [];\n{conf}\n{host.octave_assignments('llt', params)}\nmethod = 'nonrigid';\n"
            f"c0 = cputime;\n{block}\n"
            "cpu = cputime - c0;\nkeep = VecFld.VFCIndex;")
