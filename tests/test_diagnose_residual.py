"""Residual tests on signals whose answer is known."""

from __future__ import annotations

import numpy as np
from scipy import signal

from hil_sim.sensors import SensorParams, buffet_filter
from rtlift.core.rate import FS_HZ as FS
from rtlift.residual.stats import higher_order, input_crosscorr, lag_search, slow_trend, spectrum, whiteness

N = 16000


def test_white_noise_passes_whiteness_and_coloured_noise_fails():
    rng = np.random.default_rng(0)
    e = rng.normal(size=N)
    assert not whiteness(e).significant
    assert whiteness(signal.lfilter([1.0], [1.0, -0.5], e)).significant


def test_a_sinusoid_is_a_line_and_the_7hz_buffeting_is_only_a_bump():
    rng = np.random.default_rng(1)
    b, a = buffet_filter(SensorParams(), FS)
    buffet = signal.lfilter(b, a, rng.normal(size=N))
    buffet *= 0.003 / buffet.std()
    noise = 0.002 * rng.normal(size=N)
    peaks = spectrum(buffet + noise, FS).data["peaks"]
    assert not [p for p in peaks if p.kind in ("line", "resonance")]
    t = np.arange(N) / FS
    peaks = spectrum(buffet + noise + 0.003 * np.sin(2 * np.pi * 23.7 * t), FS).data["peaks"]
    lines = [p for p in peaks if p.kind == "line"]
    assert len(lines) == 1 and abs(lines[0].frequency_hz - 23.7) < 0.1


def test_billings_voon_sees_a_squared_term_the_linear_test_misses():
    rng = np.random.default_rng(2)
    u = signal.lfilter([1.0], [1.0, -0.9], rng.normal(size=N))
    u /= u.std()
    e = 0.3 * (u**2 - 1.0) + rng.normal(size=N)          # missed even nonlinearity
    assert not input_crosscorr(e, u, 20).significant or input_crosscorr(e, u, 20).statistic < 0.05
    bv = {r.name: r for r in higher_order(e, u, u, 20)}
    assert bv["bv_u2_e"].significant and bv["bv_u2_e"].statistic > 0.2


def test_lag_search_finds_a_shift_and_trend_test_a_drift():
    rng = np.random.default_rng(3)
    x = signal.lfilter([1.0], [1.0, -0.95], rng.normal(size=N))
    meas = np.concatenate([np.zeros(7), x[:-7]]) + 0.1 * rng.normal(size=N)
    assert lag_search(meas, x, FS).data["lag"] == 7
    t = np.arange(N) / FS
    drift, _ = slow_trend(1e-3 * t + 0.01 * rng.normal(size=N), x, FS)
    assert drift.significant and abs(drift.data["coef"] - 1e-3) < 1e-4
