"""Burst–burst interaction: the streaming blocks of the ``interaction`` structure (issue 18).

The structure (identified by :mod:`rtlift.identify.interaction`)::

    c(k)    = φ Σ_j h(j) Cμ(k−j)                              convolution (paper eq. 1)
    m(k)    = λ m(k−1) + (1 − λ) Cμ(k) / d,   λ = exp(−1/(τ fs))  delivered momentum
    u(k)    = Cμ_env(k) · min(1, q(k)/q₀)                          delivered envelope
    ΔCL_H(k) = G_H(m(k)) HF(c)(k) + G(m(k)) (c − HF(c))(k) + S(u(k)) u(k)   burst part
    ΔCL_L(k) = N(u(k)) · C x(k),   x(k) = A x(k−1) + B u(k)       Wiener part, driven by u
    ΔCL(k)  = ΔCL_H(k) + ΔCL_L(k)

``m`` is the momentum the actuators delivered recently (a first-order memory of time constant
τ of the burst-modulated Cμ), scaled by the duty ``d`` of lift-optimal bursting (Δt_b / T_opt)
so that at 8 Hz bursting m equals the envelope: N and the static map keep their meaning, but
isolated bursts and sparse trains drive the Wiener part by what they deliver, not by the
commanded envelope. G and G_H (piecewise linear in m on the same knots, held beyond them) are
the per-burst gains of the slow and of the fast (high-passed) part of each burst's response:
those of an isolated burst at m ≈ 0, smaller when recent bursts have already moved the flow
(the interaction the convolution alone over-predicts).

The Wiener part and the static term S(u)·u (S piecewise linear on the same knots) are driven by
the delivered envelope u (:class:`~rtlift.blocks.delivered.DeliveredEnvelope`, q a memory of the
samples with a burst on, q₀ its floor at the lift-optimal rate): where bursts fire at that rate
u is the envelope itself, as in the paper's hybrid, with no lag (m lags an amplitude-modulated
envelope by about τ, issue 31); where they fire sparsely u falls with q. A model whose Wiener
input is m (the ``delivered_momentum`` stage, the structure as first merged) runs with S = 0.

Blocks, so that a :class:`~rtlift.model.hybrid.HybridModel` — and the Kalman observer, which steps
the model's blocks one by one — runs the structure unchanged:

- :class:`~rtlift.blocks.delivered.DeliveredEnvelope`, an input stage ``(Cμ, Cμ_env) → (Cμ, u)``: the Wiener
  part and its gain see u instead of the envelope;
- :class:`InteractionConvolution`, in the model's ``convolution`` slot: ΔCL_H above (its own
  HF and m inside), stepped with (Cμ′, u) — the input stages' outputs — and the model's
  ``highpass`` the identity. ΔCL_H depends on the input only, so the observer takes it as its
  known input, as it does the paper's HF(convolution).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rtlift.blocks.chain import BlockChain
from rtlift.blocks.convolution import RingConvolution
from rtlift.blocks.delivered import DeliveredMomentum
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.wiener import _check_table, _Table

IDENTITY_SOS = np.array([[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
"""The model's ``highpass`` slot for this structure: y = x (HF lives inside ΔCL_H)."""


