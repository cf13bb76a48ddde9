"""The standard campaign: programs, record columns, sensor chain, determinism, streaming."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import signal

from firmware_io.calibration import Calibration
from hil_sim.actuation import period_samples
from hil_sim.experiments import EXPERIMENTS, TARE_SAMPLES, daq_stream, run_experiment
from hil_sim.physics import BenchPhysics
from hil_sim.sensors import STATUS_ACTUATOR_ENABLED, STATUS_ADC_SATURATED, STATUS_BURST_ON
from rtlift.core.errors import UserError
from rtlift.core.rate import FS_HZ as FS

NAMES = ("static", "single_burst", "train_T1p75", "train_T3p5", "train_T7",
         "sine_k0125", "sine_k025", "random")


@pytest.fixture(scope="module")
def runs():
    return {n: run_experiment(n, seed=7) for n in NAMES}


def burst_starts(run):
    return np.flatnonzero(np.diff(np.r_[0, (run.volts != 0).astype(int)]) == 1)


def test_experiment_names_are_those_of_interfaces_md():
    assert tuple(EXPERIMENTS) == NAMES


def test_the_standard_campaign_is_about_five_minutes(runs):
    total = sum(len(r) for r in runs.values()) / FS
    assert 240.0 < total < 330.0


@pytest.mark.parametrize("name", NAMES)
def test_every_experiment_starts_with_two_seconds_actuator_off(runs, name):
    run = runs[name]
    assert np.all(run.volts[:TARE_SAMPLES] == 0) and np.all(run.envelope_volts[:TARE_SAMPLES] == 0)
    assert np.all(run.status[:TARE_SAMPLES] & STATUS_ACTUATOR_ENABLED == 0)
    assert run.volts[TARE_SAMPLES:].max() > 0


@pytest.mark.parametrize("name", NAMES)
def test_cmu_is_the_envelope_while_a_burst_is_on_and_zero_otherwise(runs, name):
    run = runs[name]
    on = run.volts != 0
    np.testing.assert_array_equal(run.cmu[on], run.cmu_envelope[on])
    assert np.all(run.cmu[~on] == 0)
    assert np.all(run.cmu_envelope <= 0.022 + 1e-6)
    np.testing.assert_allclose(run.volts * 100, np.round(run.volts * 100), atol=1e-6)  # 0.01 V
    np.testing.assert_allclose(run.cmu, Calibration().cmu_from_volts(run.volts), rtol=1e-12)
    lengths = np.diff(np.flatnonzero(np.diff(np.r_[0, on.astype(int), 0])))[::2]
    assert set(lengths.tolist()) == {4}  # Δt_b = 0.01 s


@pytest.mark.parametrize("name,t_plus", [("train_T1p75", 1.75), ("train_T3p5", 3.5),
                                          ("train_T7", 7.0)])
def test_trains_are_ten_bursts_at_60_volts_every_T(runs, name, t_plus):
    run = runs[name]
    starts = burst_starts(run)
    assert len(starts) == 30
    gaps = np.diff(starts).reshape(-1)
    assert np.count_nonzero(gaps == period_samples(t_plus)) == 27
    assert set(run.volts[run.volts != 0].tolist()) == {60.0}


def test_single_bursts_are_isolated_by_at_least_seven_convective_times(runs):
    starts = burst_starts(runs["single_burst"])
    assert len(starts) >= 10
    assert np.diff(starts).min() >= period_samples(7.0)
    assert set(runs["single_burst"].volts[runs["single_burst"].volts != 0].tolist()) == {60.0}


@pytest.mark.parametrize("name,k", [("sine_k0125", 0.125), ("sine_k025", 0.25)])
def test_sinusoids_have_the_reduced_frequency_and_8_hz_bursts(runs, name, k):
    run = runs[name]
    env = run.cmu_envelope[TARE_SAMPLES:]
    f, p = signal.periodogram(env - env.mean(), fs=FS)
    assert np.pi * f[np.argmax(p)] * 0.245 / 3.0 == pytest.approx(k, rel=0.03)
    assert set(np.diff(burst_starts(run)).tolist()) == {50}
    assert 0.0005 < env.min() and env.max() < 0.0215


def test_random_envelope_differs_between_seeds_and_covers_the_map(runs):
    env = runs["random"].cmu_envelope[TARE_SAMPLES:]
    assert env.std() > 0.004 and env.min() < 0.002 and env.max() > 0.019
    other = run_experiment("random", seed=8).cmu_envelope
    assert np.abs(other - runs["random"].cmu_envelope).max() > 0.005


def test_counts_and_status_follow_protocol_md(runs):
    run = runs["sine_k0125"]
    assert run.counts.shape == (len(run), 6) and run.counts.dtype.kind == "i"
    assert run.status.dtype == np.uint8
    np.testing.assert_array_equal(run.status & STATUS_BURST_ON != 0, run.volts != 0)
    np.testing.assert_array_equal(run.status & STATUS_ACTUATOR_ENABLED != 0, run.envelope_volts > 0)
    assert not np.any(run.status & STATUS_ADC_SATURATED)


def test_the_transducer_sees_stalled_lift_and_drag_resolved_into_its_axes(runs):
    run = runs["static"]
    cal = Calibration()
    ft = cal.ft_from_counts(run.counts[:TARE_SAMPLES]).mean(axis=0)
    assert cal.cl_from_ft(ft) == pytest.approx(0.70, abs=0.01)  # a non-zero tare
    sin, cos = np.sin(np.radians(20.0)), np.cos(np.radians(20.0))
    assert ft[0] == pytest.approx(cal.q_area * (-0.70 * sin + 0.28 * cos), abs=0.006)  # Fx (N)
    assert ft[2] == pytest.approx(cal.q_area * (0.70 * cos + 0.28 * sin), abs=0.006)  # Fz (N)


@pytest.mark.parametrize("name", ["sine_k0125", "train_T7"])
def test_record_is_tared_and_carries_about_0p004_noise(runs, name):
    rec = runs[name].to_record()
    noise = rec.dcl - rec.extra["dcl_true"]
    assert abs(noise.mean()) < 1e-3
    assert 0.003 < noise[:TARE_SAMPLES].std() < 0.005


def test_noise_has_a_broad_buffeting_bump_near_7_hz(runs):
    rec = runs["random"].to_record()
    f, p = signal.welch(rec.dcl - rec.extra["dcl_true"], fs=FS, nperseg=400)
    band = (f > 2) & (f < 100)
    assert 5.0 <= f[band][np.argmax(p[band])] <= 9.0
    peak = p[band].max()
    assert p[f == 7].item() > 3.0 * np.median(p[(f > 40) & (f < 100)])
    assert p[f == 4].item() > 0.25 * peak and p[f == 11].item() > 0.25 * peak  # broad, not a line


def test_a_rig_read_with_its_own_calibration_is_right_and_with_another_it_is_not():
    """The bench's truth is made with the rig's own constants (hil_sim.physics), not the host's
    calibration: a rig with other signs, angle and scale reads right only through a calibration
    that describes it; through the default one the error more than doubles (it does not cancel)."""
    rig = BenchPhysics(sign_fx=-1.0, alpha_deg=18.0, counts_per_n=2.0e5)
    right = run_experiment("train_T3p5", seed=1, physics=rig, calibration=rig.calibration()).to_record()
    wrong = run_experiment("train_T3p5", seed=1, physics=rig, calibration=Calibration()).to_record()
    err_right = np.std(right.dcl - right.extra["dcl_true"])
    assert err_right < 0.006
    assert np.std(wrong.dcl - wrong.extra["dcl_true"]) > 2.0 * err_right


def test_the_default_rig_is_the_one_the_default_calibration_describes():
    assert BenchPhysics().calibration() == Calibration()


def test_the_same_seed_gives_the_same_record_bit_for_bit():
    a = run_experiment("random", seed=11, effects=["periodic_disturbance", "delay"])
    b = run_experiment("random", seed=11, effects=["periodic_disturbance", "delay"])
    for field in ("volts", "envelope_volts", "dcl_true", "counts", "status"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    np.testing.assert_array_equal(a.to_record().dcl, b.to_record().dcl)


def test_different_seeds_give_different_noise():
    a = run_experiment("train_T7", seed=1)
    b = run_experiment("train_T7", seed=2)
    np.testing.assert_array_equal(a.dcl_true, b.dcl_true)  # same program, same plant
    noise_a = a.to_record().dcl - a.dcl_true
    noise_b = b.to_record().dcl - b.dcl_true
    assert abs(np.corrcoef(noise_a, noise_b)[0, 1]) < 0.1


def test_daq_stream_continues_the_experiment_in_one_second_chunks():
    run = run_experiment("train_T1p75", seed=4, effects=["sensor_resonance"])
    chunks = list(itertools.islice(daq_stream("train_T1p75", seed=4, effects=["sensor_resonance"]),
                                   12))
    assert all(len(c) == 400 for c in chunks)
    n = len(run)
    t = np.concatenate([c.t for c in chunks])
    np.testing.assert_allclose(t, np.arange(len(t)) / FS)
    first = slice(0, n)
    np.testing.assert_allclose(np.concatenate([c.dcl_true for c in chunks])[first], run.dcl_true,
                               atol=1e-12)
    counts = np.concatenate([c.counts for c in chunks])
    assert np.mean(counts[first] == run.counts) > 0.999  # rounding may differ in a rare sample
    volts = np.concatenate([c.volts for c in chunks])
    np.testing.assert_array_equal(volts[n:2 * n][:len(volts) - n], run.volts[:len(volts) - n])


def test_unknown_experiment_or_bad_seed_is_a_user_error():
    with pytest.raises(UserError, match="unknown experiment 'sine'"):
        run_experiment("sine")
    with pytest.raises(UserError, match="seed"):
        run_experiment("static", seed=-1)
    with pytest.raises(UserError, match="unknown effect"):
        run_experiment("static", effects=["wobble"])
