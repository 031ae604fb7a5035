"""f = Ω's codes buffer is reused from one call of blob matching to the next (``blob._workspace``)."""

import threading

import numpy as np
import pytest

from ctxmatch_lib.blob import BLOB_PRESETS, BlobContext, blob_matching, free_workspace
from ctxmatch_lib.blob import _workspace

from test_blob_exact import dense_reference, planted

BASELINE = BLOB_PRESETS["baseline"]


def _held():
    return getattr(_workspace._held, "buf", None)


@pytest.fixture(autouse=True)
def _empty_workspace():
    free_workspace()
    yield
    free_workspace()


@pytest.mark.parametrize("product", ["fused", "tiles"])
@pytest.mark.parametrize("poison", [0, 0xFFFE])
def test_a_reused_buffer_holding_stale_codes_gives_the_reference(product, poison, monkeypatch):
    """Every code is rewritten by the pass: a held buffer full of 0 (every entry would look nearest) or of the
    largest code gives the dense float64 reference, on both passes, for a smaller call after a larger one."""
    monkeypatch.setattr(BlobContext, "product", product)
    d1, d2, k1, k2 = planted(3, 230, 250)
    blob_matching(*planted(4, 260, 270)[:2], **BASELINE.kwargs())
    buf = _held()
    assert buf is not None and buf.size == 260 * 270
    buf.fill(poison)
    out = blob_matching(d1, d2, **BASELINE.kwargs())
    ref = dense_reference(d1, d2, k1, k2, BASELINE)
    np.testing.assert_array_equal(out.matches, ref.matches)
    np.testing.assert_array_equal(out.scores, ref.scores)
    assert _held() is buf  # taken over (large enough) and handed back


def test_the_buffer_is_taken_not_shared_and_a_released_context_still_works():
    d1, d2, _, _ = planted(5, 120, 140)
    first = BlobContext(d1, d2, depth=1, keep_dense=True, columns=False)
    codes = first._codes
    first.release()
    assert _held() is codes and first._codes is None and first._approx is None
    a = BlobContext(d1, d2, depth=1, keep_dense=True, columns=False)
    b = BlobContext(d1, d2, depth=1, keep_dense=True, columns=False)
    assert a._codes is codes and _held() is None  # a took it: b has its own
    assert not np.shares_memory(a._approx, b._approx)
    np.testing.assert_array_equal(a._approx, b._approx)
    want = b.candidates("omega", f_prime=1)
    a.release()
    got = a.candidates("omega", f_prime=1)  # recomputes what it needs
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_only_small_buffers_are_held_and_the_larger_one_is_kept(monkeypatch):
    d1, d2, _, _ = planted(6, 100, 110)
    blob_matching(d1[:50], d2[:60], **BASELINE.kwargs())
    small = _held()
    assert small.size == 50 * 60
    blob_matching(d1, d2, **BASELINE.kwargs())  # too big for the held one: a fresh one, held instead
    assert _held().size == 100 * 110
    big = _held()
    blob_matching(d1[:50], d2[:60], **BASELINE.kwargs())
    assert _held() is big
    monkeypatch.setattr(_workspace, "HOLD_BYTES", 100 * 110 * 2 - 1)
    free_workspace()
    blob_matching(d1, d2, **BASELINE.kwargs())
    assert _held() is None


def test_paper_best_holds_no_codes_and_each_thread_has_its_own():
    d1, d2, k1, k2 = planted(7, 90, 80)
    blob_matching(d1, d2, kpts1=k1, kpts2=k2, **BLOB_PRESETS["paper-best"].kwargs())
    assert _held() is None
    blob_matching(d1, d2, **BASELINE.kwargs())
    mine = _held()
    seen = []
    t = threading.Thread(target=lambda: seen.append(_held()))
    t.start()
    t.join()
    assert mine is not None and seen == [None]
