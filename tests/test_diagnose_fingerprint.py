"""The residual fingerprint: departures from it on signals with a known answer.

A "residual" here is coloured noise (buffeting-like, AR(1)) of the same process at
identification and later, with or without a known change: a drift, a gain drift, a line, a
larger error level, a mode filtering part of it. The same process with another seed must stay
within the fingerprint; the change must leave it, in the right place and direction.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from rtlift.blocks.sensor_resonance import resonance_ba
from rtlift.core.rate import FS_HZ as FS
from rtlift.core.records import Record
from rtlift.effects.sensor_resonance import _spectral_mode
from rtlift.effects.surgery import Context
from rtlift.residual.fingerprint import (
    Z_DEPART,
    coef_departure,
    error_departure,
    print_for,
    psd_departure,
    summarize,
)
from rtlift.residual.stats import run_all

N = 16000                                           # 40 s
T = np.arange(N) / FS


def noise(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return signal.lfilter([0.01], [1.0, -0.9], rng.normal(size=N))


def yhat() -> np.ndarray:
    """A model output with a slow envelope (the regressions need a signal to scale)."""
    return 0.1 + 0.08 * np.sin(2 * np.pi * 0.3 * T)


def residual_tests(e: np.ndarray) -> dict:
    y = yhat()
    return run_all(y + e, e, y, y, y / 10.0, y / 10.0, FS)


@pytest.fixture(scope="module")
def fp() -> dict:
    e = noise(1)
    return summarize(residual_tests(e), e, FS)


def test_the_same_process_with_another_seed_stays_within_the_fingerprint(fp):
    t = residual_tests(noise(2))
    for key in ("slow_trend", "gain_trend", "direction"):
        assert abs(coef_departure(t[key], fp, key).z) < Z_DEPART
    assert abs(error_departure(noise(2), fp, FS).z) < Z_DEPART
    for lo in range(5, 190, 10):                                  # no band of the spectrum departs
        assert not psd_departure(t["spectrum"], fp, [(lo, lo + 10)], "band").departs


def test_an_offset_drift_departs_as_a_drift_and_not_as_a_gain_drift(fp):
    t = residual_tests(noise(2) + 1e-3 * T)
    assert coef_departure(t["slow_trend"], fp, "drift").z > Z_DEPART
    assert abs(coef_departure(t["gain_trend"], fp, "gain").z) < Z_DEPART
    assert t["slow_trend"].data["coef"] == pytest.approx(1e-3, rel=0.2)


def test_a_fading_gain_departs_as_a_gain_drift_and_not_as_an_offset_drift(fp):
    y = yhat()
    t = residual_tests(noise(2) - 0.01 * T * y)            # ΔCL lost: 1 %/s of the lift
    assert coef_departure(t["gain_trend"], fp, "gain").z < -Z_DEPART
    assert abs(coef_departure(t["slow_trend"], fp, "drift").z) < Z_DEPART
    assert t["gain_trend"].data["coef"] == pytest.approx(-0.01, rel=0.2)


def test_a_line_departs_at_its_frequency_only(fp):
    t = residual_tests(noise(2) + 0.003 * np.sin(2 * np.pi * 47.3 * T))
    df = float(t["spectrum"].data["f"][1])
    assert psd_departure(t["spectrum"], fp, [(47.3 - 1.5 * df, 47.3 + 1.5 * df)], "line").departs
    assert not psd_departure(t["spectrum"], fp, [(80.0, 90.0)], "elsewhere").departs


def test_a_larger_error_level_departs_and_its_z_grows_with_it(fp):
    z = [error_departure(noise(2) * k, fp, FS).z for k in (1.0, 1.15, 1.5)]
    assert abs(z[0]) < Z_DEPART < z[1] < z[2]


def test_a_mode_filtering_part_of_the_residual_is_found_from_the_spectrum_excess(fp):
    """70 % of the residual's power through a 31 Hz, ζ 0.05 mode, the rest added after it."""
    b, a = resonance_ba(31.0, 0.05, FS)
    e = np.sqrt(0.7) * signal.lfilter(b, a, noise(2)) + np.sqrt(0.3) * noise(3)
    ctx = Context(FS, 0, residual_tests(e), fp, ())
    f0, zeta = _spectral_mode(ctx, 5.0, 0.47 * FS, 0.005, 0.7)
    assert f0 == pytest.approx(31.0, rel=0.03)
    assert zeta == pytest.approx(0.05, rel=0.5)
    assert _spectral_mode(Context(FS, 0, residual_tests(noise(4)), fp, ()), 5.0, 0.47 * FS, 0.005, 0.7) is None


