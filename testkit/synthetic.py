"""Small random hybrid models and amplitude-modulated burst inputs, for tests and benchmarks."""

from __future__ import annotations

import numpy as np

from rtlift.blocks import HighPassFilter, InputGain, OutputNonlinearity, RingConvolution, WienerBlock
from rtlift.blocks.actuator_fade import ActuatorFade
from rtlift.blocks.delay import Delay
from rtlift.blocks.delivered import STRUCTURE_STAGES, DeliveredEnvelope, DeliveredMomentum
from rtlift.blocks.interaction import IDENTITY_SOS, InteractionConvolution
from rtlift.blocks.periodic_disturbance import PeriodicDisturbance
from rtlift.blocks.sensor_resonance import SensorResonance
from rtlift.blocks.wiener import HysteresisGain, OutputHysteresis
from rtlift.blocks.zero_drift import ZeroDrift
from rtlift.core.rate import FS_HZ
from rtlift.model.hybrid import HybridModel


def random_stable_A(rng: np.random.Generator, n: int, radius: float = 0.995) -> np.ndarray:
    """Controllable-canonical A with physical low-frequency poles: time constants from a few
    samples to ~200 samples (0.5 s at 400 Hz), real or lightly damped conjugate pairs."""
    poles: list[complex] = []
    while len(poles) < n:
        r = rng.uniform(0.3, radius)
        if n - len(poles) >= 2 and rng.random() < 0.5:
            th = rng.uniform(0.01, 0.3)
            poles += [r * np.exp(1j * th), r * np.exp(-1j * th)]
        else:
            poles.append(r)
    coeffs = np.real(np.poly(poles))
    A = np.zeros((n, n))
    A[0, :] = -coeffs[1:]
    A[1:, :-1] += np.eye(n - 1)
    return A


def make_model(rng: np.random.Generator, *, kernel_len: int = 30, order: int = 2, hp_order: int = 2,
               output_form: bool = False, fs_hz: float = FS_HZ) -> HybridModel:
    kernel = rng.normal(size=kernel_len) * np.exp(-np.arange(kernel_len) / 10.0)
    A = random_stable_A(rng, order)
    B = np.zeros(order)
    B[0] = 1.0
    C = rng.normal(size=order)
    C /= C @ np.linalg.solve(np.eye(order) - A, B)            # unit DC gain: y ≈ Cμ in steady state, as identified
    if output_form:
        y = np.sort(rng.normal(size=6)) * 0.01
        nl = OutputNonlinearity(np.unique(y), np.cumsum(rng.uniform(0.1, 1, size=np.unique(y).size)))
    else:
        nl = InputGain(np.linspace(0, 0.022, 8), 10 + rng.uniform(0, 5, size=8))
    return HybridModel(RingConvolution(kernel, phi=rng.uniform(0.5, 2.0)),
                       HighPassFilter.design(hp_order, rng.uniform(0.3, 20.0), fs_hz),
                       WienerBlock(A, B, C, nl), fs_hz)


