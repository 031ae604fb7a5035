"""LLT against its authors' code: the reference plugin ``benchmarks/ref_llt.py`` and the parts of
``ctxmatch_lib.filters.llt`` aligned with the authors' ``LLTV.m``.

The comparison with the authors' MATLAB code runs only when ``CTXMATCH_LLT_REF`` names a checkout of
jiayi-ma/LLT and GNU Octave is on PATH.
"""

from __future__ import annotations

import inspect
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.filters.llt import lle_weights, llt_filter, m_step
from filter_cases import planted_similarity

SIZE = (640, 480)
REF_DIR = os.environ.get("CTXMATCH_LLT_REF")

# A stand-in for the shape of the authors' demo (written here, not theirs): conf lines, the normalisation,
# the method switch, then lines that need the demo's data.
FAKE_DEMO = """\
method = 'affine';
conf.lambda = 7;
conf.Kn = 9;
load(fn_match);
[nX, nY, normal]=norm2(X,Y);
conf = LLT_init(conf);
switch method
    case 'nonrigid'
        VecFld=LLTV(nX, nY, conf);
end
VecFld.TX=(VecFld.TX)*normal.yscale;
"""


def _fake_checkout(root: Path) -> Path:
    root.mkdir(exist_ok=True)
    (root / "demo.m").write_text(FAKE_DEMO)
    for name in ("LLTV.m", "LLT_init.m", "norm2.m"):
        (root / name).write_text("% placeholder\n")
    return root


def test_plugin_loads_and_lists_its_files(bench):
    ref = bench.plugin("llt")
    assert set(ref.FILES) >= {"demo.m", "LLTV.m", "LLT_init.m", "norm2.m"}
    assert "LLTV.m" in ref.FUNC_FILES
    ours = inspect.signature(llt_filter).parameters
    assert all(key in ours for key in ref.OPTIONS)  # every shared option is a keyword of ours


def test_plugin_body_runs_the_demo_block_with_the_nonrigid_method(bench, tmp_path):
    root = _fake_checkout(tmp_path / "LLT")
    body = bench.plugin("llt").octave_body(root, {"lam": 5.0, "n_neighbors": 10})
    lines = [ln.strip() for ln in body.splitlines()]
    # the demo's conf lines, then ours (they override), then the method, then the timed block
    assert lines.index("conf.lambda = 7;") < lines.index("conf.lambda = 5.0;") < lines.index("c0 = cputime;")
    assert "conf.Kn = 10.0;" in lines
    assert lines.index("method = 'nonrigid';") < lines.index("c0 = cputime;")
    assert "[nX, nY, normal]=norm2(X,Y);" in lines and "VecFld=LLTV(nX, nY, conf);" in lines
    assert not any("load(" in ln or "VecFld.TX" in ln for ln in lines)  # the demo's data stays out
    assert lines[-2:] == ["cpu = cputime - c0;", "keep = VecFld.VFCIndex;"]
    assert "function [keep, cpu] = ref_filter" in bench.octave_driver("llt", root, {})


def test_plugin_names_a_missing_file_or_marker(bench, tmp_path):
    root = _fake_checkout(tmp_path / "LLT")
    (root / "LLTV.m").unlink()
    with pytest.raises(ValueError, match="LLTV.m"):
        bench.parse_ref(f"llt={root}")
    (root / "LLTV.m").write_text("% placeholder\n")
    assert bench.parse_ref(f"llt={root}") == ("llt", str(root))
    (root / "demo.m").write_text("conf.Kn = 3;\n")
    with pytest.raises(ValueError, match="norm2"):
        bench.plugin("llt").octave_body(root, {})


def _planted(n=200, outliers=50, seed=6):
    return planted_similarity(n, outliers, seed)


def test_octave_reference_agrees_on_one_to_one_matches(bench):
    # The authors' LLTV under Octave on a tie-free planted case. The control points are drawn at random on
    # both sides (Octave's randperm there, our generator here), so the masks may differ by that draw.
    if shutil.which("octave") is None:
        pytest.skip("GNU Octave ('octave') is not on PATH")
    if not REF_DIR:
        pytest.skip("CTXMATCH_LLT_REF (a checkout of the authors' LLT code) is not set")
    x, y, m = _planted()
    [(ref, cpu)] = bench.run_octave_reference("llt", Path(REF_DIR), [dict(X=x, Y=y, small=np.ones(len(x), bool))])
    ours = FILTERS["llt"](x, y, m, None, image_size1=SIZE, image_size2=SIZE)
    assert cpu >= 0
    assert not ref[:50].any() and ref[50:].mean() > 0.9  # the reference itself finds the planted split
    assert bench.jaccard(ours, ref) > 0.95