def test_a_pickup_line_beside_a_mode_does_not_pull_the_mode_to_it(fp):
    """The same mode with a strong 60.02 Hz sinusoid added (a pickup, 10x the line's share of
    the noise): the line stands far higher above the print than the mode, but a sinusoid has no
    mode's shape; the mode is still found at 31 Hz, not broadened beside the line."""
    b, a = resonance_ba(31.0, 0.05, FS)
    e = np.sqrt(0.7) * signal.lfilter(b, a, noise(2)) + np.sqrt(0.3) * noise(3) + 0.02 * np.sin(2 * np.pi * 60.02 * T)
    ctx = Context(FS, 0, residual_tests(e), fp, ())
    assert any(p.kind == "line" and abs(p.frequency_hz - 60.02) < 0.2 for p in ctx.tests["spectrum"].data["peaks"])
    f0, zeta = _spectral_mode(ctx, 5.0, 0.47 * FS, 0.005, 0.7)
    assert f0 == pytest.approx(31.0, rel=0.03)
    assert zeta == pytest.approx(0.05, rel=0.5)


def test_a_record_is_compared_with_its_own_type_and_says_so_otherwise(fp):
    model_print = {"version": 1, "start": 0, "records": {"sine_k0125": {**fp, "n": 100},
                                                          "static": {**fp, "n": 900}}}
    rec = Record(T[:10], T[:10], T[:10], T[:10], meta={"experiment": "sine_k0125"}, name="x")
    entry, note = print_for(model_print, rec)
    assert entry["n"] == 100 and "own sine_k0125" in note
    rec.meta = {}
    entry, note = print_for(model_print, rec)
    assert entry["n"] == 900 and "no x record" in note
    assert print_for({}, rec)[0] is None


def test_a_repeated_experiment_meets_the_models_own_misfit_on_it_and_another_does_not(tmp_path):
    """Known answer: the identification run is the model's output plus a systematic misfit the
    model has on that input plus noise; a later run of the same experiment (read back from its
    file) gives back exactly that run's misfit, so ΔCL − m is the model's output plus what
    changed (and the two runs' noise); a run of another input repeats nothing."""
    from rtlift.core.records import read_record, write_record
    from rtlift.model.validation import predict_record
    from rtlift.residual.fingerprint import fingerprint, input_digest, repeat_misfit
    from testkit.synthetic import burst_input, make_model

    rng = np.random.default_rng(5)
    model = make_model(rng)
    n = 4000
    cmu, env = burst_input(rng, n)
    t = np.arange(n) / FS
    yhat_id = predict_record(model, Record(t, cmu, env, np.zeros(n))).total
    misfit = 0.01 * np.sin(2 * np.pi * 0.5 * t)                     # what the model gets wrong on this input
    noise_id, noise_later = 0.002 * rng.normal(size=(2, n))
    change = 0.005 * (t > 5.0)                                      # what happens after identification
    fp = fingerprint(model, [Record(t, cmu, env, yhat_id + misfit + noise_id)], start=400)

    path = tmp_path / "later.csv"
    write_record(path, Record(t, cmu.copy(), env.copy(), yhat_id + misfit + change + noise_later))
    later = read_record(path)
    m, note = repeat_misfit(fp, model, later)
    assert m is not None and "repeats" in note
    assert np.max(np.abs(m - (misfit + noise_id))) < 1e-12
    assert np.max(np.abs(later.dcl - m - (yhat_id + change + noise_later - noise_id))) < 1e-12

    other = Record(t, 0.5 * cmu, 0.5 * env, yhat_id)
    assert input_digest(other) != input_digest(later)
    m_other, note_other = repeat_misfit(fp, model, other)
    assert m_other is None and "no identification experiment" in note_other
    assert repeat_misfit(None, model, later)[0] is None              # a model file from before repeats were kept
