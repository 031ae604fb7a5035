"""``ctxmatch_lib._blas.one_blas_thread``: one thread in every pool, a controller kept until modules change."""

import importlib
import sys

import pytest
from threadpoolctl import threadpool_info

from ctxmatch_lib import _blas


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