def test_defaults_are_the_authors_llt_init_and_demo_values():
    # demo.m: conf.lambda = 9e9, conf.Kn = 15; LLT_init.m: the rest; LLTV.m: LLE regulariser 1e-5 x trace.
    p = inspect.signature(llt_filter).parameters
    got = {k: p[k].default for k in ("lam", "n_neighbors", "n_control", "beta", "tau", "gamma", "a",
                                     "max_iter", "tol", "min_p", "reg")}
    assert got == dict(lam=9e9, n_neighbors=15, n_control=15, beta=0.1, tau=0.75, gamma=0.9, a=10.0,
                       max_iter=500, tol=1e-5, min_p=1e-5, reg=1e-5)


def test_lle_weights_reconstruct_each_point_from_its_neighbours():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (80, 2))
    W = lle_weights(x, 6)
    assert W.shape == (80, 80) and W.nnz == 80 * 6
    np.testing.assert_allclose(np.asarray(W.sum(1)).ravel(), 1.0)
    assert (W.diagonal() == 0).all()  # a point is not its own neighbour
    # k > 2 neighbours in 2-D: the regularised fit reconstructs each point almost exactly
    assert np.abs(x - W @ x).max() < 1e-3
    loose = lle_weights(x, 6, reg=1e-1)
    assert np.abs(x - loose @ x).max() > np.abs(x - W @ x).max()


def test_m_step_minimises_the_weighted_energy():
    # One M-step: argmin_C sum_i pw_i (|t_i - U_i C|^2 + c |Bx_i + BU_i C|^2), solved here as a stacked
    # weighted least-squares problem.
    rng = np.random.default_rng(1)
    n, m, c = 60, 5, 3.0
    U, BU = rng.normal(size=(n, m)), rng.normal(size=(n, m))
    t, bx = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    pw = rng.uniform(1e-5, 1.0, n)
    C = m_step(np.hstack([U, BU]), np.hstack([t, bx]), pw, c)
    s = np.sqrt(pw)[:, None]
    A = np.vstack([s * U, np.sqrt(c) * s * BU])
    b = np.vstack([s * t, -np.sqrt(c) * s * bx])
    np.testing.assert_allclose(C, np.linalg.lstsq(A, b, rcond=None)[0], rtol=1e-9, atol=1e-12)


def test_one_iteration_budget_keeps_everything():
    # The authors' loop runs `while iter < MaxIter` from iter = 1: MaxIter = 1 runs no EM step and returns
    # the initial posteriors P = I, every match an inlier.
    x, y, m = _planted(n=60, outliers=20, seed=2)
    assert llt_filter(x, y, m, image_size1=SIZE, image_size2=SIZE, max_iter=1).all()
    assert not llt_filter(x, y, m, image_size1=SIZE, image_size2=SIZE, max_iter=2).all()


def test_gamma_outside_the_open_unit_interval_is_an_error():
    x, y, m = _planted(n=30, outliers=5)
    for g in (0.0, 1.0, 1.5):
        with pytest.raises(ValueError, match="gamma"):
            llt_filter(x, y, m, image_size1=SIZE, image_size2=SIZE, gamma=g)


def test_lle_regulariser_is_validated():
    x, y, m = _planted(n=30, outliers=5)
    with pytest.raises(ValueError, match="reg"):
        llt_filter(x, y, m, image_size1=SIZE, image_size2=SIZE, reg=-1.0)


def test_empty_and_tiny_inputs():
    e = np.empty((0, 2))
    assert llt_filter(e, e, np.empty((0, 2), np.int64), image_size1=SIZE, image_size2=SIZE).shape == (0,)
    k = np.array([[10.0, 10.0], [50.0, 40.0]])
    keep = llt_filter(k, k + 3.0, np.c_[np.arange(2), np.arange(2)], image_size1=SIZE, image_size2=SIZE)
    assert keep.shape == (2,) and keep.dtype == bool
