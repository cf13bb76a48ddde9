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

from rtlift.blocks.actuator_fade import ActuatorFade
from rtlift.blocks.delay import Delay
from rtlift.blocks.onset_hold import OnsetHold
from rtlift.blocks.periodic_disturbance import PeriodicDisturbance
from rtlift.blocks.sensor_resonance import SensorResonance
from rtlift.blocks.wiener import HysteresisGain, OutputHysteresis
from rtlift.blocks.zero_drift import ZeroDrift
from rtlift.core.rate import FS_HZ as FS
from rtlift.model.modelfile import load_model
from testkit.synthetic import (
    assert_batch_equals_reference,
    assert_step_equals_reference,
    burst_input,
    make_model,
    step_rows,
)

TOL = 1e-12


def _stages(delay: int, fade: int, hold: int = 0) -> tuple:
    """At most one ``delay`` of ``delay`` samples, then (``fade`` 1: on-time clock, at 0.02 s at rest;
    2: wall clock, from 0) an ``actuator_fade`` whose time constant the test inputs reach, and (``hold`` 1: first, 2:
    after the delay, 3: after the fade) an ``onset_hold``: the compiled step's stages."""
    stages = (Delay(delay / FS, FS),) if delay else ()
    if fade:
        stages += (ActuatorFade(0.6, 0.05, FS, *(("on_time", 0.02) if fade == 1 else ("time", 0.0))),)
    if hold:
        at = (0, len(stages) - (1 if fade else 0), len(stages))[hold - 1]
        stages = (*stages[:at], OnsetHold(FS), *stages[at:])
    return stages


OUTPUT_STAGES = (
    lambda: ZeroDrift(FS, rate_per_s=0.01, offset=0.001),
    lambda: ZeroDrift(FS, amplitude=-0.02, time_constant_s=0.3, offset=0.002),
    lambda: SensorResonance(30.0, 0.1, FS),
    lambda: PeriodicDisturbance(50.0, 0.002, 0.3, FS, [{"n": 3, "amplitude": 0.001, "phase_rad": 1.0},
                                                         {"n": 5, "amplitude": 0.0005}]),
)
"""Output stages, any of which the compiled step takes, in any number and order."""


def _outputs(picks: list[int]) -> tuple:
    return tuple(OUTPUT_STAGES[i]() for i in picks)


output_picks = st.lists(st.integers(0, len(OUTPUT_STAGES) - 1), max_size=3)


def _hysteresis(m, kind: int) -> None:
    """The model's Wiener nonlinearity with the ``hysteresis`` factor (kind 1: driven by Cμ_env,
    a sharp switch; 2: by the lift, a play operator of finite width), in its own form; 0: none."""
    if not kind:
        return
    nl = m.wiener.nonlinearity
    width, driver = (0.0, "cmu") if kind == 1 else (0.004, "lift")
    if hasattr(nl, "gain_at"):
        m.wiener.nonlinearity = HysteresisGain(nl.cmu, nl.gain, 0.3, 0.02, FS, width, 0.9, driver)
    else:
        m.wiener.nonlinearity = OutputHysteresis(nl.y, nl.f, 0.3, 0.02, FS, width, 0.9, driver)
    m.wiener = m.wiener                  # bound again (a part swapped inside a block is not seen)


hysteresis_kinds = st.integers(0, 2)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), kernel_len=st.integers(1, 60),
       order=st.integers(1, 3), hp_order=st.integers(1, 4), output_form=st.booleans(),
       delay=st.integers(0, 5), fade=st.integers(0, 2), warm=st.integers(0, 50), outputs=output_picks,
       hysteresis=hysteresis_kinds, hold=st.integers(0, 3))
