"""Sensor chain: aerodynamic coefficients → transducer axes → noise → resolution → counts.

Equations (SI units; α the angle of attack, q_A = ½ ρ U∞² c b of the rig,
:class:`hil_sim.physics.BenchPhysics`):

- aerodynamic coefficients: ``CL = CL₀ + ΔCL + b(t)``, ``CD = CD₀ + k_D ΔCL + ½ b(t)``, with
  ``b`` the separated-flow buffeting: white noise through a broad resonator at the
  natural shedding frequency (≈ 7 Hz here, Q ≈ 1.5), its level ``σ_b (1 − 0.7 a)`` falling as
  the flow attaches, plus broadband turbulence ``σ_t``;
- axes (PROTOCOL.md, transducer x along the chord, z normal to it; the inverse of
  ``L = s_z Fz cos α − s_x Fx sin α``): ``Fz = s_z q_A (CL cos α + CD sin α)``,
  ``Fx = s_x q_A (−CL sin α + CD cos α)``, pitching moment ``Ty = q_A c CM``;
- electrical noise ``σ_e`` on every channel, then the ADC resolution (``res_n`` N,
  ``res_nm`` N·m) and the transducer range (saturation sets status bit 1);
- counts = round(BenchPhysics.counts(ft)), the transducer's firmware scaling.

The chain of a plant of the family (:mod:`hil_sim.family`; our bench has none of these, a rigid
balance, no filter, white turbulence):

- turbulence coloured by a first-order low-pass at ``f_t`` (unit variance kept:
  ``w_k = ρ w_{k−1} + √(1 − ρ²) e_k``, ρ = exp(−2π f_t / fs));
- the balance's mode on the forces, ``ω²/(s² + 2ζωs + ω²)`` at ``f_m`` (the wing's mass on the
  transducer's stiffness; bilinear, pre-warped, unit DC gain), before the electrical noise;
- the DAQ's anti-alias filter, a 2nd-order Butterworth low-pass at ``f_aa``, after the
  electrical noise and before the ADC.

Numbers: CL₀ ≈ 0.7 and CD₀ ≈ 0.3 are the order of the normal force of a stalled thin
wing at 20° (CN ≈ 0.75, CL = CN cos α, CD = CN sin α); σ_t, σ_e and σ_b together give
σ(ΔCL) ≈ 0.004 in stalled flow (the brief's bench noise); the 7 Hz buffeting is the
natural shedding frequency of ARCHITECTURE.md (St ≈ f c sin α / U∞ ≈ 0.2); resolution and
range are those of a Nano17-class transducer (FACTS.md: ±25 N Fx/Fy, ±35 N Fz, ±0.25 N·m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from hil_sim import FS_HZ
from hil_sim.physics import BenchPhysics

STATUS_ACTUATOR_ENABLED = 0x01
STATUS_ADC_SATURATED = 0x02
STATUS_SENSOR_FAULT = 0x04
STATUS_BURST_ON = 0x08


@dataclass(frozen=True)
class SensorParams:
    """Baseline aerodynamics and transducer constants (coefficients unless stated)."""

    cl_baseline: float = 0.70
    cd_baseline: float = 0.28
    drag_per_lift: float = -0.25
    """k_D: reattachment lowers pressure drag as it raises lift."""
    cm_baseline: float = -0.05
    cm_per_lift: float = -0.1
    buffet_hz: float = 7.0
    buffet_q: float = 1.5
    buffet_sigma: float = 0.0030
    """σ_b, in stalled flow."""
    buffet_attached_reduction: float = 0.7
    turbulence_sigma: float = 0.0015
    """σ_t, broadband aerodynamic noise (seen through the balance, before any resonance)."""
    electrical_sigma: float = 0.0018
    """σ_e per force channel, expressed in coefficient units (× q_A for newtons)."""
    resolution_n: float = 1.0 / 320.0
    resolution_nm: float = 1.0 / 64000.0
    range_n: tuple[float, float, float] = (25.0, 25.0, 35.0)
    range_nm: float = 0.25
    turbulence_corner_hz: float = 0.0
    """f_t: corner of the turbulence's first-order colour (Hz); 0: white."""
    balance_hz: float = 0.0
    """f_m: the balance's mode (Hz); 0: a rigid balance."""
    balance_damping: float = 0.05
    """ζ of the balance's mode."""
    filter_hz: float = 0.0
    """f_aa: the DAQ's 2nd-order Butterworth anti-alias corner (Hz); 0: no filter."""