def burst_input(rng: np.random.Generator, n: int, period: int = 50, width: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude-modulated bursts: (cmu, cmu_envelope) as on the bench."""
    env = np.clip(0.011 + 0.011 * np.sin(np.arange(n) * 2 * np.pi / rng.uniform(80, 400))
                  + rng.normal(0, 0.002, n), 0, 0.025)
    gate = (np.arange(n) % period) < width
    return np.where(gate, env, 0.0), env


def step_rows(step, cmu: np.ndarray, env: np.ndarray) -> np.ndarray:
    """``step(cmu[k], env[k])`` sample by sample (a model's ``step`` or ``reference_step``):
    rows (total, high, low), shape (3, N) (ΔCL units; N = 0 gives (3, 0))."""
    return np.array([step(c, e) for c, e in zip(cmu, env, strict=True)]).reshape(-1, 3).T


def model_steps(model, cmu: np.ndarray, env: np.ndarray) -> np.ndarray:
    """``model.step`` sample by sample: rows (total, high, low)."""
    return step_rows(model.step, cmu, env)


def assert_step_equals_reference(model: HybridModel, cmu: np.ndarray, env: np.ndarray, warm: int,
                                 tol: float) -> None:
    """The compiled ``model.step`` against its judge ``model.reference_step`` from a state that is
    not the rest state (``warm`` reference steps first): outputs (total, high, low) within
    ``tol`` × max(1, max |reference|) (ΔCL units) and the state after the steps within ``tol``
    absolute or 1e-12 relative."""
    step_rows(model.reference_step, cmu[:warm], env[:warm])
    start = model.get_state()
    compiled = step_rows(model.step, cmu[warm:], env[warm:])
    after_compiled = model.get_state()
    model.set_state(start)
    reference = step_rows(model.reference_step, cmu[warm:], env[warm:])
    scale = max(1.0, float(np.max(np.abs(reference))))
    np.testing.assert_allclose(compiled, reference, atol=tol * scale, rtol=0)
    np.testing.assert_allclose(after_compiled, model.get_state(), atol=tol, rtol=1e-12)


def assert_batch_equals_reference(model: HybridModel, cmu: np.ndarray, env: np.ndarray, warm: int,
                                  tol: float) -> None:
    """The fused ``model.simulate`` against the numpy/scipy chain ``model.reference_simulate``
    from a mid-record state (``warm`` steps first): (total, high, low) within ``tol`` ×
    max(1, max |reference|) (ΔCL units; an empty record passes) and the state left within
    ``tol`` absolute or 1e-12 relative."""
    step_rows(model.step, cmu[:warm], env[:warm])
    start = model.get_state()
    fused = np.array(model.simulate(cmu[warm:], env[warm:]))
    after = model.get_state()
    model.set_state(start)
    reference = np.array(model.reference_simulate(cmu[warm:], env[warm:]))
    scale = max(1.0, float(np.max(np.abs(reference), initial=0.0)))
    np.testing.assert_allclose(fused, reference, atol=tol * scale, rtol=0)
    np.testing.assert_allclose(after, model.get_state(), atol=tol, rtol=1e-12)


def interaction_model(rng: np.random.Generator, kernel_len: int = 40, order: int = 2, delay: int = 0,
                      output_form: bool = False, fs_hz: float = FS_HZ, hp_order: int | None = None) -> HybridModel:
    """A random model of the ``interaction`` structure (:mod:`rtlift.blocks.interaction`):
    ΔCL = G_H(m) HF(c) + G(m) (c − HF(c)) + S(u) u + N(u) C x (or f(C x), ``output_form``), u
    the delivered envelope (in half the models through a static map, ``lift``), its input
    ``delay`` samples late; the burst part's high-pass filter of order ``hp_order`` (1–4; drawn
    when None, as before it was a parameter)."""
    tau = float(rng.uniform(0.02, 1.0))
    duty = float(rng.uniform(0.05, 0.5))
    knots = np.array([0.0, 0.002, 0.006, 0.012, 0.022])
    burst = InteractionConvolution(rng.normal(size=kernel_len) * np.exp(-np.arange(kernel_len) / 12.0),
                                   float(rng.uniform(20, 120)),
                                   HighPassFilter.design(hp_order or int(rng.integers(1, 5)),
                                                         float(rng.uniform(0.5, 8)), fs_hz),
                                   knots, rng.uniform(0.2, 1.2, knots.size), rng.uniform(-0.2, 1.0, knots.size),
                                   DeliveredMomentum(tau, duty, fs_hz), rng.uniform(-5.0, 5.0, knots.size))
    A = random_stable_A(rng, order)
    B = np.zeros(order)
    B[0] = 1.0
    C = rng.normal(size=order)
    C /= C @ np.linalg.solve(np.eye(order) - A, B)
    grid = np.linspace(0, 0.022, 8)
    nonlinearity = (OutputNonlinearity(grid, 10 * grid + rng.uniform(0, 0.01, size=8).cumsum()) if output_form
                    else InputGain(grid, 10 + rng.uniform(0, 5, size=8)))
    on = int(rng.integers(1, 9))
    tau_q, period = float(rng.uniform(0.02, 1.0)), on + int(rng.integers(0, 80))
    lift = None                       # half the models put the static map before the LTI (``lift``)
    if rng.random() < 0.5:
        lift = (grid, 5 + rng.uniform(0, 10, size=8)[::-1].cumsum()[::-1] / 8)
    stages = (*((Delay(delay / fs_hz, fs_hz),) if delay else ()),
              DeliveredEnvelope(tau_q, on, period, fs_hz, lift, float(rng.uniform(1.0, 4.0))))
    return HybridModel(burst, HighPassFilter(IDENTITY_SOS, order=0), WienerBlock(A, B, C, nonlinearity), fs_hz,
                       input_stages=stages)


def run_in_chunks(model, cmu: np.ndarray, env: np.ndarray, cuts: list[int]) -> np.ndarray:
    """ΔCL of ``model`` over (cmu, env) cut at ``cuts``: batch and step-by-step chunks in turn,
    the state checkpointed (get_state), reset and restored (set_state) between chunks."""
    bounds = [0, *sorted(cuts), cmu.size]
    pieces = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        saved = model.get_state()
        model.reset()
        model.set_state(saved)
        if i % 2:
            pieces.append(model_steps(model, cmu[a:b], env[a:b])[0] if b > a else np.empty(0))
        else:
            pieces.append(model.simulate(cmu[a:b], env[a:b]).total)
    return np.concatenate(pieces)


OUTPUT_STAGES = (
    lambda: ZeroDrift(FS_HZ, rate_per_s=0.01, offset=0.001),       # an observer's bias state stands for it
    lambda: ZeroDrift(FS_HZ, amplitude=-0.02, time_constant_s=0.3),
    lambda: SensorResonance(30.0, 0.1, FS_HZ),                      # a known correction
    lambda: PeriodicDisturbance(20.0, 0.003, 0.3, FS_HZ, [{"n": 3, "amplitude": 0.001}]),   # oscillator states
)
"""The output stages the diagnosis (and ``--adapt``) adds, fresh on each call."""


def with_effects(model: HybridModel, fade: bool = False, outputs: tuple[int, ...] = (),
                 hysteresis: int = 0) -> HybridModel:
    """``model`` (changed in place, and returned) with what the diagnosis adds: an
    ``actuator_fade`` (its clock at 0.02 s at rest) after any ``delay`` and before the interaction
    structure's own stage, output stages (indices into :data:`OUTPUT_STAGES`), a hysteresis factor on the Wiener
    nonlinearity (1: driven by Cμ_env, a switch; 2: by the lift, a play operator)."""
    if fade:
        stages = list(model.input_stages)
        at = next((i for i, st in enumerate(stages) if st.name in STRUCTURE_STAGES), len(stages))
        model.input_stages = (*stages[:at], ActuatorFade(0.6, 0.05, FS_HZ, on_time0_s=0.02), *stages[at:])
    model.output_stages = tuple(OUTPUT_STAGES[i]() for i in outputs)
    if hysteresis:
        nl = model.wiener.nonlinearity
        width, driver = (0.0, "cmu") if hysteresis == 1 else (0.004, "lift")
        table = (nl.cmu, nl.gain) if hasattr(nl, "gain_at") else (nl.y, nl.f)
        cls = HysteresisGain if hasattr(nl, "gain_at") else OutputHysteresis
        model.wiener.nonlinearity = cls(*table, 0.3, 0.02, FS_HZ, width, 0.9, driver)
        model.wiener = model.wiener                  # the compiled step bound again
    return model
