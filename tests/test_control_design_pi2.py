"""The ``pi2`` structure: the PI + lead–lag + K_x with a second lead–lag g₂ (Z − c)/(Z − d)
(rtlift.app.control_design.Gains, rtlift.app.control.LiftController).

On the bench model's cached design (tests/data: its lifted plants, observers and pulse responses) with
a second lead–lag added to a scheduled point's gains: the margins it states are the loop's
(python-control's |S| peak, each crossover's |L| and ∠L), the closed-loop poles agree with
python-control's, and the controller streams exactly the C(Z) the design analyses."""

from __future__ import annotations

import math
from pathlib import Path

import control as ct
import numpy as np
import pytest
from scipy.signal import lfilter

from rtlift.app.control import ControlConfig, LiftController, config_from_gains_text, gains_text
from rtlift.app.control_design import Design, Gains, check_point, load_design
from rtlift.model.modelfile import load_model
from testkit.loops import assert_crossovers_are_the_loop_s

MODEL = Path(__file__).parent / "data" / "bench_model.json"


@pytest.fixture(scope="module")
def model():
    return load_model(MODEL)


@pytest.fixture(scope="module")
def cached():
    return load_design(str(next(MODEL.parent.glob("bench_model.design-*.json"))))


def _with_lead2(cached: Design, c: float, d: float, kp: float | None = None) -> Design:
    """The cached design's scheduled points with a second lead–lag (c, d) on their gains (``kp``
    replacing theirs when given), checked as ``design_loop`` checks a point."""
    pts = []
    for pt in cached.scheduled:
        g = pt.gains
        g2 = Gains(g.kp if kp is None else kp, g.ki, g.a, g.b, g.kx, c, d)
        pts.append(check_point(pt.cmu, pt.dcl, np.asarray(pt.plant), np.asarray(pt.plant_point), g2, cached.dt,
                               np.asarray(pt.observer), pt.fs_hz, cached.uncertainty, tail=pt.observer_tail,
                               period=pt.observer_period, pulse=pt.pulse))
    return Design(pts, cached.dt, cached.period, cached.margin, cached.targets, cached.uncertainty, cached.observer)


@pytest.mark.parametrize("c, d", [(0.45, 0.7), (-0.3, 0.25), (0.6, 0.2)])
def test_a_second_lead_lag_s_margins_are_the_loop_s_and_agree_with_its_sensitivity_peak(cached, c, d):
    """Every point: |L| = 1 at each gain crossover (PM to 0.2°), ∠L = 180° at each phase crossover
    (|L| to 0.02 dB), the |S| peak python-control computes on 20001 points to Nyquist within 0.05 dB
    of the stated one and at least what each margin implies; stable by both pole computations alike."""
    design = _with_lead2(cached, c, d)
    assert design.structure == "pi2"
    for pt in design.points:
        L = pt.loop(design.dt)
        m = pt.margins
        assert m.gain_crossovers
        assert_crossovers_are_the_loop_s(pt, design.dt)
        f = np.linspace(1e-3, 0.5 / design.dt, 20001)
        lr = ct.frequency_response(L, 2 * np.pi * f).complex.ravel()
        peak = 20 * np.log10(np.max(np.abs(1 / (1 + lr))))
        assert peak == pytest.approx(m.peak_s_db, abs=0.05)
        for _, pm in m.gain_crossovers:
            assert peak >= -20 * math.log10(2 * math.sin(math.radians(pm) / 2)) - 0.01
        for _, db in m.phase_crossovers:
            assert peak >= -20 * math.log10(abs(1 - 10 ** (db / 20))) - 0.01
        poles = ct.feedback(L, 1).poles()
        assert pt.stable == bool(np.all(np.abs(poles) < 1.0))
        # C(Z) and L(Z) from their own frequency responses and python-control's transfer functions alike
        z = np.exp(2j * np.pi * np.array([0.1, 0.7, 3.0]) * design.dt)
        np.testing.assert_allclose(pt.gains.response(z), pt.gains.tf(design.dt)(z), rtol=1e-9)
        np.testing.assert_allclose(pt.loop_response(np.array([0.1, 0.7, 3.0]), design.dt), L(z), rtol=1e-9)


def test_an_unstable_second_lead_lag_is_found_unstable_by_both_pole_computations(cached):
    """A gain far beyond the margins: the characteristic polynomial and python-control both say
    unstable, and the design names it."""
    design = _with_lead2(cached, 0.45, 0.7, kp=25.0)
    for pt in design.points:
        assert not pt.stable
        assert np.any(np.abs(ct.feedback(pt.loop(design.dt), 1).poles()) >= 1.0)
    assert any(v.startswith("closed loop unstable") for v in design.violations())