def buffet_filter(params: SensorParams, fs_hz: float = FS_HZ) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of the buffeting resonator, normalised to unit output variance for unit white input."""
    b, a = signal.iirpeak(params.buffet_hz, params.buffet_q, fs=fs_hz)
    _, h = signal.freqz(b, a, worN=4096)
    gain = math.sqrt(np.mean(np.abs(h) ** 2))
    return b / gain, a


class AeroNoise:
    """Streaming buffeting and turbulence (coefficient units), seeded, state carried over."""

    def __init__(self, params: SensorParams, rng: np.random.Generator, fs_hz: float = FS_HZ):
        self.params = params
        self.rng = rng
        self._b, self._a = buffet_filter(params, fs_hz)
        self._zi = np.zeros(len(self._a) - 1)
        corner = params.turbulence_corner_hz
        self._rho = math.exp(-2.0 * math.pi * corner / fs_hz) if corner else 0.0
        self._zt = np.zeros(1)

    def process(self, attached: np.ndarray) -> np.ndarray:
        p = self.params
        n = len(attached)
        w = self.rng.standard_normal((n, 2))  # sample-major: chunking does not change the draws
        buffet, self._zi = signal.lfilter(self._b, self._a, w[:, 0], zi=self._zi)
        level = p.buffet_sigma * (1.0 - p.buffet_attached_reduction * np.asarray(attached))
        turbulence = w[:, 1]
        if self._rho:
            rho = self._rho
            turbulence, self._zt = signal.lfilter([math.sqrt(1.0 - rho * rho)], [1.0, -rho], turbulence,
                                                  zi=self._zt)
        return level * buffet + p.turbulence_sigma * turbulence


def _lowpass(corner_hz: float, fs_hz: float):
    """2nd-order Butterworth low-pass on every column, streaming, started in steady state (the
    sensor_resonance effect's filter machinery with the Butterworth's coefficients)."""
    from hil_sim.effects import SensorResonance

    stage = SensorResonance.__new__(SensorResonance)
    stage.b, stage.a = signal.butter(2, corner_hz, fs=fs_hz)
    stage.zi = None
    return stage


class BalanceChain:
    """The balance's mode (on the forces) and the DAQ's anti-alias filter (after the electrical
    noise), streaming; either is absent when its frequency is 0 (module docstring)."""

    def __init__(self, params: SensorParams, fs_hz: float = FS_HZ) -> None:
        from hil_sim.effects import SensorResonance

        self.mode = (SensorResonance({"frequency_hz": params.balance_hz, "damping_ratio": params.balance_damping},
                                     fs_hz) if params.balance_hz else None)
        self.filter = _lowpass(params.filter_hz, fs_hz) if params.filter_hz else None

    def __bool__(self) -> bool:
        return self.mode is not None or self.filter is not None


def coefficients(dcl: np.ndarray, aero_noise: np.ndarray, params: SensorParams) -> np.ndarray:
    """(n, 3) CL, CD, CM of the wing."""
    cl = params.cl_baseline + dcl + aero_noise
    cd = params.cd_baseline + params.drag_per_lift * dcl + 0.5 * aero_noise
    cm = params.cm_baseline + params.cm_per_lift * dcl
    return np.column_stack([cl, cd, cm])


def transducer(coeffs: np.ndarray, physics: BenchPhysics, params: SensorParams,
               rng: np.random.Generator, chain: BalanceChain | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) CL CD CM → (counts (n, 6) int64, saturated (n,) bool): axes, [balance mode], noise,
    [anti-alias filter], ADC."""
    qa = physics.q_area
    ft = physics.forces(coeffs)
    if chain is not None and chain.mode is not None:
        ft = chain.mode.process(ft)
    n = len(ft)
    w = rng.standard_normal((n, 6))  # sample-major: chunking does not change the draws
    ft[:, :3] += params.electrical_sigma * qa * w[:, :3]
    ft[:, 3:] += params.electrical_sigma * qa * physics.chord_m * 0.1 * w[:, 3:]
    if chain is not None and chain.filter is not None:
        ft = chain.filter.process(ft)
    ft[:, :3] = np.round(ft[:, :3] / params.resolution_n) * params.resolution_n
    ft[:, 3:] = np.round(ft[:, 3:] / params.resolution_nm) * params.resolution_nm
    limits = np.array([*params.range_n, params.range_nm, params.range_nm, params.range_nm])
    saturated = np.any(np.abs(ft) > limits, axis=1)
    ft = np.clip(ft, -limits, limits)
    counts = np.round(physics.counts(ft)).astype(np.int64)
    return counts, saturated