def test_compiled_step_equals_reference_step(seed, n, kernel_len, order, hp_order, output_form, delay, fade, warm,
                                             outputs, hysteresis, hold):
    """(ΔCL, ΔCL_H, ΔCL_L) and the state after the steps agree to 1e-12, from any starting state."""
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=kernel_len, order=order, hp_order=hp_order, output_form=output_form)
    m.input_stages = _stages(delay, fade, hold)
    m.output_stages = _outputs(outputs)
    _hysteresis(m, hysteresis)
    assert m.compiled
    cmu, env = burst_input(rng, n + warm)
    assert_step_equals_reference(m, cmu, env, warm, TOL)     # from a state that is not the rest state


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cut=st.integers(0, 200), delay=st.integers(0, 3), fade=st.integers(0, 2),
       outputs=output_picks, hysteresis=hysteresis_kinds, hold=st.integers(0, 3))
def test_compiled_state_round_trips_through_get_and_set_state(seed, cut, delay, fade, outputs, hysteresis, hold):
    """Stop anywhere, checkpoint, restore into a fresh model: the rest of the record is identical."""
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=25, order=2)
    m.input_stages = _stages(delay, fade, hold)
    m.output_stages = _outputs(outputs)
    _hysteresis(m, hysteresis)
    cmu, env = burst_input(rng, 200)
    whole = step_rows(m.step, cmu, env)
    m.reset()
    step_rows(m.step, cmu[:cut], env[:cut])
    saved = m.get_state()
    m.reset()
    m.set_state(saved)
    np.testing.assert_array_equal(step_rows(m.step, cmu[cut:], env[cut:]), whole[:, cut:])


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
    yield "fade_then_delay", m.with_stages(input_stages=(ActuatorFade(0.7, 2.0, FS), Delay(1 / FS, FS)))
    yield "two_delays", m.with_stages(input_stages=(Delay(1 / FS, FS), Delay(2 / FS, FS)))


@pytest.mark.parametrize("name,model", list(_fallback_models()), ids=lambda v: v if isinstance(v, str) else "")
def test_models_with_uncompiled_effects_step_with_the_reference(name, model):
    assert not model.compiled
    cmu, env = burst_input(np.random.default_rng(5), 300)
    stepped = step_rows(model.step, cmu, env)
    model.reset()
    np.testing.assert_array_equal(stepped, step_rows(model.reference_step, cmu, env))


def test_assigning_stages_switches_between_compiled_and_reference():
    m = make_model(np.random.default_rng(6))
    assert m.compiled
    m.input_stages = (Delay(1 / FS, FS), Delay(2 / FS, FS))
    assert not m.compiled
    m.input_stages = ()
    m.output_stages = (ZeroDrift(FS, rate_per_s=0.01),)
    assert m.compiled


def test_output_stages_state_is_the_compiled_steps():
    """The stages' own get_state, set_state and Python step work on the array the compiled step
    advances: a model stepped compiled then by the reference goes on as the reference alone."""
    rng = np.random.default_rng(11)
    m = make_model(rng)
    m.output_stages = _outputs([0, 2, 3])
    cmu, env = burst_input(rng, 200)
    mixed = np.concatenate([step_rows(m.step, cmu[:100], env[:100]),
                            step_rows(m.reference_step, cmu[100:], env[100:])], axis=1)
    m.reset()
    alone = step_rows(m.reference_step, cmu, env)
    np.testing.assert_allclose(mixed, alone, atol=TOL, rtol=0)
    m.output_stages = _outputs([0])
    drift = m.output_stages[0]
    drift.set_state(np.array([0.5, 0.25]))         # in place: the compiled step sees it
    total, high, low = m.step(0.0, 0.0)
    assert m.compiled and total == high + low + 0.75
    np.testing.assert_array_equal(drift.get_state(), [0.75, 0.25])


