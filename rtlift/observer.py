"""Kalman observer around the hybrid model (filterpy's ``KalmanFilter``; textbook names).

State (dimension d = n + 1 + Σ n_blocks + 2H)::

    ξ(k) = [ x(k) ; b(k) ; s(k) ; r(k) ]

- ``x`` the n states of the Wiener LTI, in the paper's timing (eqs. 4–5):
  ``x(k) = A x(k−1) + B Cμ_env(k) + w_x(k)``;
- ``b`` a random-walk bias (sensor zero drift and slow model error): ``b(k) = b(k−1) + w_b(k)``;
- ``s`` states that accepted effects bring (:data:`OBSERVER_FORMS`, e.g. the oscillator of a
  periodic disturbance), each a :class:`StateBlock` with its own F, Q and measurement row;
- ``r = [a_1 … a_H ; b_1 … b_H]`` burst-synchronous ripple coefficients (``ripple_harmonics``
  H ≥ 1 in the settings, none for H = 0), random walks ``r(k) = r(k−1) + w_r(k)``. They carry
  the part of the model error that is locked to the burst phase (the shape and size of the
  per-burst ripple the convolution gets wrong), seen in the measurement through

      r-row(k) = Cμ_env(k) · [cos(2π h φ(k)/P(k)) , sin(2π h φ(k)/P(k))]_{h = 1 … H}

  with φ(k) the samples since the last burst onset (Cμ(k) > 0 after Cμ(k−1) ≤ 0, from the
  ``cmu`` column) and P(k) the interval between the last two onsets (:class:`BurstPhase`).
  The row is zero while the phase is undefined: before two onsets, when the last interval
  exceeds one burst response (the model's kernel length) or is too short for H harmonics
  (P ≤ 2H), and once φ ≥ P (the bursts stopped or slowed).

Prediction, with the input at time k (so *predict with u = Cμ_env(k), then update with the
measurement at k*)::

    ξ⁻(k) = F ξ(k−1) + G u(k),   F = diag(A, 1, F_s, I_2H),   G = [B; 0; 0; 0],   u(k) = Cμ_env(k)
    P⁻(k) = F P(k−1) Fᵀ + Q,      Q = diag(q_x v vᵀ, q_b, Q_s, q_r I_2H),   v = B / (C B)

(``q_x`` is the variance per sample of a disturbance on y = C x, ``q_b`` that of the bias step,
``q_r`` that of a ripple coefficient's step, in ΔCL²/Cμ².)

Measurement (ΔCL from the balance) with a time-varying row::

    z(k) = ΔCL_H(k) + N(Cμ_env(k)) C x(k) + b(k) + h_s s(k) + r-row(k) r(k) + v(k),   v ~ N(0, R)
    H(k) = [ N(Cμ_env(k)) C , 1 , h_s , r-row(k) ]

``ΔCL_H(k) = HF(φ Σ h(j) Cμ(k−j))`` is computed by the model's own blocks and enters as a
known input. For the textbook Wiener form ``f(y)`` the row is linearised at the predicted
``ŷ⁻ = C x⁻`` (extended Kalman filter): ``H(k) = [f′(ŷ⁻) C, 1, h_s, r-row]`` and the prediction
uses ``f(ŷ⁻)``. Update (scalar innovation ν, Joseph form)::

    ν = z − ẑ⁻,   S = H P⁻ Hᵀ + R,   K = P⁻ Hᵀ / S,   NIS = ν² / S
    ξ = ξ⁻ + K ν,   P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ

χ² gating: a sample with NIS above the ``gate_probability`` quantile of χ²₁ is rejected
(predict only, counted). Each such outlier adds 1 to a count, each sample inside the gate
takes :data:`GATE_LEAK` off it; when the count reaches ``max_rejections`` the next outlier is
accepted (flag :data:`FLAG_GATE_RELEASED`) and the gate stays open until the count has leaked
back to 0, so that a real change the model misses (a step, the reattachment transient when
actuation starts) is not locked out while isolated outliers are. A
missing or flagged sample (``dcl`` None or not finite) is predict only. NIS of the accepted updates is
tracked as a consistency monitor: running mean (≈ 1 when Q and R are right) and the
fraction inside the central 95 % band of χ²₁.

The estimate is ``ΔĈL(k) = ΔCL_H(k) + nl(Cμ_env(k), C x(k)) + b(k) + r-row(k) r(k)`` (+ states
that are part of the lift; pickups are not). ``est.model_dcl`` is the open-loop hybrid model
(what ``model.step`` gives).

Output stages of the model without an observer form are applied as known additive
corrections evaluated along the open-loop trajectory (exact for additive signals, a
unit-slope linearisation for filters). Input stages map (Cμ, Cμ_env) as in the model.

Q and R come from data (:func:`tune_observer`) and live in the model file's ``observer``
section; :meth:`Observer.from_model` reads them.

Hot path: :meth:`Observer.step` does no I/O, no logging and allocates no arrays. ``obs.kf``
(filterpy) holds ξ and P; the step runs filterpy's ``predict`` and Joseph ``update`` on those
very arrays in place, with preallocated buffers and level-1/2 BLAS calls (``scipy.linalg.blas``:
a numpy call costs ≈ 1 µs whatever its size, a BLAS level-1 call ≈ 0.15 µs). For the optimal
gain the Joseph form equals the rank-one downdate ``P = P⁻ − w wᵀ``, ``w = P⁻Hᵀ/√S`` (exactly
symmetric; positive definite for R > 0), which is what runs; the tests check it against
filterpy's ``predict`` + ``update`` to 1e-12 relative. It returns one preallocated
:class:`Estimate` updated in place.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.linalg import solve_discrete_lyapunov
from scipy.special import ndtri

from rtlift.blocks.stages import PeriodicDisturbance
from rtlift.errors import UserError
from rtlift.hybrid import HybridModel
from rtlift.records import Record

FLAG_MISSING = 1
"""No measurement (missing or flagged sample): predict only."""
FLAG_REJECTED = 2
"""Innovation outside the χ² gate: measurement rejected, predict only."""
FLAG_GATE_RELEASED = 4
"""Outside the gate but accepted: ``max_rejections`` outliers have piled up (module docstring)."""
FLAG_BAD_INPUT = 8
"""Cμ or Cμ_env was NaN/±inf: the last finite inputs are held and the sample is predict-only."""
GATE_LEAK = 0.25
"""What a sample inside the gate takes off the outlier count: the gate opens when more than
one sample in five falls outside it for a while (a consistent filter: one in 10⁴)."""

CONFIG_VERSION = 1


def chi2_1_quantile(p: float) -> float:
    """Quantile of χ² with one degree of freedom: ``(Φ⁻¹((1 + p)/2))²``."""
    return math.inf if p >= 1.0 else float(ndtri(0.5 * (1.0 + p))) ** 2


NIS_BAND = (chi2_1_quantile(0.025), chi2_1_quantile(0.975))
"""Central 95 % interval of χ²₁: a consistent filter has 95 % of its NIS values inside."""


class ObserverError(UserError):
    """A model that cannot be observed (no observer settings, an unsupported stage)."""


class Estimate:
    """One observer output. :meth:`Observer.step` returns the *same* object every call,
    updated in place (no allocation per sample): copy the fields you want to keep.

    ``dcl`` ΔĈL (filtered), ``model_dcl`` the open-loop hybrid model, ``innovation`` ν and
    ``nis`` ν²/S (NaN when there was no measurement), ``flags`` (FLAG_* bits), ``bias`` b̂,
    ``sample`` the number of steps so far.
    """

    __slots__ = ("dcl", "model_dcl", "innovation", "nis", "flags", "bias", "sample")

    def __init__(self) -> None:
        self.dcl = 0.0
        self.model_dcl = 0.0
        self.innovation = math.nan
        self.nis = math.nan
        self.flags = 0
        self.bias = 0.0
        self.sample = 0

    def as_tuple(self) -> tuple[float, float, float, float, int]:
        return (self.dcl, self.model_dcl, self.innovation, self.nis, self.flags)


@dataclass(frozen=True)
class StateBlock:
    """States an accepted effect adds: ``s(k) = F s(k−1) + w``, ``w ~ N(0, Q)``, seen in the
    measurement through ``h · s(k)``; ``in_estimate`` if they are part of the lift ΔĈL."""

    name: str
    F: np.ndarray
    Q: np.ndarray
    h: np.ndarray
    P0: np.ndarray
    in_estimate: bool = False

    @property
    def size(self) -> int:
        return int(self.h.size)


def _oscillator(params: dict[str, Any], fs_hz: float) -> StateBlock:
    """A periodic disturbance Σ A_i sin(ω_i k + φ_i) as rotating 2-state oscillators, one per
    line (the stage's own state space); the phases are the observer's to track."""
    stage = PeriodicDisturbance.from_params(params, fs_hz)
    F, _, h, _ = stage.statespace()
    amp = np.repeat(np.maximum(np.abs(stage.amplitudes), 1e-6), 2)
    return StateBlock("periodic_disturbance", F, np.diag((1e-3 * amp) ** 2), h, np.diag(amp**2))


OBSERVER_FORMS: dict[str, Callable[[dict[str, float], float], StateBlock | None]] = {
    "periodic_disturbance": _oscillator,
    "zero_drift": lambda params, fs_hz: None,   # absorbed by the random-walk bias state
}
"""Output stages the observer represents by states (a factory returning a
:class:`StateBlock`, or ``None`` when the bias state already covers the effect). Other
output stages are applied as known corrections (module docstring)."""


@dataclass(frozen=True)
class ObserverConfig:
    """Noise settings (the model file's ``observer`` section)."""

    R: float                        # measurement noise variance (ΔCL²)
    q_x: float                      # Wiener disturbance variance per sample (y²)
    q_bias: float                   # bias random-walk variance per sample (ΔCL²)
    p0_bias: float                  # initial bias variance (ΔCL²)
    gate_probability: float = 0.9999
    max_rejections: int = 40
    noise_ar: tuple[float, ...] = ()  # AR coefficients of a coloured part of the noise (() : white only)
    q_noise: float = 0.0            # its driving variance per sample (ΔCL²)
    q_gain_h: float = 0.0           # random-walk variance of a relative gain error of ΔCL_H (0: none)
    ripple_harmonics: int = 0       # H burst-synchronous harmonics (0: no ripple states)
    ripple_powers: int = 1          # amplitude terms Cμ_env (Cμ_env/Cμ_ref)^(p−1), p = 1 … ripple_powers
    q_ripple: float = 0.0           # ripple coefficient random-walk variance per sample (ΔCL²/Cμ²)
    p0_ripple: float = 0.0          # initial ripple coefficient variance (ΔCL²/Cμ²)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "noise_ar", tuple(float(a) for a in self.noise_ar))
        for name in ("R", "q_x", "q_bias", "p0_bias", "q_ripple", "p0_ripple", "q_noise", "q_gain_h"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ObserverError(f"observer setting {name} must be a finite number >= 0, got {v!r}")
        if self.R <= 0:
            raise ObserverError(f"observer setting R must be positive, got {self.R!r}")
        if not 0.5 < self.gate_probability <= 1.0:
            raise ObserverError(f"observer gate_probability must be in (0.5, 1], got {self.gate_probability!r}")
        if len(self.noise_ar) > 8 or not all(math.isfinite(a) for a in self.noise_ar) or (
                self.noise_ar and max(abs(np.roots([1.0, *(-a for a in self.noise_ar)]))) >= 1.0):
            raise ObserverError(f"observer noise_ar must be the coefficients of a stable AR model "
                                f"(at most 8), got {list(self.noise_ar)!r}")
        if not (isinstance(self.ripple_powers, int) and 1 <= self.ripple_powers <= 4):
            raise ObserverError(f"observer ripple_powers must be an integer in [1, 4], got {self.ripple_powers!r}")
        if not (isinstance(self.ripple_harmonics, int) and 0 <= self.ripple_harmonics <= MAX_HARMONICS):
            raise ObserverError(f"observer ripple_harmonics must be an integer in [0, {MAX_HARMONICS}], "
                                f"got {self.ripple_harmonics!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "model") -> ObserverConfig:
        if not d or "R" not in d:
            raise ObserverError(f"{source}: the model file has no observer settings (Q and R); "
                                "run rtlift.observer.tune_observer on recorded data and save them "
                                "with save_model(..., observer=...)")
        try:
            harmonics = d.get("ripple_harmonics", 0)
            if isinstance(harmonics, float) and harmonics.is_integer():
                harmonics = int(harmonics)
            return cls(R=float(d["R"]), q_x=float(d["q_x"]), q_bias=float(d["q_bias"]),
                       p0_bias=float(d.get("p0_bias", d["R"])),
                       gate_probability=float(d.get("gate_probability", 0.9999)),
                       max_rejections=int(d.get("max_rejections", 40)),
                       noise_ar=tuple(float(a) for a in d.get("noise_ar", ())),
                       q_noise=float(d.get("q_noise", 0.0)),
                       q_gain_h=float(d.get("q_gain_h", 0.0)),
                       ripple_harmonics=harmonics,
                       ripple_powers=int(d.get("ripple_powers", 1)),
                       q_ripple=float(d.get("q_ripple", 0.0)),
                       p0_ripple=float(d.get("p0_ripple", 0.0)),
                       extra={k: v for k, v in d.items() if k not in _CONFIG_KEYS})
        except (KeyError, TypeError, ValueError) as exc:
            raise ObserverError(f"{source}: bad observer settings ({exc})") from None

    def to_dict(self) -> dict[str, Any]:
        return {"version": CONFIG_VERSION, "R": self.R, "q_x": self.q_x, "q_bias": self.q_bias,
                "p0_bias": self.p0_bias, "gate_probability": self.gate_probability,
                "max_rejections": self.max_rejections, "noise_ar": list(self.noise_ar),
                "q_noise": self.q_noise, "ripple_harmonics": self.ripple_harmonics,
                "ripple_powers": self.ripple_powers, "q_gain_h": self.q_gain_h,
                "q_ripple": self.q_ripple, "p0_ripple": self.p0_ripple, **self.extra}


MAX_HARMONICS = 16
_CONFIG_KEYS = {"R", "q_x", "q_bias", "p0_bias", "gate_probability", "max_rejections",
                "noise_ar", "q_noise", "q_gain_h", "ripple_harmonics", "ripple_powers", "q_ripple",
                "p0_ripple"}


class BurstPhase:
    """Burst phase and period from the ``cmu`` column, and the ripple basis at that phase.

    An onset is Cμ(k) > 0 after Cμ(k−1) ≤ 0. φ(k) = samples since the last onset (0 at the
    onset), P(k) = the interval between the last two onsets when ``2H < P ≤ max_period``
    (unknown otherwise). :meth:`step` returns the basis row
    ``[cos(2π h φ/P)]_{h=1..H} ++ [sin(2π h φ/P)]_{h=1..H}`` when P is known and φ < P, else
    ``None``. The table of the current period (P rows of 2H floats) is built when the period
    changes and kept, so a step allocates nothing while the burst period stays the same.
    """

    def __init__(self, harmonics: int, max_period: int) -> None:
        self.harmonics = int(harmonics)
        self.max_period = int(max_period)
        self._period_rows: tuple[int, list[np.ndarray]] = (0, [])
        self.reset()

    def reset(self) -> None:
        self.prev = 0.0
        self.since = -1          # φ; −1 before the first onset
        self.period = 0          # 0: unknown

    def get_state(self) -> list[float]:
        return [self.prev, float(self.since), float(self.period)]

    def set_state(self, state: Sequence[float]) -> None:
        self.prev, self.since, self.period = float(state[0]), int(state[1]), int(state[2])

    def table(self, period: int) -> list[np.ndarray]:
        if self._period_rows[0] != period:
            h = np.arange(1, self.harmonics + 1, dtype=float)
            ang = 2.0 * math.pi * np.outer(np.arange(period, dtype=float), h) / period
            tab = np.ascontiguousarray(np.hstack([np.cos(ang), np.sin(ang)]))
            self._period_rows = (period, list(tab))
        return self._period_rows[1]

    def step(self, cmu: float) -> np.ndarray | None:
        if cmu > 0.0 and not self.prev > 0.0:
            if self.since >= 0:
                interval = self.since + 1
                self.period = interval if 2 * self.harmonics < interval <= self.max_period else 0
            self.since = 0
        elif self.since >= 0:
            self.since += 1
        self.prev = cmu
        p = self.period
        if p and self.since < p:
            return self.table(p)[self.since]
        return None

    def rows(self, cmu: np.ndarray) -> np.ndarray:
        """Batch twin: the basis row per sample (zeros where undefined), from the current state."""
        out = np.zeros((len(cmu), 2 * self.harmonics))
        for k, c in enumerate(np.asarray(cmu, dtype=float).tolist()):
            row = self.step(c)
            if row is not None:
                out[k] = row
        return out


def _gain_function(nl: Any) -> Callable[[float], float]:
    """The Wiener gain N in force after the open-loop step of the sample: N(Cμ_env) for the
    paper's table, times g (1 + m h) for :class:`~rtlift.blocks.wiener.HysteresisGain` (its
    ``h`` is the one the open-loop step just updated)."""
    if hasattr(nl, "factor"):
        return lambda env: nl.gain_at(env) * nl.factor()
    return nl.gain_at


class _Structure:
    """The constant matrices of the state assembly (shared by the streaming and batch filters)."""

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
        nr = 2 * self.harmonics * self.powers
        d = n + 1 + sum(b.size for b in self.blocks) + nr
        self.n, self.d, self.nr = n, d, nr
        self.r0 = d - nr                       # first ripple state
        F = np.zeros((d, d))
        F[:n, :n] = A
        F[n, n] = 1.0
        G = np.zeros(d)
        G[:n] = B
        h = np.zeros(d)          # constant part of H (the Wiener and ripple parts are set per sample)
        h[n] = 1.0
        h_est = np.zeros(d)      # constant part of what of ξ beyond x enters ΔĈL
        h_est[n] = 1.0
        Qs = np.zeros((d, d))
        P0s = np.zeros((d, d))
        Qn = np.zeros((d, d))      # the coloured noise's (scaled by q_noise)
        P0n = np.zeros((d, d))
        Qg = np.zeros((d, d))
        self.ig = -1
        i = n + 1
        for b in self.blocks:
            j = i + b.size
            F[i:j, i:j] = b.F
            if b.name == "coloured_noise":
                Qn[i:j, i:j] = b.Q
                P0n[i:j, i:j] = b.P0
            elif b.name == "gain_h":
                Qg[i:j, i:j] = b.Q
                self.ig = i
            else:
                Qs[i:j, i:j] = b.Q
                P0s[i:j, i:j] = b.P0
            h[i:j] = b.h
            if b.in_estimate:
                h_est[i:j] = b.h
            i = j
        r = slice(self.r0, d)
        F[r, r] = np.eye(nr)
        Qr = np.zeros((d, d))
        Qr[r, r] = np.eye(nr)
        cb = float(C @ B)
        scale = abs(cb) if abs(cb) > 1e-12 * (np.linalg.norm(C) * np.linalg.norm(B) + 1e-300) \
            else float(np.linalg.norm(C) * np.linalg.norm(B)) or 1.0
        v = B / scale
        Qx = np.zeros((d, d))
        Qx[:n, :n] = np.outer(v, v)
        Qb = np.zeros((d, d))
        Qb[n, n] = 1.0
        self.F, self.G, self.h, self.h_est, self.C = F, G, h, h_est, C.copy()
        self.Qx, self.Qb, self.Qs, self.Qr, self.P0s = Qx, Qb, Qs, Qr, P0s
        self.Qn, self.P0n, self.Qg = Qn, P0n, Qg

    def Q(self, cfg: ObserverConfig) -> np.ndarray:
        return (cfg.q_x * self.Qx + cfg.q_bias * self.Qb + self.Qs + cfg.q_noise * self.Qn
                + cfg.q_gain_h * self.Qg + cfg.q_ripple * self.Qr)

    def P0(self, cfg: ObserverConfig) -> np.ndarray:
        P = self.P0s + cfg.q_noise * self.P0n      # the coloured noise starts stationary
        P[self.n, self.n] = cfg.p0_bias
        P += cfg.p0_ripple * self.Qr
        return P

    def phase(self) -> BurstPhase:
        return BurstPhase(self.harmonics, self.max_period)

    def amplitudes(self, env: float) -> list[float]:
        """The ripple's amplitude terms Cμ_env (Cμ_env/Cμ_ref)^(p−1), p = 1 … powers."""
        w, out = env, []
        for _ in range(self.powers):
            out.append(w)
            w = w * env / self.cmu_ref
        return out


def _copy_model(model: HybridModel) -> HybridModel:
    from rtlift.modelfile import model_from_dict, model_to_dict

    return model_from_dict(model_to_dict(model), allow_unstable=not model.stable)


class Observer:
    """Kalman observer of ΔCL around a :class:`~rtlift.hybrid.HybridModel` (module docstring).

    ``obs = Observer.from_model(model)``; per sample ``est = obs.step(cmu, env, dcl)``
    (``dcl=None`` when missing/flagged). ``obs.kf`` is the filterpy ``KalmanFilter`` that
    holds ``x``, ``P``, ``F``, ``Q``, ``R``, ``H`` and ``B`` (= G); the step updates its ``x``
    and ``P`` arrays in place. The observer owns a copy of the model, whose blocks it steps.
    """

    def __init__(self, model: HybridModel, config: ObserverConfig) -> None:
        self.model = _copy_model(model)
        self.config = config
        st = _Structure(self.model, config.ripple_harmonics, config.noise_ar, config.ripple_powers,
                        config.q_gain_h > 0)
        self.structure = st
        kf = KalmanFilter(dim_x=st.d, dim_z=1, dim_u=1)
        kf.F = st.F.copy()
        kf.B = st.G.reshape(-1, 1).copy()
        kf.Q = st.Q(config)
        kf.R = np.array([[config.R]])
        self.kf = kf
        self.gate = chi2_1_quantile(config.gate_probability)
        d, n = st.d, st.n
        # preallocated buffers: the hot path allocates no arrays
        self._x = np.zeros(d)
        self._P = np.zeros((d, d))
        self._PT = self._P.T                    # Fortran-ordered view for BLAS dger (P is symmetric)
        self._Pf = self._P.reshape(-1)
        self._H = st.h.copy()
        kf.H = self._H.reshape(1, -1)           # the row of the last step
        self._Hr = self._H[st.r0:]
        self._xw = self._x[:n]
        self._xr = self._x[st.r0:]
        self._FT = st.F.T.copy()
        self._t = np.zeros(d)
        self._u = np.zeros(d)
        self._T = np.zeros((d, d))
        self._F = st.F
        self._G = st.G
        self._Qf = np.ascontiguousarray(kf.Q).reshape(-1)
        self._R = float(config.R)
        self._Cl = [float(c) for c in st.C]
        self._he = st.h_est.copy()              # bias and lift blocks (ripple: its own row)
        self._has_ripple = st.harmonics > 0
        nb = 2 * st.harmonics
        self._Hr_parts = [self._Hr[i * nb:(i + 1) * nb] for i in range(st.powers)]
        self._ripple_on = False
        self._cmu_ref = st.cmu_ref
        self._ig = st.ig
        if st.ig >= 0:
            self._he[st.ig] = 0.0               # its row is set per sample: added below
        self.phase = st.phase()
        m = self.model
        self._input_stages = tuple(m.input_stages)
        self._output_stages = tuple(zip(m.output_stages, st.replaced, strict=True))
        self._conv_step = m.convolution.step
        self._hp_step = m.highpass.step
        self._wiener_ol = m.wiener
        self._nl = m.wiener.nonlinearity
        self._C = st.C
        self._input_gain = st.form == "input_gain"
        self._gain = _gain_function(self._nl) if self._input_gain else None
        from scipy.linalg import blas
        self._ddot, self._daxpy, self._dcopy, self._dscal, self._dger = (
            blas.ddot, blas.daxpy, blas.dcopy, blas.dscal, blas.dger)
        self._check_in_place()
        self.estimate = Estimate()
        self.reset()

    def _check_in_place(self) -> None:
        """The BLAS wrappers write into the buffers they are given only when dtype and layout
        match; check once that they do (a silent copy would leave the state unchanged)."""
        P = np.eye(self.structure.d)
        t = np.ones(self.structure.d)
        ok = (self._dger(-1.0, t, t, a=P.T, overwrite_a=1).base is P
              and self._daxpy(t, self._t, a=0.0) is self._t
              and self._dscal(1.0, self._t) is self._t
              and self._dcopy(self._t, self._u) is self._u
              and self._daxpy(self._Qf, P.reshape(-1), a=0.0).base is P)
        if not ok:   # pragma: no cover - a BLAS build that copies
            raise ObserverError("observer: BLAS wrappers do not update buffers in place")

    @classmethod
    def from_model(cls, model: HybridModel) -> Observer:
        """The observer with the Q and R stored in the model file (``model.observer_config``)."""
        return cls(model, ObserverConfig.from_dict(model.observer_config))

    # -- state ------------------------------------------------------------------------
    def reset(self) -> None:
        """Model at rest, ξ = 0, P = P₀, burst phase unknown, monitors cleared."""
        self.model.reset()
        self._x[:] = 0.0
        self._P[:] = self.structure.P0(self.config)
        self._H[:] = self.structure.h
        self._ripple_on = False
        self.phase.reset()
        self._sync_kf()
        self._rejected_run = 0
        self._gate_open = False
        self._last_cmu = self._last_env = 0.0
        self.clear_monitors()
        e = self.estimate
        e.dcl = e.model_dcl = e.bias = 0.0
        e.innovation = e.nis = math.nan
        e.flags = 0
        e.sample = 0

    def _sync_kf(self) -> None:
        self.kf.x = self._x
        self.kf.P = self._P

    def get_state(self) -> np.ndarray:
        """[model state, ξ, P (row-major), H's ripple part, burst phase (3), outlier count,
        gate open, steps] — a copy."""
        return np.concatenate([self.model.get_state(), self._x, self._P.ravel(), self._Hr,
                               self.phase.get_state(),
                               [float(self._rejected_run), float(self._gate_open),
                                float(self.estimate.sample)]])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        ms, d, nr = self.model.state_size, self.structure.d, self._Hr.size
        size = ms + d + d * d + nr + 3 + 3
        if s.shape != (size,):
            raise ValueError(f"observer state must have shape ({size},), got {s.shape}")
        self.model.set_state(s[:ms])
        i = ms
        self._x[:] = s[i:i + d]
        i += d
        self._P[:] = s[i:i + d * d].reshape(d, d)
        i += d * d
        self._Hr[:] = s[i:i + nr]
        self._ripple_on = bool(np.any(self._Hr))
        i += nr
        self.phase.set_state(s[i:i + 3])
        self._rejected_run = float(s[-3])
        self._gate_open = bool(s[-2])
        self.estimate.sample = int(s[-1])

    # -- monitors ---------------------------------------------------------------------
    def clear_monitors(self) -> None:
        """Zero the counters and NIS/likelihood sums (the state is kept)."""
        self.updates = self.rejected = self.missing = self.bad_inputs = 0
        self._nis_sum = 0.0
        self._nis_in_band = 0
        self._nll_sum = 0.0

    @property
    def nll(self) -> float:
        """Mean negative log-likelihood of the accepted innovations, ``mean(ln S + ν²/S)``
        (up to a constant): what :func:`tune_observer` minimises."""
        return self._nll_sum / self.updates if self.updates else math.nan

    @property
    def nis_mean(self) -> float:
        """Running mean of the NIS of accepted updates (≈ 1 for a consistent filter)."""
        return self._nis_sum / self.updates if self.updates else math.nan

    @property
    def nis_band_fraction(self) -> float:
        """Fraction of accepted NIS values inside the 95 % χ²₁ band (≈ 0.95 if consistent)."""
        return self._nis_in_band / self.updates if self.updates else math.nan

    def monitors(self) -> dict[str, float | int]:
        return {"updates": self.updates, "rejected": self.rejected, "missing": self.missing,
                "bad_inputs": self.bad_inputs,
                "nis_mean": self.nis_mean, "nis_band_fraction": self.nis_band_fraction}

    # -- the 400 Hz step --------------------------------------------------------------
    def step(self, cmu: float, env: float, dcl: float | None) -> Estimate:
        """One sample: Cμ(k), Cμ_env(k) and the measured ΔCL(k) (``None``, NaN or ±inf: predict only).

        Returns the observer's preallocated :class:`Estimate`, updated in place. A non-finite
        Cμ or Cμ_env would poison the model's state for good: the last finite inputs are held
        instead and the sample is predict-only (``FLAG_BAD_INPUT``).
        """
        bad_input = 0
        if -math.inf < cmu < math.inf and -math.inf < env < math.inf:
            self._last_cmu = cmu
            self._last_env = env
        else:
            cmu, env, dcl = self._last_cmu, self._last_env, None
            bad_input = FLAG_BAD_INPUT
            self.bad_inputs += 1
        for s in self._input_stages:
            cmu, env = s.step(cmu, env)
        high = self._hp_step(self._conv_step(cmu))
        known = high
        total = high + self._wiener_ol.step(env)
        for s, replaced in self._output_stages:
            before = total
            total = s.step(total)
            if not replaced:
                known += total - before
        est = self.estimate
        est.model_dcl = total
        est.sample += 1

        x, P, H, t = self._x, self._P, self._H, self._t
        ddot, daxpy = self._ddot, self._daxpy
        # predict (filterpy's predict): ξ⁻ = F ξ + G u,  P⁻ = F P Fᵀ + Q
        np.dot(self._F, x, out=t)
        self._dcopy(t, x)
        daxpy(self._G, x, a=env)
        T = self._T
        np.dot(self._F, P, out=T)
        np.dot(T, self._FT, out=P)
        daxpy(self._Qf, self._Pf)
        # measurement row H(k) and prediction ẑ⁻
        if self._input_gain:
            g = self._gain(env)
            c = 0.0
        else:
            y = ddot(self._C, self._xw)
            g = self._nl.slope_at(y)
            c = self._nl.output_at(env, y) - g * y
        for i, ci in enumerate(self._Cl):
            H[i] = g * ci
        ig = self._ig
        if ig >= 0:
            H[ig] = high
        if self._has_ripple:
            row = self.phase.step(cmu)
            if row is not None:
                w = env
                for part in self._Hr_parts:        # r-row = [w_p · basis]_p, w_p = Cμ_env (Cμ_env/Cμ_ref)^(p−1)
                    self._dcopy(row, part)
                    self._dscal(w, part)
                    w = w * env / self._cmu_ref
                self._ripple_on = True
            elif self._ripple_on:
                self._dscal(0.0, self._Hr)
                self._ripple_on = False
        zhat = known + c + ddot(H, x)

        flags = 0
        if dcl is None or not -math.inf < dcl < math.inf:  # NaN/inf would poison ξ and P for good
            flags = FLAG_MISSING
            self.missing += 1
            est.innovation = math.nan
            est.nis = math.nan
        else:
            nu = dcl - zhat
            u = self._u
            np.dot(P, H, out=u)                   # P⁻Hᵀ
            S = ddot(H, u) + self._R
            nis = nu * nu / S
            est.innovation = nu
            est.nis = nis
            outside = nis > self.gate
            if outside and not self._gate_open and self._rejected_run < self.config.max_rejections:
                flags = FLAG_REJECTED
                self.rejected += 1
                self._rejected_run += 1
            else:
                if outside:         # released: stays open until as many samples fell inside
                    flags = FLAG_GATE_RELEASED
                    self._gate_open = True
                    self._rejected_run = self.config.max_rejections
                elif self._rejected_run:
                    self._rejected_run = max(self._rejected_run - GATE_LEAK, 0.0)
                    self._gate_open = self._gate_open and self._rejected_run > 0
                self.updates += 1
                self._nis_sum += nis
                self._nll_sum += math.log(S) + nis
                if NIS_BAND[0] <= nis <= NIS_BAND[1]:
                    self._nis_in_band += 1
                # update: ξ = ξ⁻ + K ν with K = P⁻Hᵀ/S; Joseph form with this K: P = P⁻ − w wᵀ, w = P⁻Hᵀ/√S
                daxpy(u, x, a=nu / S)
                self._dscal(1.0 / math.sqrt(S), u)
                self._dger(-1.0, u, u, a=self._PT, overwrite_a=1)
        est.flags = flags | bad_input
        xw = self._xw
        est.bias = float(x[self.structure.n])
        wiener = g * ddot(self._C, xw) if self._input_gain else self._nl.output_at(env, ddot(self._C, xw))
        est.dcl = known + wiener + ddot(self._he, x) + (ddot(self._Hr, self._xr) if self._ripple_on else 0.0)
        if ig >= 0:
            est.dcl += high * x[ig]
        return est

    def run(self, cmu: np.ndarray, env: np.ndarray, dcl: np.ndarray) -> dict[str, np.ndarray]:
        """Step through arrays (NaN in ``dcl`` = missing); returns the estimate arrays."""
        n = len(cmu)
        out = {k: np.empty(n) for k in ("dcl", "model_dcl", "innovation", "nis")}
        out["flags"] = np.empty(n, dtype=np.int64)
        step = self.step
        for i, (c, e, z) in enumerate(zip(np.asarray(cmu, float).tolist(), np.asarray(env, float).tolist(),
                                          np.asarray(dcl, float).tolist(), strict=True)):
            est = step(c, e, None if z != z else z)
            out["dcl"][i] = est.dcl
            out["model_dcl"][i] = est.model_dcl
            out["innovation"][i] = est.innovation
            out["nis"][i] = est.nis
            out["flags"][i] = est.flags
        return out


# -- identification of Q and R ----------------------------------------------------------

def actuator_off_noise(record: Record, tare_seconds: float = 2.0) -> np.ndarray:
    """ΔCL over the first ``tare_seconds`` while the actuator is off (mean removed)."""
    n = int(round(tare_seconds * record.fs_hz))
    off = (record.cmu[:n] == 0) & (record.cmu_envelope[:n] == 0)
    z = record.dcl[:n][off]
    return z - z.mean() if z.size else z


def _known_inputs(model: HybridModel, rec: Record) -> dict[str, np.ndarray]:
    """Per sample: known part of ẑ (ΔCL_H + non-replaced stage corrections), u = Cμ_env′,
    Cμ′ (after the input stages), the Wiener gain N and the open-loop model — computed by the
    model's own batch twins from rest."""
    m = _copy_model(model)
    st = _Structure(m)
    cmu, env = rec.cmu, rec.cmu_envelope
    for s in m.input_stages:
        cmu, env = s.simulate(cmu, env)
    high = m.highpass.simulate(m.convolution.simulate(cmu))
    low, _ = m.wiener.simulate(env)
    total = high + low
    known = high.copy()
    for s, replaced in zip(m.output_stages, st.replaced, strict=True):
        before = total
        total = s.simulate(total)
        if not replaced:
            known += total - before
    u = np.asarray(env, dtype=float)
    nl = _copy_model(model).wiener.nonlinearity
    gains = nl.simulate(u, np.ones_like(u)) if st.form == "input_gain" else None
    return {"known": known, "u": u, "cmu": np.asarray(cmu, dtype=float), "gain": gains, "model": total,
            "high": high}


def batch_nis(model: HybridModel, record: Record, configs: Sequence[ObserverConfig],
              skip: int = 0) -> dict[str, np.ndarray]:
    """Run the observer of :meth:`Observer.step` for several configs at once over a record
    (vectorised across configs; they must share ``ripple_harmonics``) and return per config:
    ``nis_mean``, ``nis_band_fraction``, ``nll`` (mean negative log-likelihood of the
    innovations, up to a constant), ``rejected``, ``updates``. Samples before ``skip`` are
    filtered but not scored."""
    shapes = {(c.ripple_harmonics, c.noise_ar, c.ripple_powers, c.q_gain_h > 0) for c in configs}
    if len(shapes) != 1:
        raise ValueError("batch_nis: configs must share ripple_harmonics, ripple_powers and noise_ar")
    m = _copy_model(model)
    st = _Structure(m, *shapes.pop())
    data = _known_inputs(model, record)
    known, u, z = data["known"], data["u"], record.dcl
    if st.harmonics:
        basis = st.phase().rows(data["cmu"])
        ripple = np.hstack([basis * w[:, None] for w in st.amplitudes(u)])
    else:
        ripple = None
    M, d, n, r0 = len(configs), st.d, st.n, st.r0
    F, G, FT, C = st.F, st.G, st.F.T, st.C
    Q = np.stack([st.Q(c) for c in configs])
    R = np.array([c.R for c in configs])
    gates = np.array([chi2_1_quantile(c.gate_probability) for c in configs])
    max_rej = np.array([c.max_rejections for c in configs])
    x = np.zeros((M, d))
    P = np.stack([st.P0(c) for c in configs])
    nl = m.wiener.nonlinearity
    input_gain = st.form == "input_gain"
    gains = data["gain"]
    nis_sum = np.zeros(M)
    in_band = np.zeros(M)
    nll = np.zeros(M)
    count = np.zeros(M)
    rejected = np.zeros(M)
    run = np.zeros(M)
    gate_open = np.zeros(M, dtype=bool)
    eye = np.eye(d)
    H = np.tile(st.h, (M, 1))
    for k in range(len(z)):
        x = x @ FT + G * u[k]
        P = F @ P @ FT + Q
        if ripple is not None:
            H[:, r0:] = ripple[k]
        if st.ig >= 0:
            H[:, st.ig] = data["high"][k]
        if input_gain:
            H[:, :n] = gains[k] * C
            zhat = known[k] + x @ H[0]
        else:
            y = x[:, :n] @ C
            g = np.array([nl.slope_at(v) for v in y])
            fy = nl.simulate(None, y)
            H[:, :n] = g[:, None] * C
            zhat = known[k] + fy + np.einsum("md,md->m", H[:, n:], x[:, n:])
        if z[k] != z[k]:
            continue
        nu = z[k] - zhat
        PH = np.einsum("mij,mj->mi", P, H)
        S = np.einsum("mi,mi->m", H, PH) + R
        nis = nu * nu / S
        outside = nis > gates
        release = outside & (gate_open | (run >= max_rej))
        reject = outside & ~release
        accept = ~reject
        run = np.where(release, max_rej, np.where(outside, run + 1, np.maximum(run - GATE_LEAK, 0.0)))
        gate_open = np.where(release, True, np.where(outside, gate_open, gate_open & (run > 0)))
        if k >= skip:
            rejected += reject
            nis_sum += np.where(accept, nis, 0.0)
            in_band += accept & (nis >= NIS_BAND[0]) & (nis <= NIS_BAND[1])
            nll += np.where(accept, np.log(S) + nis, 0.0)
            count += accept
        K = np.where(accept[:, None], PH / S[:, None], 0.0)
        x = x + K * nu[:, None]
        IKH = eye - K[:, :, None] * H[:, None, :]
        P = IKH @ P @ IKH.transpose(0, 2, 1) + R[:, None, None] * K[:, :, None] * K[:, None, :]
    count = np.maximum(count, 1)
    return {"nis_mean": nis_sum / count, "nis_band_fraction": in_band / count, "nll": nll / count,
            "rejected": rejected, "updates": count}


def fit_noise(segments: Sequence[np.ndarray], order: int = 2) -> dict[str, Any]:
    """White + AR(``order``) model of the actuator-off noise, by Whittle likelihood on the pooled
    periodograms of the segments (each mean-removed, ≥ 64 samples)::

        z(k) = e(k) + v(k),   e(k) = Σ a_i e(k−i) + w(k),   v ~ N(0, R_w),   w ~ N(0, q)
        S(ω) = R_w + q / |1 − Σ a_i e^{−jωi}|²

    The AR poles are parametrised as a complex pair (radius, angle) for order 2, real radii
    otherwise, radius ≤ 0.995 (a slower part is drift, the bias state's). Returns ``R`` (= R_w),
    ``noise_ar``, ``q_noise`` and ``total`` (variance of the segments); white only (R = total)
    unless the coloured model wins the likelihood-ratio test against white noise at 0.1 %."""
    from scipy import optimize
    from scipy.stats import chi2

    R_MAX = 0.995  # noqa: N806

    segs = [np.asarray(z, float) - np.mean(z) for z in segments if len(z) >= 64]
    if not segs:
        raise ValueError("fit_noise needs a segment of at least 64 samples")
    total = float(np.mean(np.concatenate(segs) ** 2))
    pgrams = []
    for z in segs:
        Z = np.fft.rfft(z)
        w = 2.0 * np.pi * np.arange(Z.size) / z.size
        pgrams.append((w[1:-1], np.abs(Z[1:-1]) ** 2 / z.size))

    def coeffs(p: np.ndarray) -> np.ndarray:
        if order == 2:     # a complex or double pole pair: radius, angle
            r = R_MAX / (1.0 + math.exp(-p[2]))
            th = math.pi / (1.0 + math.exp(-p[3]))
            return np.array([2.0 * r * math.cos(th), -r * r])
        return -np.poly(R_MAX / (1.0 + np.exp(-p[2:2 + order])))[1:]

    def nll(p: np.ndarray) -> float:
        a = coeffs(p)
        out = 0.0
        for w, per in pgrams:
            den = np.abs(1.0 - sum(a[i] * np.exp(-1j * (i + 1) * w) for i in range(order))) ** 2
            spec = math.exp(p[0]) + math.exp(p[1]) / den
            out += float(np.sum(np.log(spec) + per / spec))
        return out

    best = None
    for frac in (0.01, 0.1, 0.5):
        for th in (-3.0, -1.5, 0.0, 1.5):
            shape = [2.0, th] if order == 2 else [2.0 + th] * order
            p0 = np.array([math.log(total * (1 - frac)), math.log(total * frac * 0.05), *shape])
            res = optimize.minimize(nll, p0, method="Nelder-Mead",
                                    options={"maxiter": 3000, "xatol": 1e-5, "fatol": 1e-7})
            if best is None or res.fun < best.fun:
                best = res
    white = sum(float(np.sum(np.log(total) + per / total)) for _, per in pgrams)
    if 2.0 * (white - best.fun) < chi2.ppf(0.999, order + 1):       # likelihood ratio: no colour
        return {"R": total, "noise_ar": (), "q_noise": 0.0, "total": total}
    a = coeffs(best.x)
    Rw, q = math.exp(best.x[0]), math.exp(best.x[1])
    Fn = np.zeros((order, order))
    Fn[0, :] = a
    Fn[1:, :-1] = np.eye(order - 1)
    e1 = np.zeros((order, order))
    e1[0, 0] = 1.0
    ar_var = float(solve_discrete_lyapunov(Fn, e1)[0, 0]) * q
    return {"R": Rw, "noise_ar": tuple(float(v) for v in a), "q_noise": q, "total": total,
            "coloured_std": math.sqrt(ar_var)}


def tune_observer(model: HybridModel, records: Sequence[Record], *, tare_seconds: float = 2.0,
                  max_seconds: float = 30.0, skip_seconds: float = 2.0,
                  gate_probability: float = 0.9999, max_rejections: int = 10, harmonics: int = 8,
                  ripple_powers: int = 1, sweeps: int = 1) -> dict[str, Any]:
    """Q and R from data, for ``save_model(..., observer=tune_observer(model, records))``.

    - Noise: the actuator-off tare seconds at the start of each record (pooled) give R and the
      coloured part of the noise (buffeting: :func:`fit_noise`); if no record has them, R is
      half the variance of the first difference of the open-loop residual (white only).
    - Structure: ``harmonics`` burst-synchronous ripple harmonics (0: none) and a random-walk
      gain on ΔCL_H (module docstring).
    - Q: ``q_x``, ``q_bias``, ``q_ripple``, ``q_gain_h`` and a common scale of the noise
      (R and q_noise together: the tare is taken stalled, where buffeting is strongest) by
      maximum likelihood of the innovations (:attr:`Observer.nll`), coordinate search on a
      log grid (factors 10 then √10, ``sweeps`` passes), starting from values relative to R.
      The consistency that results (mean NIS, fraction in the χ²₁ band) is reported.
    At most ``max_seconds`` of each record are used; the first ``skip_seconds`` are not scored.
    """
    if not records:
        raise ValueError("tune_observer needs at least one record")
    fs = model.fs_hz
    recs = [r.slice(0, int(round(max_seconds * fs))) for r in records]
    quiet = [actuator_off_noise(r, tare_seconds) for r in recs]
    pooled = np.concatenate(quiet)
    if pooled.size >= 200:
        noise = fit_noise(quiet)
        r_source = (f"actuator-off tare ({pooled.size} samples in the first {tare_seconds:g} s): "
                    + ("white + AR(2) by Whittle likelihood" if noise["noise_ar"] else "white"))
    else:
        res = np.concatenate([r.dcl - _known_inputs(model, r)["model"] for r in recs])
        R = float(np.var(np.diff(res)) / 2.0)
        noise = {"R": R, "noise_ar": (), "q_noise": 0.0, "total": R}
        r_source = "half the variance of the first difference of the open-loop residual"
    if not noise["R"] > 0:
        raise ValueError("measurement noise variance is zero: cannot tune the observer")
    R_total = noise["total"]
    data = [_known_inputs(model, r) for r in recs]
    u = np.concatenate([d["u"] for d in data])
    st = _Structure(_copy_model(model))
    nl = model.wiener.nonlinearity
    if st.form == "input_gain":
        g_ref = float(np.mean(np.abs(np.concatenate([d["gain"] for d in data])))) or 1.0
    else:
        g_ref = float(np.mean(np.abs(np.diff(nl.f) / np.diff(nl.y)))) or 1.0
    env2 = float(np.mean(u[u > 0] ** 2)) if np.any(u > 0) else 1.0
    p0_ripple = R_total / env2
    skip = int(round(skip_seconds * fs))
    arrays = [(r.cmu.tolist(), r.cmu_envelope.tolist(), [None if z != z else z for z in r.dcl.tolist()])
              for r in recs]

    def config(p: dict[str, float]) -> ObserverConfig:
        ns = 10.0 ** p["noise"]
        return ObserverConfig(R=noise["R"] * ns, q_x=10.0 ** p["q_x"] * R_total / g_ref**2,
                              q_bias=10.0 ** p["q_bias"] * R_total, p0_bias=R_total,
                              gate_probability=gate_probability, max_rejections=max_rejections,
                              noise_ar=noise["noise_ar"], q_noise=noise["q_noise"] * ns,
                              ripple_harmonics=harmonics, ripple_powers=ripple_powers,
                              q_ripple=10.0 ** p["q_ripple"] * p0_ripple if harmonics else 0.0,
                              p0_ripple=p0_ripple if harmonics else 0.0,
                              q_gain_h=10.0 ** p["q_gain_h"])

    cache: dict[tuple, dict[str, float]] = {}

    def score(p: dict[str, float]) -> dict[str, float]:
        key = tuple(round(p[k], 6) for k in sorted(p))
        if key not in cache:
            obs = Observer(model, config(p))
            nll = nis = band = 0.0
            updates = rejected = 0
            for c, e, z in arrays:
                obs.reset()
                step = obs.step
                n_skip = min(skip, len(c) // 4)
                for k in range(n_skip):
                    step(c[k], e[k], z[k])
                obs.clear_monitors()
                for k in range(n_skip, len(c)):
                    step(c[k], e[k], z[k])
                nll += obs._nll_sum
                nis += obs._nis_sum
                band += obs._nis_in_band
                updates += obs.updates
                rejected += obs.rejected
            cache[key] = {"nll": nll / max(updates, 1), "nis_mean": nis / max(updates, 1),
                          "nis_band_fraction": band / max(updates, 1), "rejected": rejected}
        return cache[key]

    # log10 of: noise scale, q_x·g²/R, q_bias/R, q_ripple/p0_ripple, q_gain_h; start and bounds
    p = {"noise": 0.0, "q_x": -3.0, "q_bias": -4.0, "q_ripple": -4.0, "q_gain_h": -5.0}
    bounds = {"noise": (-1.0, 1.0), "q_x": (-6.0, 0.0), "q_bias": (-6.0, -2.0), "q_ripple": (-8.0, -1.0),
              "q_gain_h": (-8.0, -2.0)}
    names = ["noise", "q_x", "q_bias", "q_gain_h"] + (["q_ripple"] if harmonics else [])
    for step_size in [1.0] * sweeps + [0.5] * sweeps:
        for name in names:
            best = score(p)["nll"]
            for sign in (-1.0, 1.0):
                while True:
                    trial = dict(p, **{name: p[name] + sign * step_size})
                    if not bounds[name][0] <= trial[name] <= bounds[name][1]:
                        break
                    s = score(trial)["nll"]
                    if not s < best:
                        break
                    best, p = s, trial
    best_cfg = config(p)
    result = score(p)
    out = best_cfg.to_dict()
    out.update({
        "method": "R and a coloured (AR) noise part from actuator-off noise (Whittle); q_x, q_bias, "
                  "q_ripple, q_gain_h and a common noise scale by innovation maximum likelihood "
                  "(coordinate search on a log grid)",
        "r_source": r_source,
        "tuned_on": [r.name for r in records],
        "nis_mean": float(result["nis_mean"]),
        "nis_band_fraction": float(result["nis_band_fraction"]),
        "rejected": int(result["rejected"]),
        "nll": float(result["nll"]),
        "evaluations": len(cache),
        "measurement_noise_std": math.sqrt(R_total),
        "log10_factors": {k: round(v, 3) for k, v in p.items()},
    })
    return out
