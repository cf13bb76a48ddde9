"""The compiled Observer.step: the numpy/BLAS reference_step is its judge (1e-12), both advance
the same state, and observers of models whose step is not compiled fall back to the reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtlift.blocks.delay import Delay
from rtlift.blocks.onset_hold import OnsetHold
from rtlift.core.rate import FS_HZ as FS
from rtlift.observer import FLAG_BAD_INPUT, FLAG_MISSING, Observer, ObserverConfig
from testkit.synthetic import OUTPUT_STAGES, burst_input, interaction_model, make_model, with_effects

TOL = 1e-12
CONFIGS = {
    "plain": ObserverConfig(R=1.6e-5, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4, max_rejections=5),
    "all_states": ObserverConfig(R=8e-6, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4, noise_ar=(1.82, -0.85),
                                 q_noise=7e-8, q_gain_h=1e-5, ripple_harmonics=4, ripple_powers=2,
                                 q_ripple=1e-8, p0_ripple=0.1, max_rejections=5),
}


def _inputs(rng, n):
    """Bursts with every kind of sample: missing and non-finite measurements, outliers, a NaN Cμ."""
    cmu, env = burst_input(rng, n, period=int(rng.integers(20, 60)))
    z = 0.02 * env / 0.011 + rng.normal(0, 0.004, n)
    z[rng.random(n) < 0.05] = np.nan
    z[rng.random(n) < 0.03] += 0.5
    z[rng.random(n) < 0.01] = np.inf
    bad = rng.random(n) < 0.01
    cmu[bad] = np.nan
    return cmu.tolist(), env.tolist(), [None if (v != v and i % 2) else v for i, v in enumerate(z.tolist())]


def _run(step, cmu, env, z):
    return np.array([step(c, e, m).as_tuple() for c, e, m in zip(cmu, env, z, strict=True)])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 500), order=st.integers(1, 3),
       output_form=st.booleans(), delay=st.integers(0, 4), fade=st.booleans(),
       config=st.sampled_from(sorted(CONFIGS)), warm=st.integers(0, 100),
       outputs=st.lists(st.integers(0, len(OUTPUT_STAGES) - 1), max_size=3), hysteresis=st.integers(0, 2),
       hold=st.booleans())
def test_compiled_step_equals_reference_step(seed, n, order, output_form, delay, fade, config, warm, outputs,
                                             hysteresis, hold):
    """Estimates (ΔĈL, open loop, ν, NIS, flags), counters and the whole state agree to 1e-12,
    from a state that is not the rest state; with or without the ``onset_hold`` input stage
    (``identify --envelope delivered``: after the delay, its own compiled slot)."""
    rng = np.random.default_rng(seed)
    model = make_model(rng, kernel_len=40, order=order, output_form=output_form)
    model.input_stages = ((Delay(delay / FS, FS),) if delay else ()) + ((OnsetHold(FS),) if hold else ())
    # what diagnose and --adapt add: a fade after the delay, output stages, a hysteresis factor
    _agree(Observer(with_effects(model, fade, tuple(outputs), hysteresis), CONFIGS[config]), rng, n, warm)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 500), order=st.integers(1, 3), output_form=st.booleans(),
       delay=st.integers(0, 4), config=st.sampled_from(sorted(CONFIGS)), warm=st.integers(0, 100),
       fade=st.booleans(), outputs=st.lists(st.integers(0, len(OUTPUT_STAGES) - 1), max_size=3),
       hysteresis=st.integers(0, 2))
def test_compiled_step_equals_reference_step_on_the_interaction_structure(seed, n, order, output_form, delay, config,
                                                                         warm, fade, outputs, hysteresis):
    """The same for a model of the ``interaction`` structure (what ``rtlift identify`` chooses
    when the campaign has burst trains) with what the diagnosis adds to it: its own compiled
    sample, the same filter."""
    rng = np.random.default_rng(seed)
    model = with_effects(interaction_model(rng, 40, order, delay, output_form), fade, tuple(outputs), hysteresis)
    _agree(Observer(model, CONFIGS[config]), rng, n, warm)


def _agree(obs, rng, n, warm):
    """Compiled and reference steps of ``obs`` from one mid-record state agree to 1e-12."""
    assert obs.compiled
    cmu, env, z = _inputs(rng, n + warm)
    _run(obs.reference_step, cmu[:warm], env[:warm], z[:warm])
    start = obs.get_state()
    obs.clear_monitors()
    compiled = _run(obs.step, cmu[warm:], env[warm:], z[warm:])
    after, counters = obs.get_state(), obs.monitors()
    obs.set_state(start)
    obs.clear_monitors()
    reference = _run(obs.reference_step, cmu[warm:], env[warm:], z[warm:])
    scale = max(1.0, float(np.nanmax(np.abs(reference[:, :2]))))
    np.testing.assert_array_equal(compiled[:, 4], reference[:, 4])                 # flags
    np.testing.assert_array_equal(np.isnan(compiled), np.isnan(reference))
    c, r = np.nan_to_num(compiled), np.nan_to_num(reference)
    np.testing.assert_allclose(c[:, :3], r[:, :3], atol=TOL * scale, rtol=0)      # ΔĈL, open loop, ν
    # NIS = ν²/S inherits ν's relative error twice: ν agrees to 1e-12 · scale absolutely
    nu = np.maximum(np.abs(r[:, 2]), 1e-300)
    assert np.all(np.abs(c[:, 3] - r[:, 3]) <= TOL * r[:, 3] * (1.0 + 2.0 * scale / nu) + TOL)
    np.testing.assert_allclose(after, obs.get_state(), rtol=1e-12, atol=TOL * float(np.max(np.abs(after))))
    ref_counters = obs.monitors()
    for key in ("updates", "rejected", "missing", "bad_inputs"):
        assert counters[key] == ref_counters[key]


def test_bad_inputs_and_missing_samples_are_counted_the_same_way(rng):
    obs = Observer(make_model(rng), CONFIGS["plain"])
    est = obs.step(math.nan, 0.01, 0.02)
    assert est.flags == FLAG_BAD_INPUT | FLAG_MISSING and obs.bad_inputs == 1 and obs.missing == 1
    est = obs.step(0.0, 0.0, None)
    assert est.flags == FLAG_MISSING and obs.missing == 2 and est.sample == 2


def test_an_observer_of_a_model_with_an_uncompiled_block_takes_the_reference_step(rng):
    """Two delays are not in the compiled model step: the observer says so and its step is the
    reference step, sample for sample."""
    model = make_model(rng).with_stages(input_stages=(Delay(1 / FS, FS), Delay(2 / FS, FS)))
    obs, ref = Observer(model, CONFIGS["plain"]), Observer(model.copy(), CONFIGS["plain"])
    assert not model.compiled and not obs.compiled and obs.warm_up() < 0.01
    cmu, env, z = _inputs(rng, 300)
    np.testing.assert_array_equal(_run(obs.step, cmu, env, z), _run(ref.reference_step, cmu, env, z))


def test_warm_up_compiles_without_touching_the_state(rng):
    obs = Observer(make_model(rng), CONFIGS["all_states"])
    cmu, env, z = _inputs(rng, 200)
    _run(obs.step, cmu, env, z)
    before = obs.get_state()
    assert obs.warm_up() >= 0.0
    np.testing.assert_array_equal(obs.get_state(), before)


@pytest.mark.parametrize("structure", ["paper", "interaction"])
def test_touching_the_working_set_between_steps_changes_nothing(rng, structure):
    """``Observer.touch`` (called while a spinning loop waits) only reads: the same estimates,
    bit for bit, and the same state as a run without it; the interaction structure's step has
    its own touch (its arguments are not the paper's)."""
    model = make_model(rng) if structure == "paper" else with_effects(interaction_model(rng), True, (2,), 2)
    cmu, env, z = _inputs(rng, 300)
    plain, touched = Observer(model, CONFIGS["all_states"]), Observer(model.copy(), CONFIGS["all_states"])
    assert touched.compiled
    expected = _run(plain.step, cmu, env, z)

    def step(c, e, m):
        touched.touch()
        out = touched.step(c, e, m)
        touched.touch()
        return out

    np.testing.assert_array_equal(_run(step, cmu, env, z), expected)
    np.testing.assert_array_equal(touched.get_state(), plain.get_state())


@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_the_compiled_step_reuses_one_estimate_and_the_state_arrays(rng, config):
    obs = Observer(make_model(rng), CONFIGS[config])
    x, P = obs.kf.x, obs.kf.P
    first = obs.step(0.01, 0.01, 0.02)
    assert obs.step(0.0, 0.01, 0.02) is first
    assert obs.kf.x is x and obs.kf.P is P and np.any(x != 0)
