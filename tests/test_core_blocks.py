"""Streaming blocks: step() and their batch twins agree to 1e-12; reference implementations agree too."""

from __future__ import annotations

import control
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy import signal

from rtlift.blocks import HighPassFilter, LTIBlock, RingConvolution, to_statespace
from rtlift.blocks.delay import Delay
from testkit.synthetic import burst_input, make_model, model_steps, random_stable_A, run_in_chunks

TOL = 1e-12


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), kernel_len=st.integers(1, 60),
       order=st.integers(1, 3), hp_order=st.integers(1, 4), output_form=st.booleans())
def test_hybrid_step_equals_simulate(seed, n, kernel_len, order, hp_order, output_form):
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=kernel_len, order=order, hp_order=hp_order, output_form=output_form)
    cmu, env = burst_input(rng, n)
    streamed = model_steps(m, cmu, env)
    state_after_steps = m.get_state()
    m.reset()
    out = m.simulate(cmu, env)
    scale = max(1.0, float(np.max(np.abs(streamed))))      # 1e-12 of the signal's size (a draw may reach 1e2)
    np.testing.assert_allclose(np.vstack([out.total, out.high, out.low]), streamed, atol=TOL * scale, rtol=0)
    # Internal states (canonical-form x, TDF-II z) are larger and more ill-conditioned than ΔCL and
    # compiled lfilter may fuse multiply-adds: compare them relatively; the outputs above are the contract.
    np.testing.assert_allclose(m.get_state(), state_after_steps, atol=TOL, rtol=1e-9)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cuts=st.lists(st.integers(0, 300), min_size=1, max_size=6),
       kernel_len=st.integers(1, 40))
def test_chunked_batch_and_steps_carry_state(seed, cuts, kernel_len):
    """Any mix of chunks (batch) and single steps, carried through get_state/set_state, equals one pass."""
    rng = np.random.default_rng(seed)
    m = make_model(rng, kernel_len=kernel_len)
    cmu, env = burst_input(rng, 300)
    whole = m.simulate(cmu, env).total
    m.reset()
    np.testing.assert_allclose(run_in_chunks(m, cmu, env, cuts), whole, atol=TOL, rtol=0)


def test_ring_buffer_wraps_many_times_without_drift():
    rng = np.random.default_rng(1)
    h = rng.normal(size=7)
    conv = RingConvolution(h, phi=0.7)
    u = rng.normal(size=1000)                                # 140+ wraps of a 7-tap ring
    streamed = np.array([conv.step(v) for v in u])
    np.testing.assert_allclose(streamed, 0.7 * np.convolve(u, h)[:1000], atol=TOL, rtol=0)


def test_convolution_is_the_papers_eq1_for_a_single_burst():
    """A 4-sample burst of Cμ = 0.0022 convolved with h gives φ·0.0022·(h(k)+h(k−1)+h(k−2)+h(k−3))."""
    h = np.exp(-np.arange(50) / 8.0)
    conv = RingConvolution(h, phi=2.0)
    u = np.zeros(60)
    u[:4] = 0.0022
    y = conv.simulate(u)
    expect = 2.0 * 0.0022 * np.array([h[max(0, k - 3):k + 1].sum() for k in range(50)])
    np.testing.assert_allclose(y[:50], expect, atol=TOL)


@pytest.mark.parametrize("duty", [0.08, 1.0], ids=["bursts_scattered", "dense_fft"])
def test_long_batch_convolution_equals_the_ring_buffer_from_a_mid_record_state(duty):
    """20 000 samples × 300 taps (past the direct-sum size): bursts (8 % of samples non-zero)
    take the scatter path, a dense input the FFT; both equal the streamed ring buffer to 1e-12
    and hand on the same state."""
    rng = np.random.default_rng(7)
    h = rng.normal(size=300) * np.exp(-np.arange(300) / 60.0)
    u = np.where(rng.random(20_500) < duty, rng.uniform(0.0, 0.02, 20_500), 0.0)
    streamed, batch = RingConvolution(h, phi=1.3), RingConvolution(h, phi=1.3)
    for v in u[:500]:
        streamed.step(v)
    batch.set_state(streamed.get_state())
    expect = np.array([streamed.step(v) for v in u[500:]])
    np.testing.assert_allclose(batch.simulate(u[500:]), expect, atol=TOL, rtol=0)
    np.testing.assert_array_equal(batch.get_state(), streamed.get_state())


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), order=st.integers(1, 8), cutoff=st.floats(0.05, 150.0))
def test_highpass_step_equals_scipy_sosfilt(seed, order, cutoff):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=500) * 0.02
    hp = HighPassFilter.design(order, cutoff, 400.0)
    ref = signal.sosfilt(signal.butter(order, cutoff, btype="highpass", fs=400.0, output="sos"), x)
    np.testing.assert_allclose([hp.step(v) for v in x], ref, atol=TOL, rtol=0)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), order=st.integers(1, 2), cutoff=st.floats(0.3, 50.0))
