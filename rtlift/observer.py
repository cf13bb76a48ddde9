"""Kalman observer around the hybrid model (filterpy's ``KalmanFilter``; textbook names).

State (dimension d = n + 1 + Σ n_blocks)::

    ξ(k) = [ x(k) ; b(k) ; s(k) ]

- ``x`` the n states of the Wiener LTI, in the paper's timing (eqs. 4–5):
  ``x(k) = A x(k−1) + B Cμ_env(k) + w_x(k)``;
- ``b`` a random-walk bias (sensor zero drift and slow model error): ``b(k) = b(k−1) + w_b(k)``;
- ``s`` states that accepted effects bring (:data:`OBSERVER_FORMS`, e.g. the oscillator of a
  periodic disturbance), each a :class:`StateBlock` with its own F, Q and measurement row.

Prediction, with the input at time k (so *predict with u = Cμ_env(k), then update with the
measurement at k*)::

    ξ⁻(k) = F ξ(k−1) + G u(k),   F = diag(A, 1, F_s),   G = [B; 0; 0],   u(k) = Cμ_env(k)
    P⁻(k) = F P(k−1) Fᵀ + Q,      Q = diag(q_x v vᵀ, q_b, Q_s),   v = B / (C B)

(``q_x`` is the variance per sample of a disturbance on y = C x, ``q_b`` that of the bias step.)

Measurement (ΔCL from the balance) with a time-varying row::

    z(k) = ΔCL_H(k) + N(Cμ_env(k)) C x(k) + b(k) + h_s s(k) + v(k),   v ~ N(0, R)
    H(k) = [ N(Cμ_env(k)) C , 1 , h_s ]

``ΔCL_H(k) = HF(φ Σ h(j) Cμ(k−j))`` is computed by the model's own blocks and enters as a
known input. For the textbook Wiener form ``f(y)`` the row is linearised at the predicted
``ŷ⁻ = C x⁻`` (extended Kalman filter): ``H(k) = [f′(ŷ⁻) C, 1, h_s]`` and the prediction uses
``f(ŷ⁻)``. Update (scalar innovation ν, Joseph form)::

    ν = z − ẑ⁻,   S = H P⁻ Hᵀ + R,   K = P⁻ Hᵀ / S,   NIS = ν² / S
    ξ = ξ⁻ + K ν,   P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ

χ² gating: a sample with NIS above the ``gate_probability`` quantile of χ²₁ is rejected
(predict only, counted); after ``max_rejections`` consecutive rejections the next one is
accepted anyway (flag :data:`FLAG_GATE_RELEASED`) so that a real step is not locked out. A
missing or flagged sample (``dcl`` None or not finite) is predict only. NIS of the accepted updates is
tracked as a consistency monitor: running mean (≈ 1 when Q and R are right) and the
fraction inside the central 95 % band of χ²₁.

The estimate is ``ΔĈL(k) = ΔCL_H(k) + nl(Cμ_env(k), C x(k)) + b(k)`` (+ states that are part
of the lift; pickups are not). ``est.model_dcl`` is the open-loop hybrid model (what
``model.step`` gives).

Output stages of the model without an observer form are applied as known additive
corrections evaluated along the open-loop trajectory (exact for additive signals, a
unit-slope linearisation for filters). Input stages map (Cμ, Cμ_env) as in the model.

Q and R come from data (:func:`tune_observer`) and live in the model file's ``observer``
section; :meth:`Observer.from_model` reads them.

Hot path: :meth:`Observer.step` does no I/O, no logging and allocates no arrays: the
covariance algebra runs in place on preallocated buffers (the very equations of filterpy's
``predict``/``update``, which the tests check), and it returns one preallocated
:class:`Estimate` updated in place.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.special import ndtri

from rtlift.errors import UserError
from rtlift.hybrid import HybridModel
from rtlift.records import Record

FLAG_MISSING = 1
"""No measurement (missing or flagged sample): predict only."""
FLAG_REJECTED = 2
"""Innovation outside the χ² gate: measurement rejected, predict only."""
FLAG_GATE_RELEASED = 4
"""Outside the gate but accepted after ``max_rejections`` consecutive rejections."""

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


def _oscillator(params: dict[str, float], fs_hz: float) -> StateBlock:
    """A periodic disturbance ``A sin(2π f t + φ₀)`` as a rotating 2-state oscillator."""
    w = 2.0 * math.pi * float(params["frequency_hz"]) / fs_hz
    amp = float(params.get("amplitude", 0.01))
    c, s = math.cos(w), math.sin(w)
    return StateBlock("periodic_disturbance", np.array([[c, s], [-s, c]]),
                      np.eye(2) * (1e-3 * amp) ** 2, np.array([1.0, 0.0]), np.eye(2) * amp**2)


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
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("R", "q_x", "q_bias", "p0_bias"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ObserverError(f"observer setting {name} must be a finite number >= 0, got {v!r}")
        if self.R <= 0:
            raise ObserverError(f"observer setting R must be positive, got {self.R!r}")
        if not 0.5 < self.gate_probability <= 1.0:
            raise ObserverError(f"observer gate_probability must be in (0.5, 1], got {self.gate_probability!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "model") -> ObserverConfig:
        if not d or "R" not in d:
            raise ObserverError(f"{source}: the model file has no observer settings (Q and R); "
                                "run rtlift.observer.tune_observer on recorded data and save them "
                                "with save_model(..., observer=...)")
        try:
            return cls(R=float(d["R"]), q_x=float(d["q_x"]), q_bias=float(d["q_bias"]),
                       p0_bias=float(d.get("p0_bias", d["R"])),
                       gate_probability=float(d.get("gate_probability", 0.9999)),
                       max_rejections=int(d.get("max_rejections", 40)),
                       extra={k: v for k, v in d.items() if k not in _CONFIG_KEYS})
        except (KeyError, TypeError, ValueError) as exc:
            raise ObserverError(f"{source}: bad observer settings ({exc})") from None

    def to_dict(self) -> dict[str, Any]:
        return {"version": CONFIG_VERSION, "R": self.R, "q_x": self.q_x, "q_bias": self.q_bias,
                "p0_bias": self.p0_bias, "gate_probability": self.gate_probability,
                "max_rejections": self.max_rejections, **self.extra}


_CONFIG_KEYS = {"R", "q_x", "q_bias", "p0_bias", "gate_probability", "max_rejections"}


class _Structure:
    """The constant matrices of the state assembly (shared by the streaming and batch filters)."""

    def __init__(self, model: HybridModel) -> None:
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
        d = n + 1 + sum(b.size for b in self.blocks)
        self.n, self.d = n, d
        F = np.zeros((d, d))
        F[:n, :n] = A
        F[n, n] = 1.0
        G = np.zeros(d)
        G[:n] = B
        h = np.zeros(d)          # constant part of H (the Wiener part is set per sample)
        h[n] = 1.0
        h_est = np.zeros(d)      # what of ξ beyond x enters ΔĈL
        h_est[n] = 1.0
        Qs = np.zeros((d, d))
        P0s = np.zeros((d, d))
        i = n + 1
        for b in self.blocks:
            j = i + b.size
            F[i:j, i:j] = b.F
            Qs[i:j, i:j] = b.Q
            P0s[i:j, i:j] = b.P0
            h[i:j] = b.h
            if b.in_estimate:
                h_est[i:j] = b.h
            i = j
        cb = float(C @ B)
        scale = abs(cb) if abs(cb) > 1e-12 * (np.linalg.norm(C) * np.linalg.norm(B) + 1e-300) \
            else float(np.linalg.norm(C) * np.linalg.norm(B)) or 1.0
        v = B / scale
        Qx = np.zeros((d, d))
        Qx[:n, :n] = np.outer(v, v)
        Qb = np.zeros((d, d))
        Qb[n, n] = 1.0
        self.F, self.G, self.h, self.h_est, self.C = F, G, h, h_est, C.copy()
        self.Qx, self.Qb, self.Qs, self.P0s = Qx, Qb, Qs, P0s

    def Q(self, cfg: ObserverConfig) -> np.ndarray:
        return cfg.q_x * self.Qx + cfg.q_bias * self.Qb + self.Qs

    def P0(self, cfg: ObserverConfig) -> np.ndarray:
        P = self.P0s.copy()
        P[self.n, self.n] = cfg.p0_bias
        return P


def _copy_model(model: HybridModel) -> HybridModel:
    from rtlift.modelfile import model_from_dict, model_to_dict

    return model_from_dict(model_to_dict(model), allow_unstable=not model.stable)


class Observer:
    """Kalman observer of ΔCL around a :class:`~rtlift.hybrid.HybridModel` (module docstring).

    ``obs = Observer.from_model(model)``; per sample ``est = obs.step(cmu, env, dcl)``
    (``dcl=None`` when missing/flagged). ``obs.kf`` is the filterpy ``KalmanFilter`` that
    holds ``x``, ``P``, ``F``, ``Q``, ``R``, ``H`` and ``B`` (= G); the observer owns a copy of
    the model, whose blocks it steps.
    """

    def __init__(self, model: HybridModel, config: ObserverConfig) -> None:
        self.model = _copy_model(model)
        self.config = config
        st = _Structure(self.model)
        self.structure = st
        kf = KalmanFilter(dim_x=st.d, dim_z=1, dim_u=1)
        kf.F = st.F.copy()
        kf.B = st.G.reshape(-1, 1).copy()
        kf.Q = st.Q(config)
        kf.R = np.array([[config.R]])
        kf.H = st.h.reshape(1, -1).copy()
        self.kf = kf
        self.gate = chi2_1_quantile(config.gate_probability)
        d, n = st.d, st.n
        # preallocated work buffers (the hot path allocates no arrays)
        self._x = np.zeros(d)
        self._P = np.zeros((d, d))
        self._H = st.h.copy()
        self._Hx = self._H[:n]
        self._xw = self._x[:n]
        self._FT = st.F.T.copy()
        self._I = np.eye(d)
        self._t = np.zeros(d)
        self._PH = np.zeros(d)
        self._K = np.zeros(d)
        self._Kc = self._K.reshape(d, 1)        # views for outer products without np.outer's overhead
        self._Kr = self._K.reshape(1, d)
        self._Hr = self._H.reshape(1, d)
        self._F = st.F
        self._G = st.G
        self._T = np.zeros((d, d))
        self._M = np.zeros((d, d))
        self._MT = self._M.T
        self._R = float(config.R)
        self._Q = kf.Q
        m = self.model
        self._input_stages = tuple(m.input_stages)
        self._output_stages = tuple(zip(m.output_stages, st.replaced, strict=True))
        self._conv_step = m.convolution.step
        self._hp_step = m.highpass.step
        self._wiener_ol = m.wiener
        self._nl = m.wiener.nonlinearity
        self._C = st.C
        self._input_gain = st.form == "input_gain"
        self.estimate = Estimate()
        self.reset()

    @classmethod
    def from_model(cls, model: HybridModel) -> Observer:
        """The observer with the Q and R stored in the model file (``model.observer_config``)."""
        return cls(model, ObserverConfig.from_dict(model.observer_config))

    # -- state ------------------------------------------------------------------------
    def reset(self) -> None:
        """Model at rest, ξ = 0, P = P₀, monitors cleared."""
        self.model.reset()
        self._x[:] = 0.0
        self._P[:] = self.structure.P0(self.config)
        self._sync_kf()
        self._rejected_run = 0
        self.updates = 0
        self.rejected = 0
        self.missing = 0
        self._nis_sum = 0.0
        self._nis_in_band = 0
        e = self.estimate
        e.dcl = e.model_dcl = e.bias = 0.0
        e.innovation = e.nis = math.nan
        e.flags = 0
        e.sample = 0

    def _sync_kf(self) -> None:
        self.kf.x = self._x
        self.kf.P = self._P

    def get_state(self) -> np.ndarray:
        """[model state, ξ, P (row-major), consecutive rejections, steps] — a copy."""
        return np.concatenate([self.model.get_state(), self._x, self._P.ravel(),
                               [float(self._rejected_run), float(self.estimate.sample)]])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        ms, d = self.model.state_size, self.structure.d
        if s.shape != (ms + d + d * d + 2,):
            raise ValueError(f"observer state must have shape ({ms + d + d * d + 2},), got {s.shape}")
        self.model.set_state(s[:ms])
        self._x[:] = s[ms:ms + d]
        self._P[:] = s[ms + d:ms + d + d * d].reshape(d, d)
        self._rejected_run = int(s[-2])
        self.estimate.sample = int(s[-1])

    # -- monitors ---------------------------------------------------------------------
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
                "nis_mean": self.nis_mean, "nis_band_fraction": self.nis_band_fraction}

    # -- the 400 Hz step --------------------------------------------------------------
    def step(self, cmu: float, env: float, dcl: float | None) -> Estimate:
        """One sample: Cμ(k), Cμ_env(k) and the measured ΔCL(k) (``None``, NaN or ±inf: predict only).

        Returns the observer's preallocated :class:`Estimate`, updated in place.
        """
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

        x, P, t, T = self._x, self._P, self._t, self._T
        # predict: ξ⁻ = F ξ + G u,  P⁻ = F P Fᵀ + Q
        F = self._F
        np.dot(F, x, out=t)
        np.multiply(self._G, env, out=x)
        x += t
        np.dot(F, P, out=T)
        np.dot(T, self._FT, out=P)
        P += self._Q
        # measurement row H(k) and prediction ẑ⁻
        nl = self._nl
        if self._input_gain:
            g = nl.gain_at(env)
            c = 0.0
        else:
            y = float(self._C.dot(self._xw))
            g = nl.slope_at(y)
            c = nl.step(env, y) - g * y
        H = self._H
        np.multiply(self._C, g, out=self._Hx)
        zhat = known + c + float(H.dot(x))

        flags = 0
        if dcl is None or not -math.inf < dcl < math.inf:  # NaN/inf would poison ξ and P for good
            flags = FLAG_MISSING
            self.missing += 1
            est.innovation = math.nan
            est.nis = math.nan
        else:
            nu = dcl - zhat
            PH = self._PH
            np.dot(P, H, out=PH)
            S = float(H.dot(PH)) + self._R
            nis = nu * nu / S
            est.innovation = nu
            est.nis = nis
            if nis > self.gate and self._rejected_run < self.config.max_rejections:
                flags = FLAG_REJECTED
                self.rejected += 1
                self._rejected_run += 1
            else:
                if nis > self.gate:
                    flags = FLAG_GATE_RELEASED
                self._rejected_run = 0
                self.updates += 1
                self._nis_sum += nis
                if NIS_BAND[0] <= nis <= NIS_BAND[1]:
                    self._nis_in_band += 1
                # update (Joseph form): ξ = ξ⁻ + K ν, P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ
                K, M = self._K, self._M
                np.multiply(PH, 1.0 / S, out=K)
                np.multiply(K, nu, out=t)
                x += t
                np.multiply(self._Kc, self._Hr, out=M)
                np.subtract(self._I, M, out=M)
                np.dot(M, P, out=T)
                np.dot(T, self._MT, out=P)
                np.multiply(self._Kc, self._Kr, out=T)
                T *= self._R
                P += T
        est.flags = flags
        est.bias = float(x[self.structure.n])
        est.dcl = known + nl.step(env, float(self._C.dot(self._xw))) + float(self.structure.h_est.dot(x))
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
    and the open-loop model — computed by the model's own batch twins from rest."""
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
    return {"known": known, "u": np.asarray(env, dtype=float), "model": total}


