"""No number of the library goes through a numpy function that rounds differently on an AVX-512 CPU.

numpy's transcendental ufuncs (``exp``, ``log``, ``sin``, ``arccos``, ``arctan2``, ``power``, …) have AVX-512
loops whose last bit differs from their AVX2 and baseline loops; an AVX2 host cannot run them, so the CPU
emulations of ``test_blas_kernels.py`` do not see them. Here they are found by name (the list is numpy's own,
``numpy.lib.introspect.opt_func_info()``, read by ``benchmarks/bench_cpu_paths.py``): no module of the
package names one outside the training and test helpers; and ``test_blas_kernels.py`` runs its embedded
evaluations (a planar, a non-planar and a depth pair; SIFT, sGLOH2 and the numpy networks; every filter under no
model, 1SAC and MAGSAC) with these ufuncs traced, and fails if the library reaches one, directly or through scipy.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ctxmatch_lib"
#: Always checked, whatever the numpy build reports (an ARM wheel lists no x86 targets).
TRANSCENDENTAL = {"arccos", "arccosh", "arcsin", "arcsinh", "arctan", "arctan2", "arctanh", "cbrt", "cos", "cosh",
                  "exp", "exp2", "expm1", "log", "log10", "log1p", "log2", "power", "float_power", "sin", "sinh",
                  "tan", "tanh"}


def _jitted(node: ast.FunctionDef) -> bool:
    """A numba kernel: its ``np.exp`` is the C library's, whose variants test_blas_kernels emulates."""
    return any("jit" in ast.unparse(d) or "user_cache" in ast.unparse(d) for d in node.decorator_list)


def _names_used(tree: ast.AST, names: set[str]):
    """``(line, name)`` of every ``np.<name>`` / ``numpy.<name>`` outside numba kernels, and of every
    ``from numpy import <name>``."""
    skip = {id(n) for f in ast.walk(tree) if isinstance(f, ast.FunctionDef) and _jitted(f) for n in ast.walk(f)}
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if (isinstance(node, ast.Attribute) and node.attr in names and isinstance(node.value, ast.Name)
                and node.value.id in ("np", "numpy")):
            yield node.lineno, node.attr
        elif isinstance(node, ast.ImportFrom) and node.module == "numpy":
            yield from ((node.lineno, a.name) for a in node.names if a.name in names)
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow) and not _scalar_power(node):
            yield node.lineno, "power"


def _scalar_power(node: ast.BinOp) -> bool:
    """``a ** b`` that does not reach numpy's ``power`` loop: an exponent numpy computes exactly (2, 0.5, 1, 0,
    -1: square, sqrt, copy, ones, reciprocal), or a base that is a literal or a Python scalar (``float(…)``,
    ``int(…)``: the C library's ``pow``)."""
    try:
        if ast.literal_eval(node.right) in (0, 0.5, 1, 2, -1):
            return True
    except ValueError:
        pass
    base = node.left
    if isinstance(base, ast.Constant) or (isinstance(base, ast.UnaryOp) and isinstance(base.operand, ast.Constant)):
        return True
    return isinstance(base, ast.Call) and isinstance(base.func, ast.Name) and base.func.id in ("float", "int")


def test_the_avx512_table_is_read(load_benchmark):
    bench = load_benchmark("bench_cpu_paths")
    names = bench.avx512_ufuncs()
    # x86-64 wheels build AVX-512 loops for these; elsewhere the table is empty and the fixed list is checked.
    import platform

    if platform.machine().lower() in ("x86_64", "amd64"):
        assert {"exp", "log", "sin", "cos", "arctan2", "power"} <= set(names), names
    assert not set(names) & bench.EXACT


def test_no_module_names_a_cpu_rounded_ufunc(load_benchmark):
    bench = load_benchmark("bench_cpu_paths")
    names = TRANSCENDENTAL | set(bench.avx512_ufuncs())
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel in bench.ALLOWED:
            continue
        found += [f"{rel}:{line}: np.{name}" for line, name in _names_used(ast.parse(path.read_text()), names)]
    assert not found, ("use ctxmatch_lib._numerics.fixedmath (numpy's loop rounds by CPU):\n" + "\n".join(found))


def test_the_name_check_sees_a_call_and_skips_a_kernel():
    code = ("import numpy as np\nfrom numpy import log\n@numba.njit\ndef k(x):\n    return np.exp(x)\n"
            "def f(x):\n    return np.arccos(x) + np.sqrt(x) + x ** 2 + x ** -1 + 2.0 ** -24 + float(x) ** 3\n"
            "def g(x, t):\n    return x ** (1 + t)\n")
    assert sorted(_names_used(ast.parse(code), TRANSCENDENTAL)) == [(2, "log"), (7, "arccos"), (9, "power")]


def test_the_allowed_modules_exist_and_say_why(load_benchmark):
    bench = load_benchmark("bench_cpu_paths")
    for rel, why in bench.ALLOWED.items():
        assert (ROOT / rel).is_file(), rel
        assert len(why) > 10, rel


def test_the_recorder_counts_library_calls_only(load_benchmark):
    import numpy as np
    from scipy.ndimage import gaussian_filter

    from ctxmatch_lib.testing import planted_homography_matches

    bench = load_benchmark("bench_cpu_paths")
    with bench.traced(["cos", "exp"]) as hits:
        gaussian_filter(np.ones((5, 5)), 1.0)  # np.exp in scipy, called from here: not the library's
        planted_homography_matches(20)  # np.cos in an allowed module of the library
    assert [k[0] for k in hits] == ["cos"] and next(iter(hits))[1].startswith("ctxmatch_lib/testing.py:")
    assert not bench.offending(hits)
    assert isinstance(np.exp, np.ufunc) and isinstance(np.cos, np.ufunc)  # restored
