"""The compiled inner loops of the identification (rtlift/sysid/kernels.py) give scipy's and
numpy's numbers bit for bit (compared as integers, so even a zero's sign counts)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from rtlift.sysid.identify import _extrapolated_hat_basis, _Runs
from rtlift.sysid.kernels import MIN_COLUMNS, Hats, lfilter


def _bits(v: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(v).view(np.int64)


def _numpy_hat_basis(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """The basis as numpy computed it before it was compiled (the reference)."""
    last = knots.size - 1
    inv = 1.0 / np.diff(knots)
    seg = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, last - 1)
    above = x >= knots[-1]
    d = np.where(above, x - knots[-1], x - knots[seg])
    rows = np.arange(x.size)
    phi = np.zeros((x.size, knots.size), order="F")
    phi[rows, seg] = np.where(above, -inv[seg] * d + 0.0, -inv[seg] * d + 1.0)
    phi[rows, seg + 1] = np.where(above, inv[seg] * d + 1.0, inv[seg] * d + 0.0)
    phi[x == knots[-1], last - 1] = 0.0
    phi[x == knots[-1], last] = 1.0
    return phi


def test_lfilter_is_scipys_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        nb, na = int(rng.integers(1, 8)), int(rng.integers(2, 8))
        b = rng.normal(size=nb)
        a = np.concatenate([[rng.choice([1.0, 0.7, -2.5])], 0.3 * rng.normal(size=na - 1)])
        x = rng.normal(size=(int(rng.integers(1, 300)), int(rng.integers(1, 3 * MIN_COLUMNS))))
        x[rng.random(x.shape) < 0.6] = 0.0          # the hat basis is mostly zeros: their signs count too
        x = np.asfortranarray(x) if rng.random() < 0.5 else x
        ref = signal.lfilter(b, a, x, axis=0)
        out = lfilter(b, a, x)
        assert out.flags.c_contiguous and ref.flags.c_contiguous
        assert np.array_equal(_bits(out), _bits(ref))
        assert np.array_equal(_bits(lfilter(b, a, x[:, 0])), _bits(signal.lfilter(b, a, x[:, 0])))
    # unstable and non-finite: the same infinities and NaNs
    x = np.ones((2000, MIN_COLUMNS))
    x[1500, 3] = np.nan
    ref = signal.lfilter([1.0, 0.5], [1.0, -1.9], x, axis=0)
    assert not np.all(np.isfinite(ref))
    assert np.array_equal(_bits(lfilter(np.array([1.0, 0.5]), np.array([1.0, -1.9]), x)), _bits(ref))
    x = x[:, 0]
    # no recursion: scipy's own (convolution) path
    assert np.array_equal(lfilter([1.0, 2.0], [1.0], x[:10]), signal.lfilter([1.0, 2.0], [1.0], x[:10]))


def test_runs_filter_each_run_from_rest() -> None:
    rng = np.random.default_rng(3)
    parts = [(rng.normal(size=n), rng.normal(size=n)) for n in (50, 80, 31)]
    runs = _Runs(parts, 5)
    b, a = np.array([0.2, 0.1]), np.array([1.0, -0.9, 0.2])
    v = np.asfortranarray(rng.normal(size=(runs.u.size, 4)))
    ref = np.concatenate([signal.lfilter(b, a, v[lo:hi], axis=0) for lo, hi in runs.pairs], axis=0)
    assert np.array_equal(_bits(runs.lfilter(b, a, v)), _bits(ref))
    knots = np.linspace(-2.0, 2.0, 2 * MIN_COLUMNS)
    basis = _numpy_hat_basis(runs.u, knots)
    ref = np.concatenate([signal.lfilter(b, a, basis[lo:hi], axis=0) for lo, hi in runs.pairs], axis=0)
    assert np.array_equal(_bits(runs.filter_hats(b, a, Hats(runs.u, knots))), _bits(ref))


@pytest.mark.parametrize("count", [2, 5, 16, 96])
def test_hat_basis_is_numpys_bit_for_bit(count: int) -> None:
    rng = np.random.default_rng(count)
    x = rng.normal(size=3000) ** 3
    q = np.linspace(0.002, 0.998, count)
    knots = np.unique(np.quantile(x, q))
    assert np.array_equal(_bits(np.quantile(np.sort(x), q)), _bits(np.quantile(x, q)))   # the knots' shortcut
    x[:len(knots)] = knots                          # on the knots, the last one included
    x[-3:] = [np.nan, -np.inf, np.inf]
    ref = _numpy_hat_basis(x, knots)
    hats = Hats(x, knots)
    got = hats.basis()
    assert got.flags.f_contiguous
    assert np.array_equal(_bits(got.ravel(order="F")), _bits(ref.ravel(order="F")))
    assert np.array_equal(_bits(_extrapolated_hat_basis(list(x), knots).ravel(order="F")),
                          _bits(ref.ravel(order="F")))
    # filtered without being written out (or, few columns or no recursion, written out for scipy)
    for b, a in (([0.4, -0.1, 0.3], [1.0, -1.3, 0.6]), ([1.0, 0.2], [1.0]), ([0.5], [1.0, -0.2, 0.1, 0.05])):
        want = signal.lfilter(b, a, ref[:-3], axis=0)
        out = hats.filtered(np.array(b), np.array(a), np.empty((x.size - 3, knots.size)), slice(0, x.size - 3))
        assert np.array_equal(_bits(out), _bits(want))
