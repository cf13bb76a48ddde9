"""The truth plant: burst-actuated reattachment on the stalled NACA0009 (docs/BENCH.md).

Its structure is deliberately *not* the hybrid Wiener–convolution model. Three physical
mechanisms (SI units; ``c`` the Cμ delivered by the actuators, burst-modulated):

0. Burst–burst interaction. A burst fired while the previous burst's vortex is still over
   the chord finds a rolled-up shear layer and is less receptive. A memory ``q`` is 1
   during a burst and decays as ``exp(−t/τ_q)`` after it, ``τ_q`` ≈ 1.5 t⁺ (a vortex
   convecting at ≈ 0.5–0.7 U∞ leaves the chord in 1.5–2 t⁺). A burst starting with memory
   ``q`` delivers the effective momentum ``c_e = (1 − κ q) c``. Bursts 7 t⁺ apart do not
   interact (q ≈ 0.01); at the 8 Hz burst rate ``ε = 1 − κ q`` ≈ 0.7 for every burst, a
   constant factor, so the ripple stays linear in Cμ.

1. Reattachment. ``a ∈ [0, 1]`` is the attached fraction of the suction side. The
   effectiveness of a burst's momentum saturates, ``g(c_e) = c_e / (1 + c_e / c_sat)``, only
   the still-separated part ``(1 − a)`` can reattach, and without forcing the flow relaxes
   back to stall in ``τ_s`` = 3 t⁺::

       da/dt = β g(c_e) (1 − a) − a / τ_s                                  (P1)

   With bursts every T the mean drive is ``r̄ = β g Δt_b / T``; the equilibrium
   ``a* = r̄ τ_s / (1 + r̄ τ_s)`` is concave and saturating (the static map) and the time
   constant ``τ_s / (1 + r̄ τ_s)`` is one to three convective times — the multi-t⁺
   reattachment transients of Amitay & Glezer (2002) and Darabi & Wygnanski (2004). The
   circulation follows ``a`` with a lag ``τ_L`` ≈ 1 t⁺ (starting-vortex / Wagner-like
   build-up)::

       τ_L dℓ/dt = a − ℓ,        ΔCL_a = L_a ℓ                              (P1')

2. Burst vortex. Each burst rolls the separated shear layer into a vortex that convects
   over the chord: a short lift dip, then a lift bump lasting a few t⁺ (single-burst
   responses of Amitay & Glezer 2002 and Williams et al. 2010). It needs separated
   vorticity, so it is weaker when the flow is already attached::

       ΔCL_v = V · [H_v * (c_e (1 − a)^p)],   H_v(s) = (1 − s τ_n) / (1 + s τ_v)²   (P2)

   (``H_v`` has unit DC gain; its right-half-plane zero gives the initial dip.)

``ΔCL = (ΔCL_a + ΔCL_v)(1 + m_h h)`` (``m_h`` = 0 unless the hysteresis effect is on).

Convective delay: the flow answers the actuators ``τ_d`` later (the burst's vortex convects
from the slot to where it acts on the separated shear layer): all of the above is driven by
``c(t − τ_d)`` (and the envelope by ``c_env(t − τ_d)``), delayed in whole samples. Our bench has
``τ_d`` = 0; the plant family (:mod:`hil_sim.family`) draws it.
The linear convolution of the isolated-burst response therefore over-predicts close
burst trains and is nearly exact for bursts 7 t⁺ apart (the paper's observation), and the
slow lift is close to (not exactly) a Wiener response of the envelope.

Hysteresis (an effect the model is not told about; off by default): ``h`` relaxes in
``τ_s`` towards 1 while the envelope falls and towards 0 while it rises (held while it is
constant), so the static gain on falling Cμ is ``(1 + m_h)`` times that on rising Cμ.

The defaults of :class:`PlantParams` were tuned on this plant so that the static map goes
ΔCL 0 → 0.22 for Cμ 0 → 0.022 at the 8 Hz burst rate (the paper's static map) and the
convolution over-predicts 10 bursts at T = 1.75 t⁺ by > 25 % and at T = 7 t⁺ by < 5 %
(the paper's Fig. of burst trains); measured numbers are in docs/BENCH.md and
tests/test_bench_plant.py.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
from scipy import signal

from hil_sim import FS_HZ, T_CONV_S
from hil_sim.effects import Delay


@dataclass(frozen=True)
class PlantParams:
    """Truth-plant constants; times in seconds unless the name says t⁺."""

    tau_s_tplus: float = 3.0
    """Relaxation (re-separation) time τ_s in t⁺: a few convective times."""
    beta_per_s: float = 3.0e3
    """Attachment rate per unit effective Cμ while a burst is on (1/s)."""
    c_sat: float = 0.02
    """Cμ at which a burst's momentum has half its small-Cμ effectiveness."""
    lift_attached: float = 0.265
    """ΔCL of the fully attached flow, L_a."""
    vortex_gain: float = 120.0
    """V: ΔCL per unit Cμ of the burst vortex (integral of ΔCL_v = V c Δt_b)."""
    vortex_tau_tplus: float = 0.8
    """τ_v in t⁺: the vortex convects over the chord in about one to two t⁺."""
    vortex_dip_tplus: float = 0.25
    """τ_n in t⁺: right-half-plane zero giving the initial lift dip."""
    vortex_power: float = 0.25
    """p: the vortex needs separated vorticity, strength ∝ (1 − a)^p."""
    interaction: float = 0.8
    """κ: a burst fired while the previous burst's vortex is still over the chord is
    less effective, ε = 1 − κ q (burst–burst interaction)."""
    memory_tplus: float = 1.5
    """τ_q in t⁺: the burst memory q decays as the vortex convects off the chord."""
    circulation_tplus: float = 1.0
    """τ_L in t⁺: lag of the attached-flow circulation behind the attached fraction."""
    hysteresis: float = 0.0
    """m_h: relative static-gain difference falling vs rising Cμ (effect ``hysteresis``)."""
    delay_tplus: float = 0.0
    """τ_d in t⁺: convective delay from the actuators to the flow's answer (whole samples)."""

    @property
    def tau_s(self) -> float:
        return self.tau_s_tplus * T_CONV_S

    def plus(self, amounts: Mapping[str, float]) -> PlantParams:
        """These parameters with ``amounts[name]`` added to each one named (a ``plant`` effect's,
        as its registry record maps them: :attr:`rtlift.core.registry.Bench.plant`)."""
        return replace(self, **{k: float(getattr(self, k) + v) for k, v in amounts.items()})


