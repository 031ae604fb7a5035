"""The CPU-independent elementary functions of ``ctxmatch_lib._numerics.fixedmath``: ``log`` and ``atan`` agree with the
C library's and numpy's to within one unit in the last place, and keep their special values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ctxmatch_lib._numerics import fixedmath as fm


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


def _exp_tanh_inputs() -> np.ndarray:
    rng = np.random.default_rng(5)
    scales = (1e-3, 2.0 ** -5, 0.5, 3.0, 30.0, 300.0)
    return np.concatenate([
        *(rng.standard_normal(20000) * s for s in scales),
        rng.uniform(-800.0, 800.0, 20000),  # overflow, every binary exponent, the subnormal range
        (rng.standard_normal(20000) * 4).astype(np.float32),  # the patch networks' activations
        [0.0, -0.0, 2.0 ** -5, -(2.0 ** -5), np.nextafter(2.0 ** -5, 0.0), 40.0, -40.0, 709.782712893384, 709.79,
         -745.1332191019412, -745.2, -744.9, -708.5, -1e300, 1e300, 5e-324, -5e-324, 1e-310, np.inf, -np.inf],
    ])


@pytest.mark.parametrize("name", ["exp", "tanh"])
def test_compiled_exp_and_tanh_give_the_ufunc_forms_bits(name):
    """exp and tanh run a compiled loop (_fixedmath_kernels); its bits are those of the same formula written
    one numpy ufunc per operation, on every binary exponent, both tanh branches and the special values."""
    x = _exp_tanh_inputs()
    with np.errstate(all="ignore"):
        ref = getattr(fm, f"_{name}_ufuncs")(x)
    got = getattr(fm, name)(x)
    assert got.dtype == np.float64 and got.shape == x.shape
    assert np.array_equal(got.view(np.int64), ref.view(np.int64))
    assert np.isnan(getattr(fm, name)([np.nan])).all()
    # Shapes are kept, 0-d included.
    assert getattr(fm, name)(np.zeros((2, 3))).shape == (2, 3) and getattr(fm, name)(1.0).shape == ()


def test_tanh_f32_rounds_the_float64_tanh_once():
    from ctxmatch_lib._numerics.fixedmath_kernels import tanh_f32

    x = (np.random.default_rng(6).standard_normal((50, 40)) * 3).astype(np.float32)
    got = tanh_f32(x)
    assert got.dtype == np.float32 and got.shape == x.shape
    with np.errstate(all="ignore"):
        assert np.array_equal(got.view(np.int32), fm._tanh_ufuncs(x).astype(np.float32).view(np.int32))
