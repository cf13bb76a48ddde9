"""Samples → (Cμ, Cμ envelope, ΔCL): the streaming converter equals the calibration's batch
equations, tares as specified, flags bad samples; samples → a valid record file."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_io.calibration import Calibration, CalibrationError
from firmware_io.convert import Converter, record_from_samples, unwrap_seq
from firmware_io.samples import STATUS_ADC_SATURATED, STATUS_SENSOR_FAULT, Sample
from rtlift.core.records import read_record, write_record


def samples_for(rng, n=1200, seq0=65000, off=400, modulus=65536):
    out = []
    for k in range(n):
        volts = 0 if k < off or k % 50 >= 4 else int(rng.integers(100, 6000))
        ft = tuple(float(x) for x in rng.normal([-0.5, 0.1, 2.0, 0.001, 0.01, 0.0], 0.05))
        out.append(Sample((seq0 + k) % modulus, k * 2500, volts, 3000, ft, 1, float(k)))
    return out


def test_streaming_conversion_equals_the_calibration_equations(rng):
    m = np.eye(6) + 0.01 * rng.normal(size=(6, 6))
    cal = Calibration(matrix=tuple(map(tuple, m)), tare_cl=0.3, alpha_deg=18.0, sign_fx=-1.0,
                      cmu_table_v=(0.0, 20.0, 60.0, 80.0), cmu_table=(0.0, 0.0004, 0.0022, 0.003))
    conv = Converter(cal)
    samples = samples_for(rng, n=300, off=0)
    got = np.array([conv(s) for s in samples], dtype=float)
    ft = np.array([s.ft for s in samples]) @ m.T
    volts = np.array([s.volt_cv for s in samples]) / 100
    assert got[:, 0] == pytest.approx(cal.cmu_from_volts(volts), abs=1e-15)
    assert got[:, 1] == pytest.approx(cal.cmu_from_volts(np.full(300, 30.0)), abs=1e-15)
    assert got[:, 2] == pytest.approx(cal.cl_from_ft(ft) - 0.3, abs=1e-12)


def test_sixty_volts_is_cmu_0p0022_with_the_default_kappa():
    cmu, env, _ = Converter(Calibration(tare_cl=0.0))(Sample(0, 0, 6000, 3000, (0.0,) * 6, 0, 0.0))
    assert cmu == pytest.approx(0.0022, rel=1e-12) and env == pytest.approx(0.0022 / 4, rel=1e-12)


def test_flagged_samples_have_no_dcl():
    conv = Converter(Calibration(tare_cl=0.0))
    for bit in (STATUS_ADC_SATURATED, STATUS_SENSOR_FAULT):
        assert conv(Sample(0, 0, 0, 0, (1.0,) * 6, 1 | bit, 0.0))[2] is None
    assert conv(Sample(0, 0, 0, 0, (1.0,) * 6, 1 | 8, 0.0))[2] is not None


def test_tare_is_the_mean_cl_of_the_actuator_off_samples_in_the_first_tare_seconds(rng):
    cal = Calibration(tare_seconds=2.0)
    samples = samples_for(rng, n=1200, off=300)
    conv = Converter(cal, fs_hz=400.0)
    dcl = [conv(s)[2] for s in samples]
    assert all(d is None for d in dcl[:800]) and all(d is not None for d in dcl[800:])
    cl = np.array([conv.cl(s.ft) for s in samples])
    volts = np.array([s.volt_cv for s in samples], dtype=float)
    expected_tare = cal.tare_from(cl, volts, 400.0)
    assert conv.tare_cl == pytest.approx(expected_tare, abs=1e-12)
    assert dcl[-1] == pytest.approx(cl[-1] - expected_tare, abs=1e-12)


def test_taring_with_the_actuator_always_on_is_a_user_error():
    conv = Converter(Calibration(tare_seconds=0.01))
    with pytest.raises(CalibrationError):
        for k in range(10):
            conv(Sample(k, 0, 100, 100, (0.0,) * 6, 1, 0.0))


def test_seq_unwraps_across_the_wrap_and_keeps_gaps():
    assert unwrap_seq([65534, 65535, 1, 2], 65536).tolist() == [0, 1, 3, 4]
    assert unwrap_seq([250, 255, 3], 256).tolist() == [0, 5, 9]


def test_record_from_samples_round_trips_through_a_record_file(rng, tmp_path):
    samples = samples_for(rng)
    del samples[700]  # a lost sample leaves a gap in t
    samples[900].status |= STATUS_SENSOR_FAULT
    cal = Calibration()
    rec = record_from_samples(samples, cal, name="capture", meta={"link": "serial"})
    assert len(rec) == len(samples) - 1
    assert rec.t[0] == 0.0 and rec.t[-1] == pytest.approx((len(samples)) / 400.0)
    conv = Converter(cal)
    streamed = [conv(s) for s in samples]
    tail = [d for (_, _, d) in streamed[800:] if d is not None]
    assert rec.dcl[-len(tail):] == pytest.approx(tail, abs=1e-12)
    write_record(tmp_path / "capture.csv", rec)
    back = read_record(tmp_path / "capture.csv")
    assert back.meta["link"] == "serial" and math.isclose(back.fs_hz, 400.0)
    assert np.array_equal(back.dcl, rec.dcl) and np.array_equal(back.extra["seq"], rec.extra["seq"])