def batch_nis(model: HybridModel, record: Record, configs: Sequence[ObserverConfig],
              skip: int = 0) -> dict[str, np.ndarray]:
    """Run the observer of :meth:`Observer.step` for several configs at once over a record
    (vectorised across configs) and return per config: ``nis_mean``, ``nis_band_fraction``,
    ``nll`` (mean negative log-likelihood of the innovations, up to a constant), ``rejected``.
    Samples before ``skip`` are filtered but not scored."""
    st = _Structure(_copy_model(model))
    data = _known_inputs(model, record)
    known, u, z = data["known"], data["u"], record.dcl
    M, d, n = len(configs), st.d, st.n
    F, G, FT, C = st.F, st.G, st.F.T, st.C
    Q = np.stack([st.Q(c) for c in configs])
    R = np.array([c.R for c in configs])
    gates = np.array([chi2_1_quantile(c.gate_probability) for c in configs])
    max_rej = np.array([c.max_rejections for c in configs])
    x = np.zeros((M, d))
    P = np.stack([st.P0(c) for c in configs])
    nl = model.wiener.nonlinearity
    input_gain = st.form == "input_gain"
    gains = nl.simulate(u, np.ones_like(u)) if input_gain else None
    nis_sum = np.zeros(M)
    in_band = np.zeros(M)
    nll = np.zeros(M)
    count = np.zeros(M)
    rejected = np.zeros(M)
    run = np.zeros(M)
    eye = np.eye(d)
    H = np.tile(st.h, (M, 1))
    for k in range(len(z)):
        x = x @ FT + G * u[k]
        P = F @ P @ FT + Q
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
        reject = (nis > gates) & (run < max_rej)
        accept = ~reject
        run = np.where(reject, run + 1, 0)
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


