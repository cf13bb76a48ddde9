"""The state vector ξ of the observer and its constant matrices (F, G, Q, P₀, the fixed part
of H), built from a model and an :class:`~rtlift.observer.config.ObserverConfig`.

    ξ = [ x (n_wiener) ; b (1) ; s (effect blocks) ; e (coloured noise, p) ; δ (1) ; r (n_ripple) ]

in this order (:class:`StateLayout` gives each block's index range); the equations are in
:mod:`rtlift.observer`. :class:`BurstPhase` reads the burst phase φ(k) and period P(k) from
the Cμ column, for the ripple states' row of H.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from rtlift.effects import EFFECTS, StateBlock
from rtlift.model.hybrid import HybridModel
from rtlift.observer.config import ObserverConfig, ObserverError

OBSERVER_FORMS: dict[str, Callable[[dict[str, float], float], StateBlock | None]] = {
    e.name: e.observer_form for e in EFFECTS if e.observed}
"""Output stages the observer represents by states, by name: each effect's own observer form
(:meth:`rtlift.effects.base.Effect.observer_form`, a :class:`StateBlock` or ``None`` when the
bias state already covers the effect). Other output stages are applied as known corrections
(module docstring)."""


class BurstPhase:
    """Burst phase and period from the ``cmu`` column, and the ripple basis at that phase.

    An onset is Cμ(k) > 0 after Cμ(k−1) ≤ 0. φ(k) = samples since the last onset (0 at the
    onset), P(k) = the interval between the last two onsets when ``2H < P ≤ max_period``
    (unknown otherwise). :meth:`step` returns the basis row
    ``[cos(2π h φ/P)]_{h=1..H} ++ [sin(2π h φ/P)]_{h=1..H}`` when P is known and φ < P, else
    ``None``. The table of the current period (P rows of 2H floats) is built when the period
    changes and kept, so a step allocates nothing while the burst period stays the same.

    The state ``[Cμ(k−1), φ(k), P(k)]`` lives in ``state``, a float array the compiled
    observer step (:mod:`rtlift.observer.compiled`) advances in place as well.
    """

    def __init__(self, harmonics: int, max_period: int, state: np.ndarray | None = None) -> None:
        self.harmonics = int(harmonics)
        self.max_period = int(max_period)
        self.state = np.zeros(3) if state is None else state
        self._period_rows: tuple[int, list[np.ndarray]] = (0, [])
        self.reset()

    def reset(self) -> None:
        """Phase unknown: no onset seen (φ = −1), period unknown (P = 0)."""
        self.state[:] = (0.0, -1.0, 0.0)

    def get_state(self) -> list[float]:
        return self.state.tolist()

    def set_state(self, state: Sequence[float]) -> None:
        self.state[:] = (float(state[0]), int(state[1]), int(state[2]))

    def table(self, period: int) -> list[np.ndarray]:
        """The basis rows of one period, φ = 0 … P − 1."""
        if self._period_rows[0] != period:
            h = np.arange(1, self.harmonics + 1, dtype=float)
            ang = 2.0 * math.pi * np.outer(np.arange(period, dtype=float), h) / period
            tab = np.ascontiguousarray(np.hstack([np.cos(ang), np.sin(ang)]))
            self._period_rows = (period, list(tab))
        return self._period_rows[1]

    def step(self, cmu: float) -> np.ndarray | None:
        """Advance by one sample of Cμ; the basis row at φ(k), or ``None`` where undefined."""
        s = self.state
        since = int(s[1])
        if cmu > 0.0 and not s[0] > 0.0:
            if since >= 0:
                interval = since + 1
                s[2] = interval if 2 * self.harmonics < interval <= self.max_period else 0
            since = 0
        elif since >= 0:
            since += 1
        s[0] = cmu
        s[1] = since
        period = int(s[2])
        if period and since < period:
            return self.table(period)[since]
        return None


def wiener_gain(nl: Any) -> Callable[[float], float]:
    """The Wiener gain N in force after the open-loop step of the sample: N(Cμ_env) for the
    paper's table, times g (1 + m h) for :class:`~rtlift.blocks.wiener.HysteresisGain` (its
    ``h`` is the one the open-loop step just updated)."""
    if hasattr(nl, "factor"):
        return lambda env: nl.gain_at(env) * nl.factor()
    return nl.gain_at


class StateLayout:
    """Where each block of ξ sits and the constant matrices of the state-space model
    (:mod:`rtlift.observer`): ``F`` (dim_x × dim_x), ``G`` (dim_x), ``h_fixed`` the constant part
    of H(k) (bias, effect blocks, coloured noise; the Wiener, δ and ripple entries are set per
    sample), ``h_lift`` what of ξ beyond x enters the estimate ΔĈL (bias and the effect blocks
    that are part of the lift), ``C`` the Wiener LTI's output row, and :meth:`Q`, :meth:`P0`
    for a configuration.

    Index ranges: ``x = ξ[:n_wiener]``, ``b = ξ[bias]``, the blocks in ``blocks`` after it,
    ``δ = ξ[gain_h]`` (−1: no such state), ``r = ξ[ripple_start:]`` (``n_ripple`` states).
    ``form`` is the Wiener form: ``input_gain`` (N(Cμ_env)·y, H linear) or ``output`` (f(y),
    H linearised at the prediction: an extended Kalman filter).
    """

    def __init__(self, model: HybridModel, harmonics: int = 0, noise_ar: Sequence[float] = (),
                 powers: int = 1, gain_h: bool = False) -> None:
        w = model.wiener
        A, B, C = w.A, w.B, w.C
        n = A.shape[0]
        nl = w.nonlinearity
        if hasattr(nl, "gain_at"):
            self.form = "input_gain"
        elif hasattr(nl, "slope_at"):
            self.form = "output"
        else:
            raise ObserverError(f"observer: unsupported Wiener nonlinearity {type(nl).__name__}")
        self.blocks: list[StateBlock] = []
        self.replaced: list[bool] = []
        """Per output stage of the model: True when states of ξ stand for it (OBSERVER_FORMS)."""
        for s in model.output_stages:
            factory = OBSERVER_FORMS.get(s.name)
            self.replaced.append(factory is not None)
            if factory is not None:
                block = factory(s.params(), model.fs_hz)
                if block is not None:
                    self.blocks.append(block)
        self.noise_ar = tuple(float(a) for a in noise_ar)
        p = len(self.noise_ar)
        if p:      # coloured noise e(k) = Σ a_i e(k−i) + w(k): companion form, unit drive
            Fn = np.zeros((p, p))
            Fn[0, :] = self.noise_ar
            Fn[1:, :-1] = np.eye(p - 1)
            Qn = np.zeros((p, p))
            Qn[0, 0] = 1.0
            hn = np.zeros(p)
            hn[0] = 1.0
            self.blocks.append(StateBlock("coloured_noise", Fn, Qn, hn,
                                          solve_discrete_lyapunov(Fn, Qn), in_estimate=False))
        if gain_h:  # δ(k) = δ(k−1) + w(k), seen as δ ΔCL_H(k) (row set per sample)
            self.blocks.append(StateBlock("gain_h", np.eye(1), np.eye(1), np.zeros(1), np.zeros((1, 1)),
                                          in_estimate=True))
        self.harmonics = int(harmonics)
        self.powers = int(powers) if self.harmonics else 0
        self.max_period = int(model.convolution.state_size)   # one burst response (kernel length)
        table = getattr(nl, "cmu", None)
        self.cmu_ref = float(table[-1]) if table is not None and table[-1] > 0 else 1.0
        n_ripple = 2 * self.harmonics * self.powers
        dim_x = n + 1 + sum(b.size for b in self.blocks) + n_ripple
        self.n_wiener, self.bias, self.dim_x, self.n_ripple = n, n, dim_x, n_ripple
        self.ripple_start = dim_x - n_ripple
        F = np.zeros((dim_x, dim_x))
        F[:n, :n] = A
        F[n, n] = 1.0
        G = np.zeros(dim_x)
        G[:n] = B
        h = np.zeros(dim_x)
        h[n] = 1.0
        h_lift = np.zeros(dim_x)
        h_lift[n] = 1.0
        Qs = np.zeros((dim_x, dim_x))
        P0s = np.zeros((dim_x, dim_x))
        Qn = np.zeros((dim_x, dim_x))      # the coloured noise's (scaled by q_noise)
        P0n = np.zeros((dim_x, dim_x))
        Qg = np.zeros((dim_x, dim_x))
        self.gain_h = -1
        i = n + 1
        for b in self.blocks:
            j = i + b.size
            F[i:j, i:j] = b.F
            if b.name == "coloured_noise":
                Qn[i:j, i:j] = b.Q
                P0n[i:j, i:j] = b.P0
            elif b.name == "gain_h":
                Qg[i:j, i:j] = b.Q
                self.gain_h = i
            else:
                Qs[i:j, i:j] = b.Q
                P0s[i:j, i:j] = b.P0
            h[i:j] = b.h
            if b.in_estimate and b.name != "gain_h":     # δ enters as δ·ΔCL_H, set per sample
                h_lift[i:j] = b.h
            i = j
        r = slice(self.ripple_start, dim_x)
        F[r, r] = np.eye(n_ripple)
        Qr = np.zeros((dim_x, dim_x))
        Qr[r, r] = np.eye(n_ripple)
        cb = float(C @ B)
        scale = abs(cb) if abs(cb) > 1e-12 * (np.linalg.norm(C) * np.linalg.norm(B) + 1e-300) \
            else float(np.linalg.norm(C) * np.linalg.norm(B)) or 1.0
        v = B / scale
        Qx = np.zeros((dim_x, dim_x))
        Qx[:n, :n] = np.outer(v, v)
        Qb = np.zeros((dim_x, dim_x))
        Qb[n, n] = 1.0
        self.F, self.G, self.h_fixed, self.h_lift, self.C = F, G, h, h_lift, C.copy()
        self._Qx, self._Qb, self._Qs, self._Qr, self._P0s = Qx, Qb, Qs, Qr, P0s
        self._Qn, self._P0n, self._Qg = Qn, P0n, Qg

    def Q(self, cfg: ObserverConfig) -> np.ndarray:  # noqa: N802 - the textbook's name
        """Process noise covariance: diag(q_x v vᵀ, q_bias, Q_s, q_noise Q_e, q_gain_h, q_ripple I)."""
        return (cfg.q_x * self._Qx + cfg.q_bias * self._Qb + self._Qs + cfg.q_noise * self._Qn
                + cfg.q_gain_h * self._Qg + cfg.q_ripple * self._Qr)

    def P0(self, cfg: ObserverConfig) -> np.ndarray:  # noqa: N802 - the textbook's name
        """Initial covariance: 0 for x (the model starts at rest), p0_bias, the effect blocks'
        own, the coloured noise's stationary covariance, 0 for δ, p0_ripple I."""
        P = self._P0s + cfg.q_noise * self._P0n
        P[self.bias, self.bias] = cfg.p0_bias
        P += cfg.p0_ripple * self._Qr
        return P

    def phase(self, state: np.ndarray | None = None) -> BurstPhase:
        return BurstPhase(self.harmonics, self.max_period, state)

    def amplitudes(self, env: float) -> list[float]:
        """The ripple's amplitude terms Cμ_env (Cμ_env/Cμ_ref)^(p−1), p = 1 … powers."""
        w, out = env, []
        for _ in range(self.powers):
            out.append(w)
            w = w * env / self.cmu_ref
        return out
