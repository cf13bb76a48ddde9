"""Effect stages: each equals its equation (and the bench's effect), streams == batch to 1e-12,
and survives the model file."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hil_sim.effects import ActuatorFade as BenchFade
from hil_sim.effects import SensorResonance as BenchResonance
from rtlift.blocks.actuator_fade import ActuatorFade
from rtlift.blocks.delay import Delay
from rtlift.blocks.periodic_disturbance import PeriodicDisturbance, alias_hz
from rtlift.blocks.sensor_resonance import SensorResonance
from rtlift.blocks.stages import STAGES
from rtlift.blocks.wiener import NONLINEARITIES, HysteresisGain, OutputHysteresis
from rtlift.blocks.zero_drift import ZeroDrift
from rtlift.core.rate import FS_HZ as FS
from rtlift.model.modelfile import model_from_dict, model_to_dict
from testkit.synthetic import burst_input, make_model


def make_stage(name: str, rng: np.random.Generator):
    if name == "delay":
        return Delay(rng.integers(0, 30) / FS, FS)
    if name == "actuator_fade":
        return ActuatorFade(rng.uniform(0.3, 1.0), rng.uniform(0.05, 5.0), FS,
                            str(rng.choice(ActuatorFade.CLOCKS)), float(rng.choice([0.0, rng.uniform(0.0, 5.0)])))
    if name == "sensor_resonance":
        return SensorResonance(rng.uniform(5.0, 190.0), rng.uniform(0.02, 0.7), FS)
    if name == "zero_drift_linear":
        return ZeroDrift(FS, rate_per_s=rng.uniform(-2e-3, 2e-3), offset=rng.uniform(-0.01, 0.01))
    if name == "zero_drift_exp":
        return ZeroDrift(FS, amplitude=rng.uniform(-0.05, 0.05), time_constant_s=rng.uniform(0.01, 60),
                         offset=rng.uniform(-0.01, 0.01))
    harmonics = [{"n": int(n), "amplitude": rng.uniform(0.0005, 0.006), "phase_rad": rng.uniform(-4, 4)}
                 for n in rng.choice([2, 3, 5, 7], size=int(rng.integers(0, 4)), replace=False)]
    return PeriodicDisturbance(rng.uniform(0.5, 200.0), rng.uniform(0.001, 0.02),
                               rng.uniform(-4, 4), FS, harmonics)


KINDS = ["delay", "actuator_fade", "sensor_resonance", "zero_drift_linear", "zero_drift_exp",
         "periodic_disturbance"]


def run_steps(stage, a, b):
    if stage.where == "input":
        out = [stage.step(x, y) for x, y in zip(a, b, strict=True)]
        return np.array([o[0] for o in out]), np.array([o[1] for o in out])
    return np.array([stage.step(x) for x in a])


def run_batch(stage, a, b):
    return stage.simulate(a, b) if stage.where == "input" else stage.simulate(a)


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(KINDS), st.integers(0, 2**31 - 1), st.lists(st.integers(1, 300), min_size=1, max_size=4))
def test_every_stage_steps_and_chunks_agree_to_1e12(kind, seed, cuts):
    rng = np.random.default_rng(seed)
    n = sum(cuts)
    cmu, env = burst_input(rng, n)
    dcl = 0.1 * env / 0.011 + rng.normal(0, 0.004, n)
    a, b = (cmu, env) if kind in ("delay", "actuator_fade") else (dcl, None)
    s1, s2 = make_stage(kind, rng), None
    s2 = STAGES[s1.name].from_params(s1.params(), FS)
    stepped = run_steps(s1, a, b if b is not None else a)
    parts, i = [], 0
    for c in cuts:
        parts.append(run_batch(s2, a[i:i + c], None if b is None else b[i:i + c]))
        i += c
    if s1.where == "input":
        batch = (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))
        np.testing.assert_allclose(stepped[0], batch[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(stepped[1], batch[1], rtol=0, atol=1e-12)
    else:
        np.testing.assert_allclose(stepped, np.concatenate(parts), rtol=0, atol=1e-12)
    np.testing.assert_allclose(s1.get_state(), s2.get_state(), rtol=1e-9, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.lists(st.integers(1, 300), min_size=1, max_size=4), st.booleans(),
       st.sampled_from(("cmu", "lift")))
def test_hysteresis_gain_steps_and_chunks_agree_to_1e12(seed, cuts, output_form, driver):
    rng = np.random.default_rng(seed)
    n = sum(cuts)
    env = np.round(np.clip(0.011 + 0.01 * np.sin(np.arange(n) / rng.uniform(5, 50)), 0, 0.022), 5)
    env = np.clip(env + rng.normal(0, 0.001, n) * rng.integers(0, 2), 0, None)     # small reversals too
    y = env * rng.uniform(0.8, 1.2)
    args = (rng.uniform(-0.3, 0.3), rng.choice([0.0, rng.uniform(0.001, 1.0)]), FS,
            rng.choice([0.0, rng.uniform(0.0005, 0.01)]) * (1.0 if driver == "cmu" else 10.0),
            rng.uniform(0.7, 1.2), driver)
    grid = np.linspace(0, 0.022, 6)
    nl1 = OutputHysteresis(grid, 10 * grid + rng.uniform(0, 0.01, 6), *args) if output_form else \
        HysteresisGain(grid, 10 + rng.uniform(0, 3, 6), *args)
    nl2 = NONLINEARITIES[nl1.form].from_dict(nl1.to_dict())
    stepped = np.array([nl1.step(c, v) for c, v in zip(env, y, strict=True)])
    parts, i = [], 0
    for c in cuts:
        parts.append(nl2.simulate(env[i:i + c], y[i:i + c]))
        i += c
    np.testing.assert_allclose(stepped, np.concatenate(parts), rtol=0, atol=1e-12)
    np.testing.assert_allclose(nl1.get_state(), nl2.get_state(), atol=1e-15)


def test_hysteresis_gain_is_one_plus_m_on_a_falling_envelope():
    nl = HysteresisGain([0.0, 0.022], [10.0, 10.0], 0.2, 0.0, FS)
    env = np.concatenate([np.linspace(0, 0.02, 50), np.linspace(0.02, 0, 50)])
    out = nl.simulate(env, env)
    np.testing.assert_allclose(out[1:50], 10 * env[1:50], rtol=1e-12)
    np.testing.assert_allclose(out[51:], 1.2 * 10 * env[51:], rtol=1e-12)


def test_hysteresis_play_operator_keeps_its_branch_through_reversals_narrower_than_its_width():
    """Rising to 0.02, a dip of 0.001 (< w = 0.004) stays on the rising branch; falling by more
    than w moves to the falling one, with the gain ratio 1 + m and the rising branch at g."""
    nl = OutputHysteresis([0.0, 1.0], [0.0, 1.0], 0.3, 0.0, FS, width=0.004, rising_gain=0.9)
    env = np.concatenate([np.linspace(0, 0.02, 200), np.linspace(0.02, 0.019, 10),
                          np.linspace(0.019, 0.02, 10), np.linspace(0.02, 0.01, 200)])
    factor = nl.simulate(env, np.ones_like(env))
    assert factor[199] == pytest.approx(0.9, abs=1e-12)                      # rising branch: g
    assert np.max(factor[200:220]) < 0.9 * (1 + 0.3 * 0.3)                   # a 0.001 dip: barely moves
    assert factor[-1] == pytest.approx(0.9 * 1.3, abs=1e-12)                 # fell by > w: g (1 + m)


def test_pickup_lines_are_the_fundamental_and_its_harmonics_as_sampled():
    stage = PeriodicDisturbance(60.02, 0.02, 0.4, FS, [{"n": 3, "amplitude": 0.006, "phase_rad": 1.0},
                                                        {"n": 7, "amplitude": 0.002, "phase_rad": -0.5}])
    assert stage.line_hz == pytest.approx([60.02, 180.06, 20.14])            # 420.14 Hz folds to 20.14
    assert alias_hz(300.1, FS) == pytest.approx(99.9)
    t = np.arange(8000) / FS
    expected = (0.02 * np.sin(2 * math.pi * 60.02 * t + 0.4) + 0.006 * np.sin(2 * math.pi * 180.06 * t + 1.0)
                + 0.002 * np.sin(2 * math.pi * 20.14 * t - 0.5))
    np.testing.assert_allclose(stage.simulate(np.zeros(t.size)), expected, atol=1e-12)


def test_fade_on_the_wall_clock_fades_while_the_actuator_rests():
    on, wall = ActuatorFade(0.5, 1.0, FS, "on_time"), ActuatorFade(0.5, 1.0, FS, "time")
    cmu = np.zeros(400)                                   # one second with no burst
    env = np.ones(400)
    assert on.simulate(cmu, env)[1][-1] == 1.0
    assert wall.simulate(cmu, env)[1][-1] == pytest.approx(0.5 + 0.5 * math.exp(-399 / 400), rel=1e-12)


@pytest.mark.parametrize("clock", ActuatorFade.CLOCKS)
def test_a_fade_started_at_its_clock_e0_goes_on_as_one_that_ran_that_long(clock):
    """A fade at rest with its clock at E₀ gives what a fade from E = 0 gives once its clock has run
    E₀ (the on-time of bursts, or wall time): the same curve, continued; reset takes it back to E₀,
    and the model file keeps E₀."""
    cmu, env = burst_input(np.random.default_rng(4), 4000)
    head = int(np.argmax(np.cumsum(cmu > 0) >= 200)) + 1 if clock == "on_time" else 200   # 0.5 s of the clock
    ran = ActuatorFade(0.6, 1.5, FS, clock)
    ran.simulate(cmu[:head], env[:head])
    assert ran.on_time == pytest.approx(0.5, abs=1e-12)
    ran_for = ran.on_time
    later = ActuatorFade(0.6, 1.5, FS, clock, on_time0_s=ran_for)
    np.testing.assert_allclose(later.simulate(cmu[head:], env[head:])[0],
                               ran.simulate(cmu[head:], env[head:])[0], rtol=1e-12, atol=1e-15)
    later.reset()
    assert later.on_time == ran_for
    again = ActuatorFade.from_params(later.params(), FS)
    assert again.params() == later.params() and again.on_time == ran_for
    assert "on_time0_s" not in ActuatorFade(0.6, 1.5, FS, clock).params()      # model files as before


def test_resonance_equals_the_bench_mode_and_has_unity_dc_gain():
    rng = np.random.default_rng(3)
    x = rng.normal(size=2000)
    stage = SensorResonance(30.0, 0.05, FS)
    bench = BenchResonance({"frequency_hz": 30.0, "damping_ratio": 0.05}, FS)
    bench.zi = np.zeros((2, 1))
    np.testing.assert_allclose(stage.simulate(x), bench.process(x[:, None])[:, 0], atol=1e-12)
    stage.reset()
    assert stage.simulate(np.ones(4000))[-1] == pytest.approx(1.0, abs=1e-9)
    f, h = signal.freqz(stage.b, stage.a, worN=[30.0], fs=FS)
    assert abs(h[0]) == pytest.approx(1 / (2 * 0.05), rel=0.01)      # peak gain Q = 1/(2ζ)


def test_resonance_statespace_reproduces_the_filter_on_its_own_state():
    stage = SensorResonance(45.0, 0.1, FS)
    A, B, C, D = stage.statespace()
    rng = np.random.default_rng(4)
    u = rng.normal(size=300)
    x = np.zeros(2)
    out = []
    for v in u:
        x = A @ x + B * v
        out.append(C @ x + D * v)
    np.testing.assert_allclose(out, stage.simulate(u), atol=1e-12)
    np.testing.assert_allclose(stage.get_state(), x, atol=1e-12)


def test_fade_equals_the_bench_actuator_fade():
    rng = np.random.default_rng(5)
    cmu, env = burst_input(rng, 3000)
    params = {"final_fraction": 0.6, "time_constant_s": 3.0}
    out, _ = ActuatorFade.from_params(params, FS).simulate(cmu, env)
    np.testing.assert_allclose(out, BenchFade(params, FS).process(cmu), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("stage, expected", [
    (ZeroDrift(FS, rate_per_s=1e-3, offset=-0.001), lambda t: -0.001 + 1e-3 * t),
    (ZeroDrift(FS, amplitude=0.03, time_constant_s=2.0, offset=0.002),
     lambda t: 0.002 + 0.03 * (1 - np.exp(-t / 2.0))),
    (PeriodicDisturbance(20.0, 0.006, 0.7, FS), lambda t: 0.006 * np.sin(2 * math.pi * 20 * t + 0.7)),
])
def test_additive_stages_add_their_disturbance_and_their_statespace_generates_it(stage, expected):
    t = np.arange(4000) / FS
    np.testing.assert_allclose(stage.simulate(np.zeros(t.size)), expected(t), atol=1e-12)
    A, B, C, D = stage.statespace()
    assert stage.kind == "additive" and not B.any() and float(D) == 1.0
    stage.reset()
    x = stage.get_state()
    gen = []
    for _ in range(t.size):
        x = A @ x
        gen.append(C @ x)
    np.testing.assert_allclose(gen, expected(t), atol=1e-12)


def test_augmented_model_round_trips_through_the_model_file():
    rng = np.random.default_rng(6)
    model = make_model(rng)
    aug = model.with_stages(input_stages=[Delay(0.01, FS), ActuatorFade(0.7, 2.0, FS)],
                            output_stages=[SensorResonance(30, 0.05, FS),
                                           ZeroDrift(FS, rate_per_s=4e-4, offset=-4e-4),
                                           PeriodicDisturbance(20, 0.006, 1.0, FS)])
    d = model_to_dict(aug)
    nl = aug.wiener.nonlinearity
    d["wiener"]["nonlinearity"] = HysteresisGain(nl.cmu, nl.gain, 0.15, 0.25, FS).to_dict()
    aug = model_from_dict(d)
    back = model_from_dict(model_to_dict(aug))
    cmu, env = burst_input(rng, 2000)
    np.testing.assert_allclose(aug.simulate(cmu, env).total, back.simulate(cmu, env).total, atol=1e-12)
    aug.reset()
    stepped = np.array([aug.step(c, e)[0] for c, e in zip(cmu, env, strict=True)])
    back.reset()
    np.testing.assert_allclose(stepped, back.simulate(cmu, env).total, atol=1e-12)


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError):
        SensorResonance(250.0, 0.05, FS)
    with pytest.raises(ValueError):
        ActuatorFade(1.5, 3.0, FS)
    with pytest.raises(ValueError):
        ZeroDrift(FS, rate_per_s=1e-3, amplitude=0.1)
    with pytest.raises(ValueError):
        PeriodicDisturbance(20.0, float("nan"), 0.0, FS)
