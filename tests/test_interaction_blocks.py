"""The interaction structure's blocks (issue 18): streaming equals batch, state carries, the
model file and the observer take it as they take the paper's model."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtlift.blocks import HighPassFilter, InputGain, WienerBlock
from rtlift.blocks.interaction import IDENTITY_SOS, InteractionConvolution
from rtlift.blocks.stages import DeliveredMomentum
from rtlift.core.rate import FS_HZ as FS
from rtlift.model.hybrid import HybridModel
from rtlift.model.modelfile import model_from_dict, model_to_dict
from rtlift.observer import Observer, ObserverConfig
from testkit.synthetic import burst_input, model_steps, random_stable_A, run_in_chunks

TOL = 1e-12


def interaction_model(rng: np.random.Generator, kernel_len: int = 40, order: int = 2) -> HybridModel:
    """A random model of the structure: ΔCL = G_H(m) HF(c) + G(m) (c − HF(c)) + N(m) C x."""
    tau = float(rng.uniform(0.02, 1.0))
    duty = float(rng.uniform(0.05, 0.5))
    knots = np.array([0.0, 0.002, 0.006, 0.012, 0.022])
    burst = InteractionConvolution(rng.normal(size=kernel_len) * np.exp(-np.arange(kernel_len) / 12.0),
                                   float(rng.uniform(20, 120)),
                                   HighPassFilter.design(int(rng.integers(1, 5)), float(rng.uniform(0.5, 8)), FS),
                                   knots, rng.uniform(0.2, 1.2, knots.size), rng.uniform(-0.2, 1.0, knots.size),
                                   DeliveredMomentum(tau, duty, FS))
    A = random_stable_A(rng, order)
    B = np.zeros(order)
    B[0] = 1.0
    C = rng.normal(size=order)
    C /= C @ np.linalg.solve(np.eye(order) - A, B)
    wiener = WienerBlock(A, B, C, InputGain(np.linspace(0, 0.022, 8), 10 + rng.uniform(0, 5, size=8)))
    return HybridModel(burst, HighPassFilter(IDENTITY_SOS, order=0), wiener, FS,
                       input_stages=(DeliveredMomentum(tau, duty, FS),))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), kernel_len=st.integers(1, 60),
       order=st.integers(1, 3), period=st.integers(5, 300))
def test_interaction_model_step_equals_simulate(seed, n, kernel_len, order, period):
    rng = np.random.default_rng(seed)
    m = interaction_model(rng, kernel_len, order)
    cmu, env = burst_input(rng, n, period=period)
    streamed = model_steps(m, cmu, env)
    after_steps = m.get_state()
    m.reset()
    out = m.simulate(cmu, env)
    scale = max(1.0, float(np.max(np.abs(streamed))))
    np.testing.assert_allclose(np.vstack([out.total, out.high, out.low]), streamed, atol=TOL * scale, rtol=0)
    np.testing.assert_allclose(m.get_state(), after_steps, atol=TOL, rtol=1e-9)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cuts=st.lists(st.integers(0, 300), min_size=1, max_size=6))
def test_interaction_chunks_and_steps_carry_state_through_get_set(seed, cuts):
    rng = np.random.default_rng(seed)
    m = interaction_model(rng)
    cmu, env = burst_input(rng, 300, period=int(rng.integers(20, 200)))
    whole = m.simulate(cmu, env).total
    m.reset()
    np.testing.assert_allclose(run_in_chunks(m, cmu, env, cuts), whole, atol=TOL, rtol=0)


def test_delivered_momentum_settles_at_the_envelope_for_bursts_at_the_duty():
    """Bursts of 4 samples every 40 (duty 0.1) at Cμ 0.01: m settles around 0.01 (envelope units)."""
    stage = DeliveredMomentum(0.2, 0.1, FS)
    cmu = np.where(np.arange(4000) % 40 < 4, 0.01, 0.0)
    _, m = stage.simulate(cmu, cmu)
    assert np.mean(m[-400:]) == pytest.approx(0.01, rel=0.01)


def test_an_isolated_burst_with_unit_gains_and_no_wiener_part_is_the_papers_convolution():
    """G_H = G = 1 and C = 0: ΔCL_H is φ h ∗ Cμ exactly (eq. 1), whatever the HF."""
    h = np.exp(-np.arange(80) / 15.0)
    knots = np.array([0.0, 0.022])
    burst = InteractionConvolution(h, 2.0, HighPassFilter.design(2, 2.0, FS), knots, np.ones(2), np.ones(2),
                                   DeliveredMomentum(0.3, 0.08, FS))
    cmu = np.zeros(400)
    cmu[50:54] = 0.0022
    np.testing.assert_allclose(burst.simulate(cmu), 2.0 * np.convolve(cmu, h)[:400], atol=1e-15, rtol=1e-9)


def test_interaction_model_survives_its_model_file():
    rng = np.random.default_rng(7)
    m = interaction_model(rng)
    cmu, env = burst_input(rng, 2000, period=90)
    before = m.simulate(cmu, env).total
    again = model_from_dict(model_to_dict(m))
    assert isinstance(again.convolution, InteractionConvolution)
    assert [s.name for s in again.input_stages] == ["delivered_momentum"]
    np.testing.assert_array_equal(again.simulate(cmu, env).total, before)


def test_the_unchanged_observer_runs_on_the_interaction_model():
    """The observer steps the model's blocks itself: its open-loop model is the model's ΔCL."""
    rng = np.random.default_rng(11)
    m = interaction_model(rng)
    cmu, env = burst_input(rng, 1500, period=120)
    truth = m.simulate(cmu, env).total
    m.reset()
    obs = Observer(m, ObserverConfig(R=1e-6, q_x=1e-8, q_bias=1e-10, p0_bias=1e-6, q_gain_h=1e-8))
    est = np.array([[(e := obs.step(c, v, z)).model_dcl, e.dcl] for c, v, z in zip(cmu, env, truth, strict=True)])
    np.testing.assert_allclose(est[:, 0], truth, atol=1e-12, rtol=0)
    assert np.sqrt(np.mean((est[:, 1] - truth) ** 2)) < 0.01 * np.std(truth)
