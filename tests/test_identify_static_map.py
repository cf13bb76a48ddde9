"""Static map identification: monotone smoothing, N(Cμ) = ΔCL/Cμ, hysteresis report."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rtlift.core.rate import FS_HZ as FS
from rtlift.identify.static_map import fit_static_map, isotonic_increasing

CMU_MAX = 0.022


def true_map(cmu: np.ndarray) -> np.ndarray:
    """Concave saturating map: ΔCL = 0.4 Cμ / (Cμ + 0.02); slope at 0 is 20, ΔCL(0.022) ≈ 0.21."""
    return 0.4 * cmu / (cmu + 0.02)


def sweep(rng: np.random.Generator, noise: float = 0.002, seconds: float = 60.0) -> np.ndarray:
    """Triangle 0 → 0.022 → 0 with 2 s holds at zero."""
    t = np.arange(int(seconds * FS)) / FS
    return CMU_MAX * np.interp(t, [0, 2, seconds / 2, seconds - 2, seconds], [0, 0, 1, 0, 0])


floats = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(floats, min_size=1, max_size=40), st.data())
def test_isotonic_fit_is_monotone_keeps_weighted_mean_and_stays_in_range(values, data):
    v = np.array(values)
    w = np.array(data.draw(st.lists(st.floats(0.1, 10.0), min_size=v.size, max_size=v.size)))
    f = isotonic_increasing(v, w)
    assert np.all(np.diff(f) >= -1e-9 * (1 + np.abs(f[1:])))
    assert np.isclose(np.sum(w * f), np.sum(w * v), rtol=1e-9, atol=1e-6)
    assert f.min() >= v.min() - 1e-9 and f.max() <= v.max() + 1e-9


@settings(max_examples=100, deadline=None)
@given(st.lists(floats, min_size=1, max_size=40))
def test_isotonic_fit_leaves_a_sorted_sequence_unchanged(values):
    v = np.sort(np.array(values))
    np.testing.assert_allclose(isotonic_increasing(v), v, rtol=0, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(st.lists(floats, min_size=2, max_size=40))
def test_isotonic_fit_is_the_least_squares_monotone_fit(values):
    """No monotone sequence is closer: the squared error is below that of the sorted data and
    of the constant mean (both monotone candidates)."""
    v = np.array(values)
    f = isotonic_increasing(v)
    err = np.sum((f - v) ** 2)
    assert err <= np.sum((np.full_like(v, v.mean()) - v) ** 2) + 1e-6
    assert err <= np.sum((np.maximum.accumulate(v) - v) ** 2) + 1e-6


def test_noisy_sweep_gives_the_map_to_half_a_percent_of_its_range(rng):
    env = sweep(rng)
    dcl = true_map(env) + rng.normal(0, 0.002, env.size)
    sm = fit_static_map(env, dcl, FS)
    grid = np.linspace(0.001, CMU_MAX, 50)
    err = np.max(np.abs(sm(grid) - true_map(grid)))
    assert err < 0.005 * true_map(CMU_MAX) + 0.001   # bin width bias of the concave map
    assert np.all(np.diff(sm.dcl) >= 0)
    assert sm.dcl[0] == 0.0 and sm.cmu[0] == 0.0


def test_gain_table_is_dcl_over_cmu_and_its_limit_slope_at_zero(rng):
    env = sweep(rng)
    dcl = true_map(env) + rng.normal(0, 0.001, env.size)
    sm = fit_static_map(env, dcl, FS)
    assert abs(sm.limit_slope - 20.0) / 20.0 < 0.05             # d(ΔCL)/dCμ at 0 = 0.4/0.02
    assert sm.gain[0] == sm.limit_slope                         # N(0): the limit, not 0/0
    inner = sm.gain_cmu[1:]
    np.testing.assert_allclose(sm.gain[1:] * inner, sm.dcl[1:], rtol=1e-12)
    assert np.all(np.isfinite(sm.gain))


def test_noise_free_sweep_recovers_n_to_one_percent():
    env = sweep(np.random.default_rng(0))
    sm = fit_static_map(env, true_map(env), FS, n_bins=40)
    c = sm.gain_cmu[2:]
    np.testing.assert_allclose(sm.gain[2:], true_map(c) / c, rtol=0.01)


def test_matching_branches_are_reported_as_no_hysteresis(rng):
    env = sweep(rng)
    sm = fit_static_map(env, true_map(env) + rng.normal(0, 0.002, env.size), FS)
    assert not sm.hysteresis.significant
    assert sm.hysteresis.max_gap_relative < 0.02


def test_gain_that_differs_on_falling_cmu_is_reported_as_hysteresis(rng):
    env = sweep(rng)
    falling = np.gradient(env) < 0
    dcl = true_map(env) * np.where(falling, 1.15, 1.0) + rng.normal(0, 0.002, env.size)
    h = fit_static_map(env, dcl, FS).hysteresis
    assert h.significant and h.verdict.startswith("hysteresis")
    assert 0.10 < h.max_gap_relative < 0.16                     # 15 % of ΔCL at the top
    assert h.loop_area > 0                                       # falling branch above


def test_a_lagging_response_is_told_apart_from_hysteresis(rng):
    """ΔCL lagging the envelope by 0.5 s opens a loop that a 0.5 s shift closes."""
    env = sweep(rng, seconds=20.0)
    lag = int(0.5 * FS)
    dcl = np.concatenate([np.zeros(lag), true_map(env)[:-lag]]) + rng.normal(0, 0.001, env.size)
    h = fit_static_map(env, dcl, FS).hysteresis
    assert h.significant
    assert "lag loop" in h.verdict
    assert abs(h.closing_lag_s - 0.5) <= 0.1
