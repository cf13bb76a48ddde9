"""The lift loop's design from the model (rtlift.app.control_design) and the gust it must reject.

The model is tests/data/bench_model.json (identified on the simulated bench in the paper's
structure; the paper's own printed model has an LTI pole at exactly z = 1, no static map to
linearise). Margins are python-control's; the closed-loop gust run is ``rtlift control``'s loop
in process on the bench (a few seconds of plant time)."""

from __future__ import annotations

import math
from pathlib import Path

import control as ct
import numpy as np
import pytest

from rtlift.app.control import ControlConfig, LiftController, config_from_gains_text, gains_text
from rtlift.app.control_design import Gains, design_loop, lifted_plant
from rtlift.app.hil_tracking import InProcessTracking
from rtlift.model.modelfile import load_model

MODEL = Path(__file__).parent / "data" / "bench_model.json"


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)


@pytest.fixture(scope="module")
def design(model):
    return design_loop(model)


def test_the_lifted_plant_has_unit_dc_gain_in_lift_units_and_one_period_of_delay(model):
    p, q = lifted_plant(model, LiftController(model), 0.08)
    assert p[0] == pytest.approx(0.0, abs=1e-9) and q[0] == pytest.approx(0.0, abs=1e-9)
    assert p.sum() == pytest.approx(1.0, abs=0.05)   # S⁻¹ then the model: ΔCL per ΔCL at DC
    # the latest value also carries the burst ripple at the decisions' fixed phase, ∝ Cμ
    assert q.sum() == pytest.approx(1.0, abs=0.05)


def test_the_design_meets_its_margins_by_python_control(design):
    for pt in design.points:
        gm, pm, _, _, _, _ = ct.stability_margins(pt.loop(design.dt))
        assert 20 * math.log10(gm) >= 6.0 - 0.05
        assert pm >= 45.0 - 0.5
        assert np.all(np.abs(ct.feedback(pt.loop(design.dt), 1).poles()) < 1.0)
        s = np.abs(pt.sensitivity(np.geomspace(0.01, 3.99, 800), design.dt))
        assert 20 * math.log10(s.max()) <= design.targets.peak_db + 0.05
        assert pt.f6_hz >= 0.35            # 6 dB of rejection predicted up to at least 0.35 Hz


def test_a_lead_lag_of_zero_and_no_fast_path_is_the_hand_set_pi(model):
    hand = LiftController(model, ControlConfig())
    same = LiftController(model, ControlConfig(schedule=((0.001, 0.5, 0.25, 0.0, 0.0, 0.0),
                                                         (0.02, 0.5, 0.25, 0.0, 0.0, 0.0))))
    rng = np.random.default_rng(0)
    for _ in range(2000):
        est = 0.08 + 0.01 * rng.standard_normal()
        assert hand.step(est, 0.1) == same.step(est, 0.1)


def test_scheduled_gains_are_interpolated_in_cmu(model):
    ctl = LiftController(model, ControlConfig(schedule=((0.002, 1.0, 0.2, 0.1, 0.5, 0.0),
                                                        (0.012, 3.0, 0.4, 0.3, 0.7, 1.0))))
    ctl._schedule_at(0.007)
    assert (ctl.kp, ctl.kx, ctl._a, ctl._b) == pytest.approx((2.0, 0.5, 0.2, 0.6))
    assert ctl._gain_i == pytest.approx(50 / (400 * 0.3))
    ctl._schedule_at(0.05)
    assert ctl.kp == pytest.approx(3.0)


def test_the_gains_round_trip_through_the_command_log_text(design):
    cfg = ControlConfig(schedule=design.schedule())
    assert config_from_gains_text(gains_text(cfg), True, 400.0) == cfg


def test_the_prediction_uses_the_loop_python_control_checks(design):
    pt = design.points[1]
    f = np.array([0.1, 0.35, 1.0])
    z = np.exp(2j * np.pi * f * design.dt)
    L = pt.loop(design.dt)
    np.testing.assert_allclose(pt.sensitivity(f, design.dt), 1 / (1 + L(z)), rtol=1e-9)
    g = Gains(0.5, design.dt / 0.25)
    assert g.kx == 0.0 and g.response(np.array([1e6 + 0j]))[0] == pytest.approx(0.5 + design.dt / 0.25, rel=1e-5)


def _amplitude(t, y, f, t0):
    sel = t >= t0
    x = np.c_[np.sin(2 * np.pi * f * t[sel]), np.cos(2 * np.pi * f * t[sel]), np.ones(sel.sum())]
    c = np.linalg.lstsq(x, y[sel], rcond=None)[0]
    return math.hypot(c[0], c[1])


def test_feedback_suppresses_a_gust_at_0_1_hz_by_at_least_6_db(model, design):
    """Constant reference 0.08, gust 0.01 at 0.1 Hz: the true lift's amplitude at 0.1 Hz over
    two whole periods after 4 s, feedback over feedforward only."""
    amp = {}
    for fb, cfg in ((False, ControlConfig(feedback=False)), (True, ControlConfig(schedule=design.schedule()))):
        run = InProcessTracking(model, LiftController(model, cfg), "steps:0.08@0", 24.0, effects=(),
                                gust="0.1:0.01").run()
        t, y, _ = run.traces()
        amp[fb] = _amplitude(t, y, 0.1, 4.0)
    assert amp[False] == pytest.approx(0.01, rel=0.02)   # feedforward only: the gust as it came
    assert 20 * math.log10(amp[True] / amp[False]) <= -6.0


def test_the_designed_loop_does_not_wind_up_at_an_unreachable_level(model, design):
    """0.10, then 0.35 for 4 s (beyond the static map's 0.22: the actuator pinned), then 0.10:
    the return settles (within 0.01 on the burst-period mean of the truth) in at most 1.5 s."""
    from rtlift.app.hil_tracking import reference_values, settling_times

    spec = "steps:0.10@0,0.35@4,0.10@8"
    run = InProcessTracking(model, LiftController(model, ControlConfig(schedule=design.schedule())), spec, 12.0,
                            effects=()).run()
    _, y, env = run.traces()
    settle = settling_times(y, reference_values(spec, len(y)))
    assert settle[0] is None                       # 0.35 is beyond reach
    assert env[int(7.5 * 400)] == pytest.approx(env.max())  # pinned at the limit there
    assert settle[1] is not None and settle[1] <= 1.5


def test_a_saved_design_report_gives_rtlift_control_the_same_schedule(model, design, tmp_path):
    from rtlift.app.commands.control import control_config
    from rtlift.app.commands.design import write_report

    out = tmp_path / "design"
    write_report(design, str(out), str(MODEL))
    assert (out / "report.md").exists() and (out / "bode.png").stat().st_size > 10_000
    config, source = control_config(model, True, None, None, str(out / "report.json"))
    assert config.schedule == design.schedule()
    assert source["source"].startswith("design file")


@pytest.mark.parametrize("text", ["{}", "not json", '{"points": [{"cmu": 0.01}]}'])
def test_a_bad_design_file_is_one_line_and_exit_2(tmp_path, capsys, text):
    from rtlift.app.cli import main

    bad = tmp_path / "r.json"
    bad.write_text(text)
    code = main(["control", "--serial", "/dev/null", "--model", str(MODEL), "--reference", "steps:0.1@0",
                 "--design", str(bad)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--design" in err[0]
