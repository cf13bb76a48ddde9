"""The compiled HybridModel.step: the pure-Python reference_step is its judge (1e-12), it advances
the same state, and models it cannot compile fall back to the reference."""

from __future__ import annotations

import copy
import pickle
from importlib.resources import files

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtlift.blocks.stages import ActuatorFade, Delay, PeriodicDisturbance, SensorResonance, ZeroDrift
from rtlift.blocks.wiener import HysteresisGain, OutputHysteresis
from rtlift.modelfile import load_model
from testkit.synthetic import burst_input, make_model

TOL = 1e-12
FS = 400.0


def _run(step, cmu, env):
    return np.array([step(c, e) for c, e in zip(cmu, env, strict=True)]).reshape(-1, 3).T


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), kernel_len=st.integers(1, 60),
       order=st.integers(1, 3), hp_order=st.integers(1, 4), output_form=st.booleans(),
       delay=st.integers(0, 5), warm=st.integers(0, 50))
def test_compiled_step_equals_reference_step(seed, n, kernel_len, order, hp_order, output_form, delay, warm):
    """(ΔCL, ΔCL_H, ΔCL_L) and the state after the steps agree to 1e-12, from any starting state."""
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=kernel_len, order=order, hp_order=hp_order, output_form=output_form)
    if delay:
        m.input_stages = (Delay(delay / FS, FS),)
    assert m.compiled
    cmu, env = burst_input(rng, n + warm)
    _run(m.reference_step, cmu[:warm], env[:warm])         # a state that is not the rest state
    start = m.get_state()
    compiled = _run(m.step, cmu[warm:], env[warm:])
    after_compiled = m.get_state()
    m.set_state(start)
    reference = _run(m.reference_step, cmu[warm:], env[warm:])
    scale = max(1.0, float(np.max(np.abs(reference))))
    np.testing.assert_allclose(compiled, reference, atol=TOL * scale, rtol=0)
    np.testing.assert_allclose(after_compiled, m.get_state(), atol=TOL, rtol=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cut=st.integers(0, 200), delay=st.integers(0, 3))
def test_compiled_state_round_trips_through_get_and_set_state(seed, cut, delay):
    """Stop anywhere, checkpoint, restore into a fresh model: the rest of the record is identical."""
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=25, order=2)
    m.input_stages = (Delay(delay / FS, FS),)
    cmu, env = burst_input(rng, 200)
    whole = _run(m.step, cmu, env)
    m.reset()
    _run(m.step, cmu[:cut], env[:cut])
    saved = m.get_state()
    m.reset()
    m.set_state(saved)
    np.testing.assert_array_equal(_run(m.step, cmu[cut:], env[cut:]), whole[:, cut:])


def test_paper_model_takes_the_compiled_step():
    m = load_model(files("rtlift") / "data" / "paper_model.json", allow_unstable=True)
    assert m.compiled


@pytest.mark.parametrize("output_form", [False, True])
def test_identified_model_forms_take_the_compiled_step(output_form):
    """What rtlift identify writes: input_gain or output form, with or without a dead-time delay."""
    m = make_model(np.random.default_rng(3), output_form=output_form)
    assert m.compiled
    m.input_stages = (Delay(1 / FS, FS),)
    assert m.compiled


def _fallback_models():
    rng = np.random.default_rng(4)
    m = make_model(rng)
    yield "zero_drift", m.with_stages(output_stages=(ZeroDrift(FS, rate_per_s=0.01, offset=0.001),))
    yield "sensor_resonance", m.with_stages(output_stages=(SensorResonance(30.0, 0.1, FS),))
    yield "periodic_disturbance", m.with_stages(output_stages=(PeriodicDisturbance(20.0, 0.002, 0.3, FS),))
    yield "actuator_fade", m.with_stages(input_stages=(ActuatorFade(0.7, 2.0, FS),))
    yield "two_delays", m.with_stages(input_stages=(Delay(1 / FS, FS), Delay(2 / FS, FS)))
    for cls in (HysteresisGain, OutputHysteresis):
        h = make_model(rng, output_form=cls is OutputHysteresis)
        nl = h.wiener.nonlinearity
        table = (nl.cmu, nl.gain) if cls is HysteresisGain else (nl.y, nl.f)
        h.wiener.nonlinearity = cls(*table, magnitude=0.2, time_constant_s=0.1, fs_hz=FS)
        yield cls.form, h


@pytest.mark.parametrize("name,model", list(_fallback_models()), ids=lambda v: v if isinstance(v, str) else "")
def test_models_with_uncompiled_effects_step_with_the_reference(name, model):
    assert not model.compiled
    cmu, env = burst_input(np.random.default_rng(5), 300)
    stepped = _run(model.step, cmu, env)
    model.reset()
    np.testing.assert_array_equal(stepped, _run(model.reference_step, cmu, env))


def test_assigning_stages_switches_between_compiled_and_reference():
    m = make_model(np.random.default_rng(6))
    assert m.compiled
    m.output_stages = (ZeroDrift(FS, rate_per_s=0.01),)
    assert not m.compiled
    m.output_stages = ()
    assert m.compiled


def test_warm_up_leaves_the_state_untouched():
    rng = np.random.default_rng(7)
    m = make_model(rng)
    cmu, env = burst_input(rng, 50)
    _run(m.step, cmu, env)
    before = m.get_state()
    assert m.warm_up() >= 0.0
    np.testing.assert_array_equal(m.get_state(), before)


def test_copies_do_not_share_state_with_the_original():
    m = make_model(np.random.default_rng(8))
    m.step(0.01, 0.01)
    before = m.get_state()
    for twin in (copy.deepcopy(m), pickle.loads(pickle.dumps(m))):
        assert twin.compiled
        twin.step(0.02, 0.02)
        np.testing.assert_array_equal(m.get_state(), before)
        assert not np.array_equal(twin.get_state(), before)


def test_integer_and_numpy_scalar_inputs_give_the_float_result():
    m = make_model(np.random.default_rng(9))
    compiled = m.step(np.float64(0.01), 1)
    m.reset()
    assert compiled == pytest.approx(m.reference_step(0.01, 1.0), abs=1e-15)
