"""Experiment programs (rtlift.core.programs): the standard campaign is one definition that the
bench renders exactly, program files round-trip, and a bad program file is one line, exit 2."""

from __future__ import annotations

import os
import re
import tempfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_io.calibration import Calibration
from hil_sim.experiments import TARE_SAMPLES, run_experiment
from rtlift.app.cli import main
from rtlift.core.programs import CAMPAIGN, ProgramError, read_program, standard_program

CAL = Calibration()


def _onsets(volts: np.ndarray) -> np.ndarray:
    on = volts > 0
    return np.flatnonzero(on & ~np.concatenate([[False], on[:-1]]))


@pytest.mark.parametrize("name", CAMPAIGN)
def test_every_bench_burst_starts_at_a_program_onset_with_its_envelope(name):
    program = standard_program(name, CAL.volts_from_cmu, seed=2)
    run = run_experiment(name, seed=2)
    onsets = {o.sample: o for o in program.onsets()}
    bursts = _onsets(run.volts) - TARE_SAMPLES
    assert len(run) == TARE_SAMPLES + program.samples()
    assert set(bursts) == {k for k, o in onsets.items() if o.envelope_v > 0}
    for k in bursts:
        assert run.volts[TARE_SAMPLES + k] == pytest.approx(onsets[k].envelope_v, abs=0.005)  # 0.01 V steps


def test_a_train_program_is_ten_bursts_three_times_with_the_rest_between():
    program = standard_program("train_T3p5", CAL.volts_from_cmu)
    on = [o for o in program.onsets() if o.envelope_v > 0]
    assert len(on) == 30
    gaps = np.diff([o.sample for o in on])
    assert sorted(set(gaps.tolist())) == [114, 114 + 490]            # 3.5 t+ = 114 samples; rest 15 t+ = 490
    assert {o.period_ms for o in on} == {286}                          # 285.8 ms in whole ms
    assert on[0].envelope_v == pytest.approx(60.0)


def test_the_random_program_follows_the_seed():
    a, b = (standard_program("random", CAL.volts_from_cmu, seed=s) for s in (1, 2))
    again = standard_program("random", CAL.volts_from_cmu, seed=1)
    assert np.array_equal(a.envelope_v, again.envelope_v) and not np.array_equal(a.envelope_v, b.envelope_v)


def test_a_program_file_round_trips_to_the_same_onsets(tmp_path):
    program = standard_program("train_T7", CAL.volts_from_cmu)
    path = tmp_path / "t7.csv"
    program.write(path)
    back = read_program(path)
    assert back.name == "train_T7" and back.source == str(path)
    assert back.onsets() == program.onsets()


def test_a_period_between_onsets_takes_effect_at_the_next_onset(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("t,envelope_v,burst_period_ms\n0,50,125\n0.2,80,250\n1.0,0,250\n")
    on = read_program(path).onsets()
    assert [o.sample for o in on] == [0, 50, 100, 200, 300]          # 125 ms until the onset at 0.25 s
    assert [o.envelope_v for o in on] == [50, 50, 80, 80, 80]


BAD = {
    "missing column": ("t,envelope_v\n0,1\n1,0\n", "column 'burst_period_ms' is missing"),
    "not a number": ("t,envelope_v,burst_period_ms\n0,abc,125\n1,0,125\n", "not a number"),
    "late start": ("t,envelope_v,burst_period_ms\n0.5,10,125\n1,0,125\n", "starts at t = 0"),
    "t backwards": ("t,envelope_v,burst_period_ms\n0,10,125\n2,10,125\n1,0,125\n", "not strictly increasing"),
    "too many volts": ("t,envelope_v,burst_period_ms\n0,250,125\n1,0,125\n", "outside 0"),
    "negative volts": ("t,envelope_v,burst_period_ms\n0,-1,125\n1,0,125\n", "outside 0"),
    "fractional period": ("t,envelope_v,burst_period_ms\n0,10,12.5\n1,0,125\n", "whole number of ms"),
    "short period": ("t,envelope_v,burst_period_ms\n0,10,5\n1,0,125\n", "shorter than two bursts"),
    "no first period": ("t,envelope_v,burst_period_ms\n0,10,0\n1,0,0\n", "must give a period"),
    "never off": ("t,envelope_v,burst_period_ms\n0,10,125\n1,10,125\n", "must be 0 (off)"),
    "rows too close": ("t,envelope_v,burst_period_ms\n0,10,125\n0.001,20,125\n1,0,125\n", "less than one sample"),
    "one row": ("t,envelope_v,burst_period_ms\n0,0,125\n", "at least 2 needed"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_program_file_is_one_line_and_exit_2(tmp_path, capsys, case):
    text, expected = BAD[case]
    path = tmp_path / "prog.csv"
    path.write_text(text)
    with pytest.raises(ProgramError, match=re.escape(expected)):
        read_program(path)
    code = main(["record", "--serial", str(tmp_path / "no-such-port"), str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and str(path) in err and expected in err
    assert not (tmp_path / "out").exists()                            # refused before anything else


def test_an_unknown_experiment_and_a_missing_file_are_one_line_and_exit_2(tmp_path, capsys):
    assert main(["record", "--serial", "x", "sine_k05", "--out", str(tmp_path)]) == 2
    assert "unknown experiment 'sine_k05'" in capsys.readouterr().err
    assert main(["record", "--serial", "x", str(tmp_path / "nope.csv"), "--out", str(tmp_path)]) == 2
    assert "no such file" in capsys.readouterr().err


def test_the_same_experiment_twice_is_refused(tmp_path, capsys):
    assert main(["record", "--serial", "x", "campaign", "random", "--out", str(tmp_path)]) == 2
    assert "given twice" in capsys.readouterr().err


def test_the_shipped_calibration_example_is_the_default_bench():
    from firmware_io.calibration import EXAMPLE_PATH

    assert Calibration.load(EXAMPLE_PATH) == Calibration()
    text = open(EXAMPLE_PATH, encoding="utf-8").read()
    for key in ("counts_per_n", "counts_per_nm", "matrix", "chord_m", "span_m", "alpha_deg", "u_inf_m_s",
                "rho_kg_m3", "sign_fx", "sign_fz", "tare_cl", "tare_seconds", "kappa", "cmu_table_v", "cmu_table"):
        assert f"{key} " in text or f"{key} =" in text, key


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.floats(-1, 5), st.floats(-10, 250), st.integers(-5, 70000)), min_size=0, max_size=6),
       st.sampled_from(["t,envelope_v,burst_period_ms", "t,envelope_v", "burst_period_ms,t,envelope_v"]))
def test_any_table_is_a_program_or_a_one_line_program_error(rows, header):
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "p.csv")
        with open(path, "w", encoding="utf-8") as f:
            f.write(header + "\n" + "".join(",".join(repr(v) for v in row) + "\n" for row in rows))
        try:
            program = read_program(path)
        except ProgramError as exc:
            assert "\n" not in str(exc) and path in str(exc)
        else:
            assert program.samples() >= 1 and program.envelope_v[-1] == 0
            assert all(0 <= o.sample < program.samples() for o in program.onsets())