def test_warm_up_leaves_the_state_untouched():
    rng = np.random.default_rng(7)
    m = make_model(rng)
    cmu, env = burst_input(rng, 50)
    step_rows(m.step, cmu, env)
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


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cuts=st.lists(st.integers(0, 400), min_size=2, max_size=2),
       kernel_len=st.integers(1, 60), order=st.integers(1, 3), hp_order=st.integers(1, 4),
       output_form=st.booleans(), delay=st.integers(0, 5), fade=st.integers(0, 2), outputs=output_picks,
       hysteresis=hysteresis_kinds, hold=st.integers(0, 3))
def test_compiled_batch_continues_the_steps_seamlessly(seed, cuts, kernel_len, order, hp_order, output_form, delay,
                                                       fade, outputs, hysteresis, hold):
    """Stream, batch (the fused compiled loop), stream again: (ΔCL, ΔCL_H, ΔCL_L) and the state
    after each part equal the steps alone to 1e-12, batches shorter and longer than the kernel."""
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=kernel_len, order=order, hp_order=hp_order, output_form=output_form)
    m.input_stages = _stages(delay, fade, hold)
    m.output_stages = _outputs(outputs)
    _hysteresis(m, hysteresis)
    assert m.compiled
    cmu, env = burst_input(rng, 450)
    a, b = sorted(cuts)
    expect = step_rows(m.step, cmu, env)
    after_steps = m.get_state()
    m.reset()
    first = step_rows(m.step, cmu[:a], env[:a])
    batch = np.array(m.simulate(cmu[a:b], env[a:b])).reshape(3, -1)
    last = step_rows(m.step, cmu[b:], env[b:])
    got = np.concatenate([first, batch, last], axis=1)
    scale = max(1.0, float(np.max(np.abs(expect))))
    np.testing.assert_allclose(got, expect, atol=TOL * scale, rtol=0)
    np.testing.assert_allclose(m.get_state(), after_steps, atol=TOL, rtol=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 3000), warm=st.integers(0, 400),
       output_form=st.booleans(), delay=st.integers(0, 3), fade=st.integers(0, 2), outputs=output_picks,
       hysteresis=hysteresis_kinds)
def test_compiled_batch_equals_the_numpy_batch(seed, n, warm, output_form, delay, fade, outputs, hysteresis):
    """The fused loop and the numpy/scipy chain (``reference_simulate``, scatter or FFT for long
    records) agree to 1e-12 from a mid-record state, and leave the same state."""
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=300, output_form=output_form)
    m.input_stages = _stages(delay, fade)
    m.output_stages = _outputs(outputs)
    _hysteresis(m, hysteresis)
    cmu, env = burst_input(rng, warm + n)
    assert_batch_equals_reference(m, cmu, env, warm, TOL)


@pytest.mark.parametrize("name,model", list(_fallback_models()), ids=lambda v: v if isinstance(v, str) else "")
def test_models_with_uncompiled_effects_batch_with_the_numpy_chain(name, model, monkeypatch):
    import rtlift.blocks.compiled as compiled

    def refuse(*args):
        raise AssertionError("the fused batch ran for a model it does not cover")

    monkeypatch.setattr(compiled, "hybrid_simulate", refuse)
    cmu, env = burst_input(np.random.default_rng(10), 300)
    batch = model.simulate(cmu, env)
    model.reset()
    np.testing.assert_array_equal(np.array(batch), np.array(model.reference_simulate(cmu, env)))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), size=st.sampled_from([2, 3, 8, 25, 128, 129, 300]))
def test_table_segment_is_bisect_right_for_every_value(seed, size):
    """The counting search (short grids) and the bisection (long ones) find bisect_right − 1,
    on grid points, between them, outside, and for NaN."""
    from bisect import bisect_right

    from rtlift.blocks.compiled import _segment

    rng = np.random.default_rng(seed)
    xs = np.unique(rng.normal(size=size))
    probes = np.concatenate([xs, rng.normal(size=50) * 2, [np.nan, -np.inf, np.inf, np.nextafter(xs[0], -1)]])
    for v in probes:
        expect = bisect_right(xs.tolist(), v) - 1
        assert _segment(xs, v) == expect