def test_highpass_step_equals_scipy_lfilter(seed, order, cutoff):
    """Against the transfer-function form too, where that form is itself accurate (order ≤ 2; above,
    lfilter's single polynomial loses digits near z = 1)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=2000) * 0.02
    hp = HighPassFilter.design(order, cutoff, 400.0)
    b, a = signal.butter(order, cutoff, btype="highpass", fs=400.0)
    np.testing.assert_allclose([hp.step(v) for v in x], signal.lfilter(b, a, x), atol=TOL, rtol=0)


def test_highpass_removes_dc_and_passes_the_burst_rate():
    hp = HighPassFilter.design(2, 2.0, 400.0)
    g = np.abs(hp.frequency_response(np.array([0.0, 8.0]), 400.0))
    assert g[0] < 1e-12
    assert abs(g[1] - 1.0) < 0.01


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 3))
@example(seed=199255, n=3)      # a pole at 0.991: the old block-Toeplitz batch drifted 8e-12 (CI, 2026-11-26)
def test_lti_matches_python_control_forced_response(seed, n):
    """x(k) = A x(k−1) + B u(k), y = C x(k) equals python-control's (A, B, CA, CB) realisation."""
    rng = np.random.default_rng(seed)
    A = random_stable_A(rng, n)
    B = rng.normal(size=n)
    C = rng.normal(size=n)
    C /= C @ np.linalg.solve(np.eye(n) - A, B)            # unit DC gain, as an identified model
    u = rng.uniform(0, 0.022, size=400)                    # Cμ-sized input
    lti = LTIBlock(A, B, C)
    ref = control.forced_response(to_statespace(A, B, C, 1.0 / 400), U=u).outputs
    np.testing.assert_allclose([lti.step(v) for v in u], ref, atol=TOL, rtol=0)
    lti.reset()
    np.testing.assert_allclose(lti.simulate(u), ref, atol=TOL, rtol=0)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(4, 5))
def test_high_order_canonical_form_agrees_to_rounding_it_amplifies(seed, n):
    """The companion (canonical) form with 4–5 poles near z = 1 amplifies rounding like a
    high-order polynomial does: step, batch and python-control still agree to 1e-9 relative."""
    rng = np.random.default_rng(seed)
    A = random_stable_A(rng, n)
    B = np.eye(n)[0]
    C = rng.normal(size=n)
    C /= C @ np.linalg.solve(np.eye(n) - A, B)
    u = rng.uniform(0, 0.022, size=400)
    lti = LTIBlock(A, B, C)
    ref = control.forced_response(to_statespace(A, B, C, 1.0 / 400), U=u).outputs
    scale = np.max(np.abs(ref))
    np.testing.assert_allclose([lti.step(v) for v in u], ref, atol=1e-9 * scale, rtol=0)
    lti.reset()
    np.testing.assert_allclose(lti.simulate(u), ref, atol=1e-9 * scale, rtol=0)


def test_input_enters_at_time_k_direct_path():
    """y(0) = C B u(0): the paper's timing has no one-sample delay."""
    lti = LTIBlock([[0.5, 0.1], [1.0, 0.0]], [1.0, 0.0], [2.0, 3.0])
    assert lti.step(1.0) == 2.0


def test_delay_stage_shifts_by_whole_samples_in_both_paths():
    d = Delay(0.0125, 400.0)                                # 5 samples
    cmu = np.arange(1.0, 21.0)
    env = -cmu
    streamed = np.array([d.step(c, e) for c, e in zip(cmu, env, strict=True)])
    assert d.samples == 5
    np.testing.assert_array_equal(streamed[:5], 0.0)
    np.testing.assert_array_equal(streamed[5:, 0], cmu[:15])
    d.reset()
    c2, e2 = d.simulate(cmu, env)
    np.testing.assert_array_equal(c2, streamed[:, 0])
    np.testing.assert_array_equal(e2, streamed[:, 1])


def test_long_records_take_the_fft_path_and_still_equal_the_steps():
    """A 300-tap kernel over 20 000 samples (6e6 multiply-adds) is convolved by overlap-add FFT."""
    rng = np.random.default_rng(7)
    m = make_model(rng, kernel_len=300)
    cmu, env = burst_input(rng, 20_000)
    streamed = model_steps(m, cmu, env)[0]
    m.reset()
    np.testing.assert_allclose(m.simulate(cmu, env).total, streamed, atol=TOL, rtol=0)
