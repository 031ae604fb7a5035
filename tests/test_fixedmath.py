"""The CPU-independent elementary functions of ``ctxmatch_lib._fixedmath``: ``log`` and ``atan`` agree with the
C library's and numpy's to within one unit in the last place, and keep their special values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ctxmatch_lib import _fixedmath as fm


def _ulps(got: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """|got - ref| in units of the last place of ``ref`` (0 where both are equal)."""
    return np.where(got == ref, 0.0, np.abs(got - ref) / np.spacing(np.abs(ref)))


def _log_inputs() -> np.ndarray:
    rng = np.random.default_rng(0)
    return np.concatenate([
        rng.uniform(0.0, 4.0, 20000),
        np.exp(rng.uniform(-700.0, 700.0, 20000)),  # every binary exponent
        rng.uniform(0.70, 1.42, 20000),  # both sides of the reduction bound sqrt(2) / 2
        [5e-324, 1e-310, np.finfo(float).tiny, np.finfo(float).max, np.nextafter(1.0, 0.0), np.nextafter(1.0, 2.0)],
    ])


@pytest.mark.parametrize("ref", [np.log, lambda x: np.array([math.log(v) for v in x.tolist()])],
                         ids=["numpy", "libm"])
def test_log_within_one_ulp(ref):
    x = _log_inputs()
    assert _ulps(fm.log(x), ref(x)).max() <= 1.0


def test_log_exact_and_special_values():
    assert fm.log([1.0, 2.0 ** 10, 2.0 ** -1074]).tolist() == [0.0, 10 * math.log(2.0), -1074 * math.log(2.0)]
    out = fm.log([0.0, -0.0, np.inf, -1.0, np.nan])
    assert out[:3].tolist() == [-np.inf, -np.inf, np.inf] and np.isnan(out[3:]).all()
    assert fm.log(np.float32(0.5)).dtype == np.float64 and fm.log(np.float32(0.5)) == fm.log(0.5)
    assert fm.log(np.empty((0, 3))).shape == (0, 3)


def test_log_inverts_exp():
    x = np.linspace(-700.0, 700.0, 10001)
    assert np.abs(fm.log(fm.exp(x)) - x).max() <= 2 * np.spacing(700.0)


def test_atan_within_one_ulp_and_odd():
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.normal(0.0, 3.0, 20000), np.exp(rng.uniform(-40.0, 40.0, 20000)),
                        [7 / 16, 11 / 16, 19 / 16, 39 / 16, 2.0 ** 66, 1e-300]])
    x = np.r_[x, -x]
    got = fm.atan(x)
    assert _ulps(got, np.array([math.atan(v) for v in x.tolist()])).max() <= 1.0
    assert _ulps(got, np.arctan(x)).max() <= 1.0
    assert np.array_equal(got, -fm.atan(-x))
    assert np.array_equal(got, fm.atan2(x, 1.0))


def test_atan_special_values():
    out = fm.atan([0.0, -0.0, np.inf, -np.inf, np.nan])
    assert out[2:4].tolist() == [math.pi / 2, -math.pi / 2] and np.isnan(out[4])
    assert out[0] == 0.0 and not np.signbit(out[0]) and np.signbit(out[1])


def test_atan2_propagates_nan():
    out = fm.atan2([np.nan, 1.0, np.nan, 1.0], [1.0, np.nan, np.nan, 1.0])
    assert np.isnan(out[:3]).all() and out[3] == math.pi / 4