def tune_observer(model: HybridModel, records: Sequence[Record], *, tare_seconds: float = 2.0,
                  max_seconds: float = 60.0, skip_seconds: float = 2.0,
                  gate_probability: float = 0.9999) -> dict[str, Any]:
    """Q and R from data, for ``save_model(..., observer=tune_observer(model, records))``.

    - R: variance of ΔCL over the actuator-off tare seconds at the start of each record
      (pooled); if no record has them, half the variance of the first difference of the
      open-loop residual (its white, high-frequency part).
    - Q: ``q_x`` and ``q_bias`` by maximum likelihood of the innovations on a log grid
      (relative to R), then one common scale chosen so that the mean NIS is closest to 1.
      At most ``max_seconds`` of each record are used; the first ``skip_seconds`` are not
      scored.
    """
    if not records:
        raise ValueError("tune_observer needs at least one record")
    fs = model.fs_hz
    recs = [r.slice(0, int(round(max_seconds * fs))) for r in records]
    quiet = [actuator_off_noise(r, tare_seconds) for r in recs]
    pooled = np.concatenate(quiet)
    if pooled.size >= 20:
        R = float(np.mean(pooled**2))
        r_source = f"actuator-off tare ({pooled.size} samples in the first {tare_seconds:g} s)"
    else:
        res = np.concatenate([r.dcl - _known_inputs(model, r)["model"] for r in recs])
        R = float(np.var(np.diff(res)) / 2.0)
        r_source = "half the variance of the first difference of the open-loop residual"
    if not R > 0:
        raise ValueError("measurement noise variance is zero: cannot tune the observer")
    st = _Structure(_copy_model(model))
    u = np.concatenate([_known_inputs(model, r)["u"] for r in recs])
    nl = model.wiener.nonlinearity
    if st.form == "input_gain":
        g_ref = float(np.mean(np.abs(nl.simulate(u, np.ones_like(u))))) or 1.0
    else:
        g_ref = float(np.mean(np.abs(np.diff(nl.f) / np.diff(nl.y)))) or 1.0
    skip = int(round(skip_seconds * fs))

    def score(cfgs: list[ObserverConfig]) -> dict[str, np.ndarray]:
        parts = [batch_nis(model, r, cfgs, skip=min(skip, len(r) // 4)) for r in recs]
        w = np.array([p["updates"] for p in parts])
        tot = w.sum(axis=0)
        return {k: (np.sum([p[k] * p["updates"] for p in parts], axis=0) / tot
                    if k != "rejected" else np.sum([p[k] for p in parts], axis=0))
                for k in ("nis_mean", "nis_band_fraction", "nll", "rejected")}

    def cfg(qx: float, qb: float) -> ObserverConfig:
        return ObserverConfig(R=R, q_x=qx, q_bias=qb, p0_bias=R, gate_probability=gate_probability)

    qx_grid = [0.0, *(R / g_ref**2 * f for f in (1e-4, 1e-3, 1e-2, 1e-1))]
    qb_grid = [R * f for f in (1e-6, 1e-5, 1e-4, 1e-3, 1e-2)]
    grid = [(qx, qb) for qx in qx_grid for qb in qb_grid]
    s1 = score([cfg(qx, qb) for qx, qb in grid])
    qx, qb = grid[int(np.argmin(s1["nll"]))]
    scales = (0.25, 0.5, 0.71, 1.0, 1.41, 2.0, 4.0)
    s2 = score([cfg(qx * f, qb * f) for f in scales])
    i = int(np.argmin(np.abs(np.log(s2["nis_mean"]))))
    best = cfg(qx * scales[i], qb * scales[i])
    out = best.to_dict()
    out.update({
        "method": "R from actuator-off noise; q_x, q_bias by innovation maximum likelihood on a "
                  "log grid, then a common scale for mean NIS closest to 1",
        "r_source": r_source,
        "tuned_on": [r.name for r in records],
        "nis_mean": float(s2["nis_mean"][i]),
        "nis_band_fraction": float(s2["nis_band_fraction"][i]),
        "rejected": int(s2["rejected"][i]),
        "measurement_noise_std": math.sqrt(R),
    })
    return out
