"""The ``onset_hold`` input stage (issue 47): the envelope each burst delivered, held until the
next onset — its equation, its streaming/batch twins, and the compiled model step that runs it."""

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
from rtlift.core.rate import FS_HZ as FS
from rtlift.model.modelfile import model_from_dict, model_to_dict
from testkit.synthetic import (
    assert_batch_equals_reference,
    assert_step_equals_reference,
    interaction_model,
    make_model,
    step_rows,
)

TOL = 1e-12
PERIOD, WIDTH = 50, 4


def _bursts(rng: np.random.Generator, n: int, period: int = PERIOD, offset: int = 0,
            off_runs: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A smooth envelope (Cμ) with runs at 0 (actuators off), bursts of WIDTH samples every
    ``period`` from ``offset``: (Cμ, Cμ_env) as the bench records them."""
    k = np.arange(n)
    env = np.clip(0.011 + 0.009 * np.sin(2 * np.pi * k / rng.uniform(60, 500)) + rng.normal(0, 0.001, n), 0, 0.025)
    if off_runs and n > 10:
        a = int(rng.integers(0, n))
        env[a:a + int(rng.integers(1, 3 * period))] = 0.0
    gate = ((k - offset) % period) < WIDTH
    return np.where(gate, env, 0.0), env


def test_smooth_and_held_envelopes_delivering_the_same_bursts_give_the_same_input():
    """The equation: u is the envelope at each onset, held; so the smooth envelope and the one
    latched at each onset (the loop's), with the same bursts, map to the same u, exactly; u = 0
    where the envelope is 0; the Cμ column passes unchanged."""
    rng = np.random.default_rng(3)
    cmu, env = _bursts(rng, 2000, offset=7)
    onsets = np.flatnonzero((cmu > 0) & (np.concatenate(([0.0], cmu[:-1])) <= 0))
    held = np.zeros_like(env)                                  # the equation, sample by sample
    for k in range(1, env.size):
        held[k] = 0.0 if env[k] <= 0 else env[k] if k in onsets else held[k - 1]
    c_out, u = OnsetHold(FS).simulate(cmu, env)
    np.testing.assert_array_equal(c_out, cmu)
    np.testing.assert_array_equal(u, held)
    assert np.all(u[:7] == 0.0)                               # before the first onset: nothing delivered
    latched = np.where(env > 0, held, 0.0)                     # the envelope as the loop holds it
    np.testing.assert_array_equal(OnsetHold(FS).simulate(cmu, latched)[1], u)
    assert np.max(np.abs(u - env)) > 1e-3                      # the stage does change a smooth envelope


def test_constant_envelope_with_sparse_bursts_is_unchanged():
    """Single bursts and trains at a held amplitude: u = Cμ_env from the first onset on (the
    stage does not touch those records), and 0 where the envelope is."""
    env = np.full(3000, 0.0022)
    env[:800] = 0.0
    env[2500:] = 0.0
    cmu = np.where((np.arange(3000) % 377) < WIDTH, env, 0.0)
    first = int(np.flatnonzero(cmu > 0)[0])
    _, u = OnsetHold(FS).simulate(cmu, env)
    np.testing.assert_array_equal(u[first:], env[first:])
    assert np.all(u[:first] == 0.0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 600), cut=st.integers(0, 600),
       period=st.integers(5, 120))
def test_streaming_equals_batch_from_any_state(seed, n, cut, period):
    """step and simulate agree exactly (≤ 1e-12) and leave the same state, from a mid-record state."""
    rng = np.random.default_rng(seed)
    cmu, env = _bursts(rng, n + cut, period, int(rng.integers(0, period)))
    a, b = OnsetHold(FS), OnsetHold(FS)
    a.simulate(cmu[:cut], env[:cut])
    b.set_state(a.get_state())
    streamed = np.array([a.step(c, e) for c, e in zip(cmu[cut:], env[cut:], strict=True)]).reshape(-1, 2).T
    batch = np.array(b.simulate(cmu[cut:], env[cut:]))
    np.testing.assert_allclose(batch, streamed, atol=TOL, rtol=0)
    np.testing.assert_array_equal(a.get_state(), b.get_state())


ORDERS = ("H", "DH", "HD", "HF", "FH", "DHF", "HDF", "DFH")
"""The input-stage orders the compiled step runs with the hold (D delay, F fade, H hold): what
``rtlift identify --envelope delivered`` writes ([delay,] hold) and what the diagnosis appends
to it (a delay, a fade), and the hold after a fade or between the two."""


def _stages(delay: int, order: str = "DH", clock: str = "on_time") -> tuple:
    """The input stages in ``order`` (:data:`ORDERS`): a delay of ``delay`` samples (none for 0),
    a fade on ``clock``, the hold."""
    made = {"D": (Delay(delay / FS, FS),) if delay else (), "F": (ActuatorFade(0.6, 0.05, FS, clock),),
            "H": (OnsetHold(FS),)}
    return tuple(st for c in order for st in made[c])


def _model(seed: int, delay: int, output_form: bool, order: str = "DH", clock: str = "on_time"):
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=40, output_form=output_form)
    m.input_stages = _stages(delay, order, clock)
    return m, rng


def _compiled_and_right(m, rng: np.random.Generator, n: int, warm: int) -> None:
    """``m`` takes the compiled step, and its step and fused batch equal the reference step and
    the numpy chain to 1e-12 (and leave the same states) from ``warm`` samples into bursts."""
    assert m.compiled
    cmu, env = _bursts(rng, n + warm, offset=int(rng.integers(0, PERIOD)))
    assert_step_equals_reference(m, cmu, env, warm, TOL)
    m.reset()
    assert_batch_equals_reference(m, cmu, env, warm, TOL)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), warm=st.integers(0, 120), delay=st.integers(0, 4),
       output_form=st.booleans(), order=st.sampled_from(ORDERS), clock=st.sampled_from(("on_time", "time")))
def test_compiled_step_and_batch_with_the_hold_equal_the_reference(seed, n, warm, delay, output_form, order, clock):
    """A model with the hold among a delay and a fade (:data:`ORDERS`) takes the compiled step;
    step and fused batch equal the reference step and the numpy chain to 1e-12 from a
    mid-record state (the states too: the fade's clock, the rings, the hold's [u, Cμ(k−1)])."""
    m, rng = _model(seed, delay, output_form, order, clock)
    _compiled_and_right(m, rng, n, warm)


def test_the_hold_changes_the_model_and_copies_keep_their_own_state():
    """The hold moves the model's output (against the same model without it), and a copy, a
    pickle and a model-file round trip step exactly as the original (the stage's state a view
    into the compiled slot, made again in each)."""
    m, rng = _model(5, 2, False)
    cmu, env = _bursts(rng, 1500, offset=11, off_runs=False)
    plain = m.copy()
    plain.input_stages = (Delay(2 / FS, FS),)
    with_hold = step_rows(m.step, cmu[:700], env[:700])
    without = step_rows(plain.step, cmu[:700], env[:700])
    assert np.max(np.abs(with_hold[2] - without[2])) > 1e-4 * np.max(np.abs(without[2]))
    twins = [copy.deepcopy(m), pickle.loads(pickle.dumps(m)), model_from_dict(model_to_dict(m))]
    for t in twins[2:]:
        t.set_state(m.get_state())
    rest = step_rows(m.step, cmu[700:], env[700:])
    for t in twins:
        assert t.compiled
        np.testing.assert_allclose(step_rows(t.step, cmu[700:], env[700:]), rest, atol=TOL, rtol=0)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 300), warm=st.integers(0, 100), delay=st.integers(0, 3),
       order=st.sampled_from(ORDERS))
def test_the_interaction_structure_with_the_hold_equals_its_reference(seed, n, warm, delay, order):
    """The ``interaction`` structure with the hold among a delay and a fade before its own
    ``delivered_envelope``: compiled; step and batch equal the reference to 1e-12."""
    rng = np.random.default_rng(seed)
    m = interaction_model(rng, kernel_len=30, order=2)
    m.input_stages = (*_stages(delay, order), m.input_stages[-1])      # before its delivered_envelope
    _compiled_and_right(m, rng, n, warm)


def test_the_hold_runs_in_its_own_place_and_other_orders_take_the_reference_step():
    """The hold's slot follows the model's order: with a fade that does not reach 1 in the record,
    fade then hold (the envelope faded at the onset, held) and hold then fade (the held envelope
    faded at each sample) give different Wiener inputs, each compiled and each its own
    reference's; two holds, or a fade before the delay, take the reference step."""
    outs = {}
    for order in ("FH", "HF"):
        m, rng = _model(7, 0, False, order)
        assert m.compiled
        cmu, env = _bursts(rng, 600, offset=3, off_runs=False)
        outs[order] = step_rows(m.step, cmu, env)
        m.reset()
        np.testing.assert_allclose(outs[order], step_rows(m.reference_step, cmu, env), atol=TOL, rtol=0)
    assert np.max(np.abs(outs["FH"][2] - outs["HF"][2])) > 1e-3 * np.max(np.abs(outs["HF"][2]))
    m, _ = _model(7, 2, False, "FDH")
    assert not m.compiled
    m.input_stages = (OnsetHold(FS), OnsetHold(FS))
    assert not m.compiled


def test_bad_state_is_refused():
    with pytest.raises(ValueError, match="shape"):
        OnsetHold(FS).set_state(np.zeros(3))


def test_identification_applies_the_stage_to_its_records_and_refuses_an_unknown_convention():
    """``delivered`` is the stage from rest on a record's envelope (Cμ and ΔCL untouched);
    ``IdentifyOptions.envelope`` other than recorded/delivered/auto is one ValueError."""
    from rtlift.core.records import Record
    from rtlift.identify.campaign import IdentifyOptions, delivered, identify_hybrid

    rng = np.random.default_rng(9)
    cmu, env = _bursts(rng, 900, offset=4)
    rec = Record(np.arange(900) / FS, cmu, env, rng.normal(0, 0.01, 900))
    got = delivered(rec, FS)
    np.testing.assert_array_equal(got.cmu_envelope, OnsetHold(FS).simulate(cmu, env)[1])
    np.testing.assert_array_equal(got.cmu, rec.cmu)
    np.testing.assert_array_equal(got.dcl, rec.dcl)
    np.testing.assert_array_equal(rec.cmu_envelope, env)          # the record itself unchanged
    with pytest.raises(ValueError, match="envelope convention 'held'"):
        identify_hybrid(rec, rec, rec, IdentifyOptions(envelope="held"))


def test_the_bench_model_with_the_hold_is_compiled_and_refused_by_the_c_export():
    """The bench model (an old file: no stage, its outputs unchanged by this stage's existence)
    with the hold appended: compiled, its observer compiled, and `rtlift export c` refuses it in
    one line (the C module has no translation of the hold)."""
    from importlib.resources import files

    from rtlift.export.filter_spec import ExportError, bound_observer
    from rtlift.model.modelfile import load_model
    from rtlift.observer import Observer

    base = load_model(str(files("tests") / "data" / "bench_model.json"))
    assert "onset_hold" not in [s.name for s in base.input_stages]
    m = base.with_stages(input_stages=(OnsetHold(base.fs_hz),))
    m.observer_config = base.observer_config
    assert m.compiled and Observer.from_model(m).compiled
    with pytest.raises(ExportError, match="onset_hold"):
        bound_observer(m)


@pytest.mark.parametrize("path", [*sorted(str(p) for p in (files("tests") / "data").iterdir()
                                          if p.name.endswith(".json") and ".design-" not in p.name),
                                  str(files("rtlift") / "data" / "paper_model.json")])
def test_model_files_load_and_their_compiled_step_and_batch_equal_the_reference(path):
    """The model files (tests/data and the package's paper model, written before the hold had a
    slot of its own) load as they were: compiled, no hold in their packed parameters (place 0, no
    hold state), and step and batch equal to the reference step (which no packing touches) to
    1e-12; with the hold after their stages the same holds, and the hold's state is the model's."""
    from rtlift.blocks.compiled_stages import HOLD
    from rtlift.model.modelfile import load_model

    base = load_model(path, allow_unstable=True)
    cmu, env = _bursts(np.random.default_rng(2), 1170, offset=5, off_runs=False)     # its envelope > 0 after 1000
    for m in (base, base.with_stages(input_stages=(OnsetHold(base.fs_hz),))):
        assert m.compiled
        par, sstate = m._kernel[1][0], m._kernel[1][5]        # (par, d_cmu, d_env, d_pos, fpar, sstate, ...)
        hold = any(type(st) is OnsetHold for st in m.input_stages)
        assert par[par.size - HOLD] == (0.0 if m is base else 2.0 if base.input_stages else 1.0)
        assert sstate.size == 4 + sum(st.state_size for st in m.output_stages) + 2 * hold
        assert_step_equals_reference(m, cmu, env, 200, TOL)
        if hold:
            np.testing.assert_array_equal(m.input_stages[-1].get_state(), sstate[-2:])
            assert m.input_stages[-1].get_state()[0] > 0.0        # an envelope held since the last onset
        m.reset()                       # the batch against the reference step (the paper model integrates
        step_rows(m.reference_step, cmu[:200], env[:200])   # without bound: its numpy chain's rounding grows)
        start = m.get_state()
        fused = np.array(m.simulate(cmu[200:], env[200:]))
        after = m.get_state()
        m.set_state(start)
        np.testing.assert_allclose(fused, step_rows(m.reference_step, cmu[200:], env[200:]), atol=TOL, rtol=0)
        np.testing.assert_allclose(after, m.get_state(), atol=TOL, rtol=1e-12)
