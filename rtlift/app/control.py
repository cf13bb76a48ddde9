"""Lift tracking around the observer: ΔCL reference in, burst envelope Cμ out (400 Hz).

The plant seen from the envelope is the hybrid model's slow part, a Wiener system
(ARCHITECTURE.md): ``x(k) = A x(k−1) + B Cμ(k)``, ``ΔCL_L = N(Cμ) · C x`` (or ``f(C x)``);
the burst ripple (the high-passed convolution) has no mean. Its static map is therefore

    S(Cμ) = nl(Cμ, G₀ Cμ),    G₀ = C (I − A)⁻¹ B   (the LTI DC gain),

concave and saturating. :class:`LiftController` implements

    v = r + K_p ē + I,        u = S⁻¹(v) clamped to [0, Cμ_max]

with ``ē`` the tracking error ``r − ΔĈL`` averaged over one burst period (the ripple's
period, so the average removes it), ``r`` the reference and ``I`` the integral of
``(T / T_i) ē``. With the feedback off, ``u = S⁻¹(r)``: pure feedforward through the
inverse of the identified static map and DC gain. Working in ΔCL units before the inverse
makes the loop gain independent of the operating point (the map's slope varies about 5× over
its range), so one pair (K_p, T_i) serves the whole range.

Why PI with conditional integration. The envelope can only change at burst onsets (8 Hz),
so a model-predictive law has one move per 125 ms and little to gain over PI on a plant whose
slow part is nearly first order; what it needs is bounded behaviour at the actuator limits
(Cμ ≥ 0, the firmware's 200 V). Conditional integration (the integrator holds while the
command is saturated and the error would push it further) needs no extra tuning constant,
unlike back-calculation's tracking time, and guarantees the integrator never grows while the
actuator is pinned, so a reference beyond reach leaves no windup to unwind. The integrator is
also clamped to the map's range.

Measured on the model as plant (tests/test_control.py; steps 0 → 0.10 → 0.16 → 0.06 with an
actuator fade to 75 %): tracking RMSE 0.0091 with feedback against 0.0191 feedforward only
(ratio 0.48), step settling ≈ 1.1 s, recovery ≈ 0.8 s after 4 s at an unreachable reference.
A two-degree-of-freedom variant (feedback on the model's expected response to the
feedforward instead of the reference) settled in 0.45 s but only reached a ratio of 0.66: the
error on the ``r`` side also buys back part of the plant's own lag, so plain PI is the default.

:meth:`LiftController.step` allocates nothing and does no I/O: call it once per sample; it
decides a new envelope every ``period`` samples (``updated`` is true then: send it).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtlift.core.errors import UserError
from rtlift.core.rate import FS_HZ

BURST_PERIOD_SAMPLES = 50
"""The lift-optimal 8 Hz burst rate at 400 Hz: the envelope changes once per period."""
DEFAULT_CMU_MAX = 0.022
"""Top of the identified static map (the bench's 200 V limit gives ≈ 0.0245)."""
MAP_POINTS = 201


@dataclass(frozen=True)
class ControlConfig:
    """Controller settings: ``kp`` (ΔCL per ΔCL), ``ti_s`` integral time (s), ``feedback``,
    ``cmu_max`` actuator limit as Cμ, ``period`` samples between envelope updates."""

    kp: float = 0.5
    ti_s: float = 0.25
    feedback: bool = True
    cmu_max: float = DEFAULT_CMU_MAX
    period: int = BURST_PERIOD_SAMPLES
    fs_hz: float = FS_HZ

    def __post_init__(self) -> None:
        for name in ("kp", "ti_s", "cmu_max", "fs_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0) and not (name == "kp" and v == 0):
                raise ValueError(f"control {name} must be a positive number, got {v!r}")
        if not isinstance(self.period, int) or self.period < 1:
            raise ValueError(f"control period must be a positive integer, got {self.period!r}")


def dc_gain(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> float:
    """G₀ = C (I − A)⁻¹ B of x(k) = A x(k−1) + B u(k), y = C x (input at time k)."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    return float(np.asarray(C, dtype=float) @ np.linalg.solve(np.eye(len(A)) - A,
                                                              np.asarray(B, dtype=float)))


def static_map(model: Any, cmu_max: float, points: int = MAP_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(Cμ grid on [0, cmu_max], S(Cμ)) of the model's Wiener part (and of the interaction
    structure's burst part, whose slow response has a mean), made non-decreasing."""
    w = model.wiener
    g0 = dc_gain(w.A, w.B, w.C)
    cmu = np.linspace(0.0, cmu_max, points)
    nl = w.nonlinearity
    if hasattr(nl, "gain_at"):
        dcl = np.array([nl.gain_at(c) * g0 * c for c in cmu])
    else:
        dcl = np.array([nl.output_at(c, g0 * c) for c in cmu])
    burst = getattr(model.convolution, "steady_output", None)     # the interaction structure's slow burst part
    if burst is not None:
        dcl = dcl + np.array([burst(c) for c in cmu])
    return cmu, np.maximum.accumulate(dcl)


class LiftController:
    """Feedforward through S⁻¹ plus PI feedback on the observer's ΔĈL (module docstring)."""

    def __init__(self, model: Any, config: ControlConfig | None = None) -> None:
        self.config = cfg = config or ControlConfig()
        cmu, dcl = static_map(model, cfg.cmu_max)
        keep = np.concatenate([[True], np.diff(dcl) > 0])  # strictly increasing for the inverse
        self._map_dcl = [float(v) for v in dcl[keep]]
        self._map_cmu = [float(v) for v in cmu[keep]]
        if len(self._map_dcl) < 2 or not all(map(math.isfinite, self._map_dcl)):
            raise UserError("model: its static map does not increase with Cμ; cannot invert it for control")
        self.dcl_min = self._map_dcl[0]
        self.dcl_max = self._map_dcl[-1]
        self._gain_i = cfg.period / (cfg.fs_hz * cfg.ti_s)
        self.reset()

    def reset(self) -> None:
        self.feedforward = 0.0
        """The last feedforward envelope S⁻¹(r) (Cμ)."""
        self.integral = 0.0
        self.envelope = 0.0
        """The last decided envelope (Cμ)."""
        self.saturated = False
        """Whether the last decision sat at an actuator limit."""
        self.updated = False
        self._count = 0
        self._err_sum = 0.0
        self._ref_sum = 0.0
        self._ref_n = 0
        self._n = 0

    def sync(self, samples_to_decision: int) -> None:
        """Make the next decision fall ``samples_to_decision`` samples from now (align the
        updates ahead of the device's burst onsets)."""
        self._count = self.config.period - max(1, int(samples_to_decision))

    def inverse(self, dcl: float) -> float:
        """S⁻¹(ΔCL) as Cμ, clamped to the map's range [0, cmu_max]."""
        xs = self._map_dcl
        if dcl <= xs[0]:
            return self._map_cmu[0]
        if dcl >= xs[-1]:
            return self._map_cmu[-1]
        j = bisect_right(xs, dcl) - 1
        c0, c1 = self._map_cmu[j], self._map_cmu[j + 1]
        return c0 + (c1 - c0) * (dcl - xs[j]) / (xs[j + 1] - xs[j])

    def step(self, estimate: Any, reference: float) -> float:
        """One sample: the observer's estimate (an :class:`~rtlift.observer.Estimate` or ΔĈL
        as a float) and the ΔCL reference; returns the envelope Cμ to command. A new one is
        decided every ``period`` samples (``updated``); in between the last is returned."""
        dcl = estimate if isinstance(estimate, float) else estimate.dcl
        if dcl == dcl:  # a NaN estimate (no measurement yet) does not feed the average
            self._err_sum += reference - dcl
            self._n += 1
        self._ref_sum += reference
        self._ref_n += 1
        self._count += 1
        if self._count < self.config.period:
            self.updated = False
            return self.envelope
        cfg = self.config
        ref = self._ref_sum / self._ref_n
        self.feedforward = self.inverse(ref)
        v = ref
        if cfg.feedback and self._n:
            err = self._err_sum / self._n
            v = ref + cfg.kp * err + self.integral
            lo, hi = self.dcl_min, self.dcl_max
            pushing_high = v >= hi and err > 0.0
            pushing_low = v <= lo and err < 0.0
            if not (pushing_high or pushing_low):  # conditional integration
                self.integral += self._gain_i * err
                span = hi - lo
                self.integral = min(max(self.integral, -span), span)
                v = ref + cfg.kp * err + self.integral
        self.saturated = v >= self.dcl_max or v <= self.dcl_min
        self.envelope = self.inverse(v)
        self._count = 0
        self._err_sum = 0.0
        self._ref_sum = 0.0
        self._ref_n = 0
        self._n = 0
        self.updated = True
        return self.envelope