def vortex_filter(params: PlantParams, fs_hz: float = FS_HZ) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of H_v(s) = (1 − s τ_n)/(1 + s τ_v)² discretised with a zero-order hold."""
    tv = params.vortex_tau_tplus * T_CONV_S
    tn = params.vortex_dip_tplus * T_CONV_S
    b, a, _ = signal.cont2discrete(([-tn, 1.0], [tv * tv, 2.0 * tv, 1.0]), 1.0 / fs_hz, "zoh")
    b = np.trim_zeros(np.ravel(b), "f")
    return np.concatenate([np.zeros(len(a) - len(b)), b]), np.asarray(a, dtype=float)


class TruthPlant:
    """Streaming truth plant: ``process(cmu, cmu_envelope)`` on chunks, state carried over.

    ``cmu`` is the Cμ the actuators deliver (burst-modulated), ``cmu_envelope`` the commanded
    envelope (only its direction of change matters, for the hysteresis effect).
    """

    def __init__(self, params: PlantParams | None = None, fs_hz: float = FS_HZ) -> None:
        self.params = params or PlantParams()
        self.fs_hz = float(fs_hz)
        self._b, self._a = vortex_filter(self.params, self.fs_hz)
        pole = math.exp(-1.0 / (self.fs_hz * self.params.circulation_tplus * T_CONV_S))
        self._bl, self._al = np.array([0.0, 1.0 - pole]), np.array([1.0, -pole])
        self.reset()

    def reset(self) -> None:
        self.attached = 0.0
        self.falling = 0.0
        self.h = 0.0
        self.last_env = 0.0
        self.memory = 0.0
        self.efficiency = 1.0
        self.on = False
        self._zi = np.zeros(len(self._a) - 1)
        self._zl = np.zeros(1)
        seconds = self.params.delay_tplus * T_CONV_S
        self._delay = Delay({"seconds": seconds}, self.fs_hz) if round(seconds * self.fs_hz) else None
        if self._delay is not None:    # at rest before the first sample: no actuation in the pipe
            self._delay.buffer = np.zeros((self._delay.n, 2))

    def process(self, cmu: np.ndarray, cmu_envelope: np.ndarray) -> dict[str, np.ndarray]:
        """ΔCL of the chunk and its parts: keys ``dcl``, ``attached``, ``vortex``."""
        p = self.params
        c = np.asarray(cmu, dtype=float)
        env = np.asarray(cmu_envelope, dtype=float)
        if self._delay is not None:    # c(t − τ_d), c_env(t − τ_d): delayed together, one buffer
            delayed = self._delay.process(np.column_stack([c, env]))
            c, env = delayed[:, 0], delayed[:, 1]
        n = len(c)
        dt = 1.0 / self.fs_hz
        inv_tau = 1.0 / p.tau_s
        decay_off = math.exp(-dt * inv_tau)
        decay_q = math.exp(-dt / (p.memory_tplus * T_CONV_S))
        ce = np.empty(n)
        att = np.empty(n)
        hh = np.empty(n)
        a = self.attached
        h = self.h
        falling = self.falling
        last = self.last_env
        q, eps, on = self.memory, self.efficiency, self.on
        kappa = p.interaction
        beta, c_sat = p.beta_per_s, p.c_sat
        hyst = p.hysteresis != 0.0
        for k in range(n):
            ck = c[k]
            if ck > 0.0:
                if not on:
                    eps = 1.0 - kappa * q
                    on = True
                q = 1.0
                ck *= eps
            else:
                on = False
                q *= decay_q
            ce[k] = ck
            r = beta * ck / (1.0 + ck / c_sat)
            # exact step of (P1) with the drive held over the sample
            if r > 0.0:
                lam = r + inv_tau
                a_inf = r / lam
                a = a_inf + (a - a_inf) * math.exp(-lam * dt)
            else:
                a *= decay_off
            att[k] = a
            if hyst:
                e = env[k]
                if e < last:
                    falling = 1.0
                elif e > last:
                    falling = 0.0
                last = e
                h = falling + (h - falling) * decay_off
                hh[k] = h
        self.attached, self.h, self.falling, self.last_env = a, h, falling, last
        self.memory, self.efficiency, self.on = q, eps, on
        u = ce * (1.0 - att) ** p.vortex_power
        vortex, self._zi = signal.lfilter(self._b, self._a, u, zi=self._zi)
        vortex = p.vortex_gain * vortex
        circ, self._zl = signal.lfilter(self._bl, self._al, att, zi=self._zl)
        dcl = p.lift_attached * circ + vortex
        if hyst:
            dcl = dcl * (1.0 + p.hysteresis * hh)
        return {"dcl": dcl, "attached": att, "vortex": vortex, "cmu_effective": ce}
