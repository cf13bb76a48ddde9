"""Actuation signals: the slow control signal (envelope), burst gating, drive voltage.

The paper's actuation signal nests three signals: a 400 Hz pulse carrier (the actuator
resonance; not modelled — one DAQ sample *is* one carrier period), bursts of
Δt_b = 0.01 s = 0.125 t⁺ = 4 samples repeated every T, and the control signal that sets the
burst amplitude. The bench drives the actuators with a voltage amplitude; the actuators deliver
Cμ = κ V² (:class:`hil_sim.physics.BenchPhysics`, 60 V ↔ Cμ 0.0022: the rig's own law, not the
host's calibration). Voltages are quantised to PROTOCOL.md's 0.01 V, and the Cμ columns are the
quantised voltages' Cμ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hil_sim import FS_HZ, T_CONV_S
from hil_sim.physics import BenchPhysics
from rtlift.core.programs import CMU_AT_60V, OPTIMAL_PERIOD_MS, samples_of_ms
from rtlift.core.programs import CMU_MAX as CMU_MAX

BURST_SAMPLES = 4
"""Δt_b = 0.01 s at 400 Hz (paper: Δt_b = 0.125 t⁺)."""
OPTIMAL_PERIOD_SAMPLES = samples_of_ms(OPTIMAL_PERIOD_MS)
"""The lift-optimal 8 Hz burst rate (paper: T = 1.56 t⁺) at 400 Hz: 50 samples."""
SINGLE_BURST_CMU = CMU_AT_60V
"""The paper's single-burst and burst-train amplitude: 60 V ↔ Cμ 0.0022."""
VOLT_STEP = 0.01
"""PROTOCOL.md: volt_cv and envelope_cv in 0.01 V."""


def period_samples(t_plus: float, fs_hz: float = FS_HZ) -> int:
    """A burst period of ``t_plus`` convective times, in whole samples."""
    return int(round(t_plus * T_CONV_S * fs_hz))


def burst_gate(n: int, period: int, start: int = 0, count: int | None = None,
               width: int = BURST_SAMPLES) -> np.ndarray:
    """Boolean gate: bursts of ``width`` samples every ``period`` from ``start`` (``count`` of them)."""
    k = np.arange(n) - start
    gate = (k >= 0) & (k % period < width)
    if count is not None:
        gate &= k < count * period
    return gate


@dataclass(frozen=True)
class Actuation:
    """One program of the actuator chain, all arrays of one length at 400 Hz."""

    volts: np.ndarray
    """Drive amplitude (V), 0 when the burst is off (PROTOCOL.md volt_cv)."""
    envelope_volts: np.ndarray
    """The control signal as a drive amplitude (V) (PROTOCOL.md envelope_cv)."""
    cmu: np.ndarray
    """Cμ of the drive: the envelope's Cμ while a burst is on, 0 otherwise."""
    cmu_envelope: np.ndarray
    """Cμ of the control signal."""
    burst: np.ndarray
    """True while the burst gate is open and the envelope is non-zero."""


def quantise_volts(volts: np.ndarray) -> np.ndarray:
    """Round to the protocol's 0.01 V."""
    return np.round(np.asarray(volts, dtype=float) / VOLT_STEP) * VOLT_STEP


def actuate_volts(envelope_volts: np.ndarray, gate: np.ndarray, physics: BenchPhysics) -> Actuation:
    """Envelope (as a drive amplitude, V) and burst gate → quantised voltages and the Cμ the
    actuators deliver at them."""
    env_v = quantise_volts(envelope_volts)
    volts = np.where(gate, env_v, 0.0)
    cmu_env = physics.cmu_from_volts(env_v)
    cmu = np.where(volts != 0.0, cmu_env, 0.0)
    return Actuation(volts, env_v, cmu, cmu_env, volts != 0.0)