def test_the_controller_streams_the_feedback_the_design_analyses(model):
    """One schedule row with a second lead–lag F on the whole feedback, the estimate one value for 49
    samples of each period and another on its last: the feedback v − r decided at each period is
    K_A e_A + K_X e_X with e_A the period's mean error, e_X the latest one, K_A = C − K_x F, K_X = K_x F,
    C = (K_p + K_i Z/(Z − 1)) g (Z − a)/(Z − b) F, F = g₂ (Z − c)/(Z − d), to 1e-12 (nothing saturates)."""
    g = Gains(0.8, 50 / (400 * 0.2), 0.3, 0.55, 0.6, -0.5, 0.4)
    ctl = LiftController(model, ControlConfig(schedule=((0.01, g.kp, 0.2, g.a, g.b, g.kx, g.c, g.d),)))
    rng = np.random.default_rng(3)
    e_body, e_last = 0.004 * rng.standard_normal((2, 60))
    ref, out = 0.08, []
    for eb, el in zip(e_body, e_last, strict=True):
        for k in range(50):
            ctl.step(ref - (eb if k < 49 else el), ref)
        assert ctl.updated and not ctl.saturated
        out.append(ctl.feedback_dcl)
    e_a, e_x = (49 * e_body + e_last) / 50, e_last
    cv = np.convolve
    g1, g2 = (1 - g.b) / (1 - g.a), (1 - g.d) / (1 - g.c)
    f_num, f_den = g2 * np.array([1.0, -g.c]), np.array([1.0, -g.d])
    c_num = cv(g1 * cv([g.kp + g.ki, -g.kp], [1.0, -g.a]), f_num)     # equal degrees: the same in Z⁻¹
    den = cv(cv([1.0, -1.0], [1.0, -g.b]), f_den)
    x_num = g.kx * cv(cv([1.0, -1.0], [1.0, -g.b]), f_num)
    want = lfilter(c_num - x_num, den, e_a) + lfilter(x_num, den, e_x)
    assert np.max(np.abs(want)) > 0.003
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-12)
    z = np.exp(2j * np.pi * np.array([0.1, 1.0, 4.0]) * 0.125)
    ka, kx = g.parts(z)                 # the design's K_A, K_X are the same filters
    np.testing.assert_allclose(ka, np.polyval(c_num - x_num, z) / np.polyval(den, z), rtol=1e-12)
    np.testing.assert_allclose(kx, np.polyval(x_num, z) / np.polyval(den, z), rtol=1e-12)


def test_six_column_rows_and_eight_with_no_second_lead_lag_decide_the_same_envelopes(model):
    six = ((0.002, 1.0, 0.2, 0.1, 0.5, 0.3), (0.012, 3.0, 0.4, 0.3, 0.7, 1.0))
    eight = tuple((*r, 0.0, 0.0) for r in six)
    a, b = LiftController(model, ControlConfig(schedule=six)), LiftController(model, ControlConfig(schedule=eight))
    rng = np.random.default_rng(0)
    for _ in range(2000):
        est = 0.08 + 0.01 * rng.standard_normal()
        assert a.step(est, 0.1) == b.step(est, 0.1)


def test_the_schedule_is_interpolated_in_every_column_and_round_trips(model, cached):
    ctl = LiftController(model, ControlConfig(schedule=((0.002, 1.0, 0.2, 0.1, 0.5, 0.0, 0.2, 0.4),
                                                        (0.012, 3.0, 0.4, 0.3, 0.7, 1.0, 0.6, 0.8))))
    ctl._schedule_at(0.007)
    assert (ctl.kp, ctl.kx, ctl._a, ctl._b, ctl._c, ctl._d) == pytest.approx((2.0, 0.5, 0.2, 0.6, 0.4, 0.6))
    assert ctl._g2 == pytest.approx(0.4 / 0.6)
    design = _with_lead2(cached, 0.45, 0.7)
    rows = design.schedule()
    assert all(len(r) == 8 and r[6:] == (0.45, 0.7) for r in rows)
    cfg = design.control_config()
    assert config_from_gains_text(gains_text(cfg), True, 400.0) == cfg
    again = Design.from_dict(design.to_dict())
    assert again.structure == "pi2" and again.schedule() == rows
    assert [p.margins.peak_s_db for p in again.points] == pytest.approx([p.margins.peak_s_db for p in design.points],
                                                                        abs=1e-9)
    with pytest.raises(ValueError, match="rows"):
        ControlConfig(schedule=((0.002, 1.0, 0.2, 0.1, 0.5, 0.0, 0.2),))
    with pytest.raises(ValueError, match="same number of columns"):
        ControlConfig(schedule=((0.002, 1.0, 0.2, 0.1, 0.5, 0.0), (0.01, 1.0, 0.2, 0.1, 0.5, 0.0, 0.2, 0.4)))
