"""Effects the model is not told about: parsing, ranges, and the physics each one imprints."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hil_sim.effects import EFFECTS, Effect, parse_effect
from hil_sim.experiments import TARE_SAMPLES, run_experiment
from rtlift.core.errors import UserError
from rtlift.core.rate import FS_HZ as FS

SEED = 5


@pytest.fixture(scope="module")
def baseline():
    return {n: run_experiment(n, seed=SEED).to_record() for n in ("random", "static", "sine_k0125")}


def with_effect(name, *specs):
    return run_experiment(name, seed=SEED, effects=list(specs)).to_record()


# -- parsing ---------------------------------------------------------------------------

def test_names_and_parameters_are_those_of_interfaces_md():
    assert {n: set(i.ranges) for n, i in EFFECTS.items()} == {
        "delay": {"seconds"},
        "sensor_resonance": {"frequency_hz", "damping_ratio"},
        "actuator_fade": {"final_fraction", "time_constant_s"},
        "zero_drift": {"rate_per_s", "amplitude", "time_constant_s"},
        "periodic_disturbance": {"frequency_hz", "amplitude"},
        "hysteresis": {"magnitude"},
    }


def test_bare_name_takes_the_defaults_and_defaults_lie_in_the_ranges():
    for name, info in EFFECTS.items():
        effect = parse_effect(name)
        assert dict(effect.params) == dict(info.defaults)
        for key, value in effect.params.items():
            lo, hi = info.ranges[key]
            assert lo <= value <= hi, (name, key)


def test_given_parameters_override_defaults():
    e = parse_effect(" sensor_resonance: frequency_hz=42.5 ")
    assert e.params == {"frequency_hz": 42.5, "damping_ratio": 0.05}


def test_zero_drift_takes_a_rate_or_an_exponential_approach():
    assert parse_effect("zero_drift:rate_per_s=1e-3").params == {"rate_per_s": 1e-3}
    e = parse_effect("zero_drift:amplitude=0.03,time_constant_s=12")
    assert e.params == {"amplitude": 0.03, "time_constant_s": 12.0}


@pytest.mark.parametrize("spec", [
    "wobble", "delay:secs=0.1", "delay:seconds=abc", "delay:seconds", "delay:seconds=-1",
    "delay:seconds=nan", "delay:seconds=1,seconds=2", "sensor_resonance:frequency_hz=250",
    "actuator_fade:final_fraction=1.5", "zero_drift:rate_per_s=1e-3,amplitude=0.1",
    "sensor_resonance:damping_ratio=0",
])
def test_a_bad_spec_is_a_one_line_user_error(spec):
    with pytest.raises(UserError) as info:
        parse_effect(spec)
    assert "\n" not in str(info.value) and spec.split(":")[0] in str(info.value)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(sorted(EFFECTS)), st.integers(0, 2**32 - 1))
def test_drawn_effects_lie_in_their_ranges_and_round_trip_through_the_spec(name, seed):
    info = EFFECTS[name]
    effect = info.draw(np.random.default_rng(seed))
    assert effect == info.draw(np.random.default_rng(seed))
    for key, value in effect.params.items():
        lo, hi = info.ranges[key]
        assert lo <= value <= hi
    again = parse_effect(effect.spec())
    assert again.name == name
    for key, value in effect.params.items():
        assert again.params[key] == pytest.approx(value, rel=1e-5)


def test_effects_are_recorded_in_the_metadata():
    rec = with_effect("train_T7", "delay:seconds=0.05", "hysteresis")
    assert rec.meta["effects"] == "delay:seconds=0.05; hysteresis:magnitude=0.15"
    assert run_experiment("train_T7").to_record().meta["effects"] == "none"


# -- physics ---------------------------------------------------------------------------

@pytest.mark.parametrize("seconds", [0.025, 0.06])
def test_delay_shifts_the_cross_correlation_peak_by_its_samples(baseline, seconds):
    rec = with_effect("random", Effect("delay", {"seconds": seconds}))
    a = baseline["random"].dcl - baseline["random"].dcl.mean()
    b = rec.dcl - rec.dcl.mean()
    lags = np.arange(-40, 41)
    xc = [np.dot(a[40:-40], b[40 + k:len(b) - 40 + k]) for k in lags]
    assert lags[int(np.argmax(xc))] == round(seconds * FS)
    np.testing.assert_array_equal(rec.extra["dcl_true"], baseline["random"].extra["dcl_true"])


@pytest.mark.parametrize("frequency_hz,damping_ratio", [(30.0, 0.05), (55.0, 0.03)])
def test_sensor_resonance_peaks_the_residual_spectrum_at_its_frequency(
        baseline, frequency_hz, damping_ratio):
    spec = f"sensor_resonance:frequency_hz={frequency_hz},damping_ratio={damping_ratio}"
    rec = with_effect("random", spec)
    base = baseline["random"]
    f, p_eff = signal.welch(rec.dcl, fs=FS, nperseg=800)
    _, p_base = signal.welch(base.dcl, fs=FS, nperseg=800)
    band = (f > 5) & (f < 150)
    ratio = p_eff[band] / p_base[band]
    assert f[band][np.argmax(ratio)] == pytest.approx(frequency_hz, abs=1.0)
    # |H|² at resonance is 1/(2ζ)² (100 for ζ = 0.05); electrical noise after the mode dilutes it
    assert ratio.max() > 0.3 / (2 * damping_ratio) ** 2
    low = (f > 0.4) & (f < 3.0)
    assert np.count_nonzero(low) == 5
    np.testing.assert_allclose(p_eff[low] / p_base[low], 1.0, atol=0.2)  # unit DC gain


def test_actuator_fade_lowers_late_lift_as_on_time_accumulates(baseline):
    base = baseline["sine_k0125"]
    rec = with_effect("sine_k0125", "actuator_fade:final_fraction=0.6,time_constant_s=3")
    true, true0 = rec.extra["dcl_true"], base.extra["dcl_true"]
    early = slice(TARE_SAMPLES, TARE_SAMPLES + int(4.1 * FS))  # two periods
    late = slice(len(true) - int(8.2 * FS), len(true))  # four periods
    on_time = np.count_nonzero(rec.cmu > 0) / FS  # ≈ 3.4 s of bursts by the end
    fraction_at_end = 0.6 + 0.4 * np.exp(-on_time / 3.0)
    assert true[early].mean() / true0[early].mean() > 0.93
    late_ratio = true[late].mean() / true0[late].mean()
    assert late_ratio < 0.85
    assert late_ratio == pytest.approx(fraction_at_end, abs=0.08)  # concave map: lift fades less than Cμ
    np.testing.assert_array_equal(rec.cmu, base.cmu)  # the command does not show it


def test_zero_drift_adds_a_ramp_of_its_rate_after_the_tare(baseline):
    base = baseline["random"]
    rec = with_effect("random", "zero_drift:rate_per_s=8e-4")
    diff = rec.dcl - base.dcl
    slope = np.polyfit(rec.t, diff, 1)[0]
    assert slope == pytest.approx(8e-4, rel=0.05)
    assert abs(diff[:TARE_SAMPLES].mean()) < 1e-3  # the tare absorbs the drift so far


def test_zero_drift_exponential_form_approaches_its_amplitude(baseline):
    base = baseline["random"]
    rec = with_effect("random", "zero_drift:amplitude=0.03,time_constant_s=10")
    diff = rec.dcl - base.dcl
    tare_part = np.mean(0.03 * (1 - np.exp(-rec.t[:TARE_SAMPLES] / 10)))
    assert diff[-400:].mean() == pytest.approx(0.03 * (1 - np.exp(-59.5 / 10)) - tare_part, abs=1e-3)


def test_periodic_disturbance_is_a_narrow_line_at_its_frequency(baseline):
    base = baseline["random"]
    rec = with_effect("random", "periodic_disturbance:frequency_hz=20,amplitude=0.006")
    f, p_eff = signal.welch(rec.dcl, fs=FS, nperseg=4000)
    _, p_base = signal.welch(base.dcl, fs=FS, nperseg=4000)
    excess = p_eff - p_base
    assert f[np.argmax(excess)] == pytest.approx(20.0, abs=0.1)
    assert np.count_nonzero(excess > 0.1 * excess.max()) <= 3  # narrow, not a bump
    diff = rec.dcl - base.dcl
    basis = np.column_stack([np.sin(2 * np.pi * 20 * rec.t), np.cos(2 * np.pi * 20 * rec.t)])
    coef = np.linalg.lstsq(basis, diff, rcond=None)[0]
    assert np.hypot(*coef) == pytest.approx(0.006, rel=0.03)


def test_hysteresis_raises_the_falling_branch_of_the_static_sweep(baseline):
    def gap(rec):
        top = int(np.argmax(rec.cmu_envelope))
        near = np.abs(rec.cmu_envelope - 0.011) < 5e-4
        up = rec.dcl[:top][near[:top]].mean()
        down = rec.dcl[top:][near[top:]].mean()
        return (down - up) / up

    assert gap(baseline["static"]) < 0.03
    assert gap(with_effect("static", "hysteresis:magnitude=0.15")) == pytest.approx(0.15, abs=0.04)


def test_effects_compose(baseline):
    base = baseline["random"]
    rec = with_effect("random", "delay:seconds=0.05", "periodic_disturbance:frequency_hz=33")
    f, p = signal.welch(rec.dcl, fs=FS, nperseg=4000)
    _, p0 = signal.welch(base.dcl, fs=FS, nperseg=4000)
    assert f[np.argmax(p - p0)] == pytest.approx(33.0, abs=0.1)
    a, b = base.extra["dcl_true"], rec.dcl
    lags = np.arange(0, 41)
    xc = [np.dot(a[:len(a) - 40] - a.mean(), b[k:len(b) - 40 + k] - b.mean()) for k in lags]
    assert lags[int(np.argmax(xc))] == 20


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_every_effect_at_its_default_changes_the_record_beyond_the_noise(baseline, name):
    base = baseline["random"]
    rec = with_effect("random", name)
    assert np.std(rec.dcl - base.dcl) > 0.004  # the bench noise σ is ≈ 0.004