class InteractionConvolution(BlockChain):
    """``ΔCL_H(k) = G_H(m(k)) HF(c)(k) + G(m(k)) (c − HF(c))(k) + S(u(k)) u(k)`` (module
    docstring), streaming, with a batch twin. ``kernel``/``phi`` as :class:`RingConvolution`;
    ``highpass`` the HF; ``knots`` (m and u, in Cμ), ``gains_h``, ``gains`` and ``gains_static``
    the G_H, G and S tables (held beyond the ends; S zero if not given); ``momentum`` the m
    recursion. u, the Wiener input, comes with each sample (:meth:`step`'s ``w``)."""

    def __init__(self, kernel: np.ndarray, phi: float, highpass: HighPassFilter, knots: np.ndarray,
                 gains_h: np.ndarray, gains: np.ndarray, momentum: DeliveredMomentum,
                 gains_static: np.ndarray | None = None) -> None:
        self.conv = RingConvolution(kernel, phi)
        self.highpass = highpass
        self.gain_h = _Table(*_check_table(knots, gains_h, "interaction fast gain"), extrapolate=False)
        self.gain = _Table(*_check_table(knots, gains, "interaction gain"), extrapolate=False)
        static = np.zeros(np.size(knots)) if gains_static is None else gains_static
        self.gain_static = _Table(*_check_table(knots, static, "interaction static gain"), extrapolate=False)
        self.momentum = momentum
        self.kernel, self.phi = self.conv.kernel, self.conv.phi

    state_name = "interaction"

    @property
    def blocks(self) -> tuple[Any, ...]:
        """State order: [convolution (last L inputs, newest first), HF, m]."""
        return (self.conv, self.highpass, self.momentum)

    slow = 0.0
    """The slow term G(m)(c − HF c) + S(u)u of the last :meth:`step` (part of the flow's
    quasi-steady lift, which drives a ``hysteresis`` factor on the lift: :meth:`simulate_parts`)."""

    def step(self, u: float, w: float) -> float:
        """Push Cμ(k) (``u``) and the Wiener input u(k) (``w``), return ΔCL_H(k) (its slow term
        kept in :attr:`slow`). No array allocation."""
        c = self.conv.step(u)
        hf = self.highpass.step(c)
        m = self.momentum.momentum(u)
        fast, slow_c, slow_u = self.gain_h(m) * hf, self.gain(m) * (c - hf), self.gain_static(w) * w
        self.slow = slow_c + slow_u
        return fast + slow_c + slow_u

    def reset(self) -> None:
        super().reset()
        self.slow = 0.0

    def steady_output(self, envelope: float, u: float | None = None) -> float:
        """ΔCL_H's mean under lift-optimal bursting at ``envelope`` (duty d, so m ≈ the envelope;
        u the Wiener input there, the envelope unless given, e.g. its static lift): HF removes the
        mean of c, the slow part keeps G(m) φ Σh · d · envelope, the static term S(u) u (the
        controller's static map adds them to the Wiener part's)."""
        u = envelope if u is None else u
        return (self.gain(envelope) * self.phi * float(np.sum(self.kernel)) * self.momentum.duty * envelope
                + self.gain_static(u) * u)

    def kernel_arrays(self) -> tuple[tuple[Any, ...], tuple[np.ndarray, ...]]:
        """For the compiled step (:func:`rtlift.blocks.compiled_interaction.interaction_step`):
        parameters (φh, HF sections, m's (λ, 1 − λ, 1/d), knots, G_H values and slopes, G values
        and slopes, S values and slopes) and state (convolution buffer and position, HF state, m),
        not copies."""
        (taps,), conv_state = self.conv.kernel_arrays()
        (coef,), hp_state = self.highpass.kernel_arrays()
        m_par, m_state = self.momentum.kernel_arrays()
        gh, g, gs = self.gain_h, self.gain, self.gain_static
        return ((taps, coef, m_par, g.x, gh.f, gh.slope, g.f, g.slope, gs.f, gs.slope),
                (*conv_state, *hp_state, *m_state))

    def simulate(self, u: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Batch twin of :meth:`step` (``w`` the Wiener input u); starts from and advances the
        current state."""
        return self.simulate_parts(u, w)[0]

    def simulate_parts(self, u: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`simulate` and its slow term G(m)(c − HF c) + S(u)u, per sample."""
        u = np.asarray(u, dtype=float)
        w = np.asarray(w, dtype=float)
        c = self.conv.simulate(u)
        hf = self.highpass.simulate(c)
        m = self.momentum.momentum_batch(u)
        slow_c, slow_u = self.gain.batch(m) * (c - hf), self.gain_static.batch(w) * w
        slow = slow_c + slow_u
        if slow.size:
            self.slow = float(slow[-1])
        return self.gain_h.batch(m) * hf + slow_c + slow_u, slow

    def params(self) -> dict[str, Any]:
        """The model file's ``convolution.interaction`` entry."""
        hp = self.highpass
        return {"knots": self.gain.x.tolist(), "gains_h": self.gain_h.f.tolist(), "gains": self.gain.f.tolist(),
                "gains_static": self.gain_static.f.tolist(),
                "highpass": {"order": hp.order, "cutoff_hz": hp.cutoff_hz, "sos": hp.sos.tolist()},
                "momentum": self.momentum.params()}

    @classmethod
    def from_params(cls, kernel: np.ndarray, phi: float, params: dict[str, Any],
                    fs_hz: float) -> InteractionConvolution:
        """Inverse of :meth:`params` (``KeyError``/``ValueError`` on a bad entry)."""
        hp = params["highpass"]
        return cls(kernel, phi, HighPassFilter(np.asarray(hp["sos"], dtype=float), order=hp.get("order"),
                                               cutoff_hz=hp.get("cutoff_hz")),
                   np.asarray(params["knots"], dtype=float), np.asarray(params["gains_h"], dtype=float),
                   np.asarray(params["gains"], dtype=float),
                   DeliveredMomentum.from_params(params["momentum"], fs_hz),
                   np.asarray(params["gains_static"], dtype=float) if "gains_static" in params else None)
