"""``ctxmatch_lib._numerics.blas``: one thread in every pool (a controller kept until modules change), and the product that
blob matching's scan accumulates into its tile."""

import importlib
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from ctxmatch_lib._numerics import blas as _blas


def test_every_pool_runs_one_thread_inside():
    with _blas.one_blas_thread():
        assert all(pool["num_threads"] == 1 for pool in threadpool_info())


def test_controller_is_kept_until_a_module_is_imported():
    with _blas.one_blas_thread():
        pass
    first = _blas._controller
    with _blas.one_blas_thread():
        pass
    assert _blas._controller is first
    fresh = [name for name in ("mailbox", "imaplib", "poplib", "smtplib", "ftplib") if name not in sys.modules]
    if not fresh:
        pytest.skip("every candidate standard-library module is already imported")
    importlib.import_module(fresh[0])
    with _blas.one_blas_thread():
        pass
    assert _blas._controller is not first


def test_accumulate_product_adds_the_float32_product_in_place():
    rng = np.random.default_rng(0)
    a, b = rng.random((37, 24), np.float32), rng.random((29, 24), np.float32)
    out = np.zeros((37, 29), np.float32)
    ptr = out.ctypes.data
    _blas.accumulate_product(a, b, out)
    assert out.ctypes.data == ptr
    np.testing.assert_allclose(out, a.astype(np.float64) @ b.T.astype(np.float64), rtol=1e-5)
    _blas.accumulate_product(a, b, out)  # accumulates: twice the product
    np.testing.assert_allclose(out, 2 * (a.astype(np.float64) @ b.T.astype(np.float64)), rtol=1e-5)


def test_accumulate_product_writes_back_a_copy(monkeypatch):
    """Where f2py would hand back a copy instead of working in place, the result still lands in ``out``."""
    sgemm = _blas._blas.sgemm

    def on_a_copy(alpha, x, y, beta, c, **kw):
        return sgemm(alpha, x, y, beta=beta, c=np.array(c, order="F", copy=True), **kw)

    monkeypatch.setattr(_blas._blas, "sgemm", on_a_copy)
    a, b = np.ones((3, 2), np.float32), np.full((4, 2), 2.0, np.float32)
    out = np.zeros((3, 4), np.float32)
    _blas.accumulate_product(a, b, out)
    assert (out == 4).all()


@pytest.mark.parametrize("bad, name", [(dict(a=np.ones((3, 2))), "a"), (dict(b=np.ones((2, 4), np.float32).T), "b"),
                                       (dict(out=np.ones((3, 5), np.float32)), "shapes")])
def test_accumulate_product_rejects_bad_operands(bad, name):
    args = dict(a=np.ones((3, 2), np.float32), b=np.ones((4, 2), np.float32), out=np.zeros((3, 4), np.float32))
    args.update(bad)
    with pytest.raises(ValueError, match=name):
        _blas.accumulate_product(**args)
