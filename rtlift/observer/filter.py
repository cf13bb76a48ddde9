"""The filter: :class:`Observer` (the 400 Hz step) and its :class:`Estimate` (equations in
:mod:`rtlift.observer`)."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from scipy.linalg import blas

from rtlift.blocks.compiled import hybrid_step
from rtlift.blocks.compiled_interaction import interaction_step
from rtlift.blocks.compiled_stages import output_flags
from rtlift.model.hybrid import HybridModel
from rtlift.observer import compiled as cs
from rtlift.observer import compiled_at
from rtlift.observer.config import (
    FLAG_BAD_INPUT,
    FLAG_GATE_RELEASED,
    FLAG_MISSING,
    FLAG_REJECTED,
    GATE_LEAK,
    NIS_BAND,
    ObserverConfig,
    ObserverError,
    chi2_1_quantile,
)
from rtlift.observer.layout import StateLayout, wiener_gain


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


class Observer:
    """Kalman observer of ΔCL around a :class:`~rtlift.model.hybrid.HybridModel` (:mod:`rtlift.observer`).

    ``obs = Observer.from_model(model)``; per sample ``est = obs.step(cmu, env, dcl)``
    (``dcl=None`` when missing/flagged). ``obs.kf`` is the filterpy ``KalmanFilter`` that
    holds ``x`` (= ξ), ``P``, ``F``, ``Q``, ``R``, ``H`` and ``B`` (= G); the step updates its
    ``x`` and ``P`` arrays in place. ``obs.layout`` (:class:`StateLayout`) says where each
    block of ξ sits. The observer owns a copy of the model (``obs.model``).

    :meth:`step` is one compiled call (:mod:`rtlift.observer.compiled`) when the model's own
    step is compiled (``model.compiled``), else :meth:`reference_step`, the same filter in
    numpy and BLAS that is also the compiled step's test oracle; ``obs.compiled`` says which.
    Both advance the same arrays. :meth:`warm_up` compiles before a live link opens.
    """

    def __init__(self, model: HybridModel, config: ObserverConfig) -> None:
        self.model = model.copy()
        self.config = config
        lay = StateLayout(self.model, config.ripple_harmonics, config.noise_ar, config.ripple_powers,
                          config.q_gain_h > 0)
        self.layout = lay
        d, n = lay.dim_x, lay.n_wiener
        self._Q = lay.Q(config)
        self._kf = None                         # filterpy's KalmanFilter over these arrays, built by :attr:`kf`
        self.gate = chi2_1_quantile(config.gate_probability)
        # the state, preallocated: ξ, P, the row H(k), the scalar state (gate, phase, counters)
        self._xi = np.zeros(d)
        self._P = np.zeros((d, d))
        self._H = lay.h_fixed.copy()
        self._s = np.zeros(cs.SCALAR_STATE_SIZE)
        self.phase = lay.phase(self._s[cs.PHASE:cs.PHASE + 3])
        # views and scratch of the reference step
        self._PT = self._P.T                    # Fortran-ordered view for BLAS dger (P is symmetric)
        self._P_flat = self._P.reshape(-1)
        self._Q_flat = np.ascontiguousarray(self._Q).reshape(-1)
        self._FT = lay.F.T.copy()
        self._xi_wiener = self._xi[:n]
        self._xi_ripple = self._xi[lay.ripple_start:]
        self._H_ripple = self._H[lay.ripple_start:]
        nb = 2 * lay.harmonics
        self._H_ripple_powers = [self._H_ripple[i * nb:(i + 1) * nb] for i in range(lay.powers)]
        self._FP = np.zeros((d, d))             # F P
        self._F_xi = np.zeros(d)                # F ξ
        self._PHt = np.zeros(d)                 # P⁻Hᵀ, then w = P⁻Hᵀ/√S
        self._C_list = [float(c) for c in lay.C]
        self._nl = self.model.wiener.nonlinearity
        self._gain = wiener_gain(self._nl) if lay.form == "input_gain" else None
        self._output_stages = tuple(zip(self.model.output_stages, lay.replaced, strict=True))
        self._ddot, self._daxpy, self._dcopy, self._dscal, self._dger = (
            blas.ddot, blas.daxpy, blas.dcopy, blas.dscal, blas.dger)
        self._check_in_place()
        self._kernel = self._bind_kernel()
        # the same compiled step with its arrays bound by address (one argument: compiled_at)
        self._at = compiled_at.bind(*self._kernel[:2]) if self._kernel else ()
        self.estimate = Estimate()
        self.reset()

    def _check_in_place(self) -> None:
        """The BLAS wrappers write into the buffers they are given only when dtype and layout
        match; check once that they do (a silent copy would leave the state unchanged)."""
        d = self.layout.dim_x
        P = np.eye(d)
        t = np.ones(d)
        ok = (self._dger(-1.0, t, t, a=P.T, overwrite_a=1).base is P
              and self._daxpy(t, self._F_xi, a=0.0) is self._F_xi
              and self._dscal(1.0, self._F_xi) is self._F_xi
              and self._dcopy(self._F_xi, self._PHt) is self._PHt
              and self._daxpy(self._Q_flat, P.reshape(-1), a=0.0).base is P)
        if not ok:   # pragma: no cover - a BLAS build that copies
            raise ObserverError("observer: BLAS wrappers do not update buffers in place")

    def _bind_kernel(self) -> tuple:
        """(compiled step, its arguments after Cμ, Cμ_env, ΔCL, its :meth:`touch`), or () for the
        reference step."""
        kernel = self.model._bind_kernel()
        if not kernel:
            return ()
        lay = self.layout
        if kernel[0] is hybrid_step:
            # the model's arguments, its parameters (the first) with the observer's flags on the output
            # stages: a stage's correction counts toward the known part of ẑ unless states of ξ stand for it
            step, touch = cs.observer_step, cs.observer_touch
        elif kernel[0] is interaction_step:
            step, touch = cs.observer_step_interaction, cs.observer_touch_interaction
        else:  # pragma: no cover - every compiled model step is one of the two
            return ()
        model_args = (output_flags(kernel[1][0], [not r for r in lay.replaced]), *kernel[1][1:])
        ipar, fpar = cs.pack_layout(lay, self.config.R, self.gate, self.config.max_rejections)
        d = lay.dim_x
        tab = np.zeros((max(lay.max_period, 1) if lay.harmonics else 1, max(2 * lay.harmonics, 1)))
        args = (*model_args, ipar, fpar, np.ascontiguousarray(self._Q), self._xi, self._P, self._H,
                np.zeros((d, d)), np.zeros(2 * d), tab, self._s)
        return step, args, touch

    @property
    def kf(self) -> Any:
        """filterpy's ``KalmanFilter`` holding this observer's arrays: ``x`` is ξ and ``P`` its
        covariance (the very arrays the step updates in place), ``Q``, ``H`` the step's own, ``F``,
        ``B`` (= G) and ``R`` copies. Built on first use: importing filterpy imports scipy.stats,
        about a second of a live start that the step itself never needs."""
        if self._kf is None:
            from filterpy.kalman import KalmanFilter

            lay = self.layout
            kf = KalmanFilter(dim_x=lay.dim_x, dim_z=1, dim_u=1)
            kf.F = lay.F.copy()
            kf.B = lay.G.reshape(-1, 1).copy()
            kf.Q = self._Q
            kf.R = np.array([[self.config.R]])
            kf.x, kf.P, kf.H = self._xi, self._P, self._H.reshape(1, -1)
            self._kf = kf
        return self._kf

    @property
    def compiled(self) -> bool:
        """True when :meth:`step` is the compiled step (the model's step is compiled)."""
        return bool(self._kernel)

    def warm_up(self) -> float:
        """Compile the step (or load it from numba's cache) now, not on the first live sample;
        the state is untouched. Returns the seconds taken (≈ 0 for the reference step)."""
        t0 = time.perf_counter()
        if self._kernel:
            fn, args, _ = self._kernel
            fn(0.0, 0.0, 0.0, *(a.copy() if isinstance(a, np.ndarray) else a for a in args))
            compiled_at.warm_up(fn, args)
        return time.perf_counter() - t0

    def touch(self) -> None:
        """Bring the compiled step's working set into the cache without changing anything
        (:func:`.compiled.observer_touch`); a no-op for the reference step. For a loop that
        spins between samples (``link.on_idle``): the step then runs at its tight-loop cost."""
        if self._kernel:
            _, args, touch = self._kernel
            touch(*args)

    @classmethod
    def from_model(cls, model: HybridModel) -> Observer:
        """The observer with the Q and R stored in the model file (``model.observer_config``)."""
        return cls(model, ObserverConfig.from_dict(model.observer_config))

    # -- state ------------------------------------------------------------------------
    def reset(self) -> None:
        """Model at rest, ξ = 0, P = P₀, burst phase unknown, monitors cleared."""
        self.model.reset()
        self._xi[:] = 0.0
        self._P[:] = self.layout.P0(self.config)
        self._H[:] = self.layout.h_fixed
        self._s[:] = 0.0
        self.phase.reset()
        e = self.estimate
        e.dcl = e.model_dcl = e.bias = 0.0
        e.innovation = e.nis = math.nan
        e.flags = 0
        e.sample = 0

    def get_state(self) -> np.ndarray:
        """[model state, ξ, P (row-major), H's ripple part, burst phase (3), the last finite Cμ
        and Cμ_env (held for a bad input), outlier count, gate open, steps] — a copy."""
        s = self._s
        return np.concatenate([self.model.get_state(), self._xi, self._P.ravel(), self._H_ripple,
                               self.phase.get_state(), [s[cs.LAST_CMU], s[cs.LAST_ENV]],
                               [s[cs.REJECTED_RUN], s[cs.GATE_OPEN], float(self.estimate.sample)]])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        ms, d, nr = self.model.state_size, self.layout.dim_x, self._H_ripple.size
        size = ms + d + d * d + nr + 3 + 2 + 3
        if s.shape != (size,):
            raise ValueError(f"observer state must have shape ({size},), got {s.shape}")
        self.model.set_state(s[:ms])
        i = ms
        self._xi[:] = s[i:i + d]
        i += d
        self._P[:] = s[i:i + d * d].reshape(d, d)
        i += d * d
        self._H_ripple[:] = s[i:i + nr]
        self._s[cs.RIPPLE_ON] = float(np.any(self._H_ripple))
        i += nr
        self.phase.set_state(s[i:i + 3])
        i += 3
        self._s[cs.LAST_CMU], self._s[cs.LAST_ENV] = s[i], s[i + 1]
        self._s[cs.REJECTED_RUN] = s[-3]
        self._s[cs.GATE_OPEN] = float(bool(s[-2]))
        self._s[cs.SAMPLE] = s[-1]
        self.estimate.sample = int(s[-1])

    # -- monitors ---------------------------------------------------------------------
    def clear_monitors(self) -> None:
        """Zero the counters and NIS/likelihood sums (the state is kept)."""
        self._s[cs.UPDATES:cs.NLL_SUM + 1] = 0.0

    updates = property(lambda self: int(self._s[cs.UPDATES]), doc="Accepted measurement updates.")
    rejected = property(lambda self: int(self._s[cs.REJECTED]), doc="Measurements rejected by the χ² gate.")
    missing = property(lambda self: int(self._s[cs.MISSING]), doc="Samples without a measurement.")
    bad_inputs = property(lambda self: int(self._s[cs.BAD_INPUTS]), doc="Samples with a non-finite Cμ or Cμ_env.")

    @property
    def nll(self) -> float:
        """Mean negative log-likelihood of the accepted innovations, ``mean(ln S + ν²/S)``
        (up to a constant): what :func:`~rtlift.observer.tune_observer` minimises."""
        return float(self._s[cs.NLL_SUM]) / self.updates if self.updates else math.nan

    @property
    def nis_mean(self) -> float:
        """Running mean of the NIS of accepted updates (≈ 1 for a consistent filter)."""
        return float(self._s[cs.NIS_SUM]) / self.updates if self.updates else math.nan

    @property
    def nis_band_fraction(self) -> float:
        """Fraction of accepted NIS values inside the 95 % χ²₁ band (≈ 0.95 if consistent)."""
        return float(self._s[cs.NIS_IN_BAND]) / self.updates if self.updates else math.nan

    def monitors(self) -> dict[str, float | int]:
        return {"updates": self.updates, "rejected": self.rejected, "missing": self.missing,
                "bad_inputs": self.bad_inputs,
                "nis_mean": self.nis_mean, "nis_band_fraction": self.nis_band_fraction}

    # -- the 400 Hz step --------------------------------------------------------------
    def step(self, cmu: float, env: float, dcl: float | None) -> Estimate:
        """One sample: Cμ(k), Cμ_env(k) and the measured ΔCL(k) (``None``, NaN or ±inf: predict only).

        Returns the observer's preallocated :class:`Estimate`, updated in place. A non-finite
        Cμ or Cμ_env would poison the model's state for good: the last finite inputs are held
        instead and the sample is predict-only (``FLAG_BAD_INPUT``). Compiled when
        :attr:`compiled`, else :meth:`reference_step`.
        """
        kernel = self._at or self._kernel      # the arrays by address (compiled_at), else one by one
        if not kernel:
            return self.reference_step(cmu, env, dcl)
        fn, args, _ = kernel
        est = self.estimate
        est.dcl, est.model_dcl, est.innovation, est.nis, est.flags, est.bias = fn(
            float(cmu), float(env), math.nan if dcl is None else float(dcl), *args)
        est.sample += 1
        return est

    def reference_step(self, cmu: float, env: float, dcl: float | None) -> Estimate:
        """:meth:`step` in numpy and BLAS, block by block (the compiled step's oracle).

        It steps the model's blocks itself rather than calling ``model.step``: it needs the
        inputs after the input stages (for G u and the burst phase) and the part of the output
        stages' correction it does not carry as states, which ``model.step`` does not return.
        """
        s = self._s
        bad_input = 0
        if -math.inf < cmu < math.inf and -math.inf < env < math.inf:
            s[cs.LAST_CMU] = cmu
            s[cs.LAST_ENV] = env
        else:
            cmu, env, dcl = float(s[cs.LAST_CMU]), float(s[cs.LAST_ENV]), None
            bad_input = FLAG_BAD_INPUT
            s[cs.BAD_INPUTS] += 1
        m = self.model
        for stage in m.input_stages:
            cmu, env = stage.step(cmu, env)
        high, low = m.parts_step(cmu, env)
        known = high
        total = high + low
        for stage, replaced in self._output_stages:
            before = total
            total = stage.step(total)
            if not replaced:
                known += total - before
        est = self.estimate
        est.model_dcl = total
        est.sample += 1
        s[cs.SAMPLE] += 1

        lay = self.layout
        xi, P, H, PHt = self._xi, self._P, self._H, self._PHt
        ddot, daxpy = self._ddot, self._daxpy
        # predict (filterpy's predict): ξ⁻ = F ξ + G u,  P⁻ = F P Fᵀ + Q
        np.dot(lay.F, xi, out=self._F_xi)
        self._dcopy(self._F_xi, xi)
        daxpy(lay.G, xi, a=env)
        np.dot(lay.F, P, out=self._FP)
        np.dot(self._FP, self._FT, out=P)
        daxpy(self._Q_flat, self._P_flat)
        # measurement row H(k) and prediction ẑ⁻
        if self._gain is not None:
            g = self._gain(env)
            c = 0.0
        else:
            y = ddot(lay.C, self._xi_wiener)
            g = self._nl.slope_at(y)
            c = self._nl.output_at(env, y) - g * y
        for i, ci in enumerate(self._C_list):
            H[i] = g * ci
        ig = lay.gain_h
        if ig >= 0:
            H[ig] = high
        if lay.harmonics:
            row = self.phase.step(cmu)
            if row is not None:
                w = env
                for part in self._H_ripple_powers:   # r-row = [w_p · basis]_p, w_p = Cμ_env (Cμ_env/Cμ_ref)^(p−1)
                    self._dcopy(row, part)
                    self._dscal(w, part)
                    w = w * env / lay.cmu_ref
                s[cs.RIPPLE_ON] = 1.0
            elif s[cs.RIPPLE_ON]:
                self._dscal(0.0, self._H_ripple)
                s[cs.RIPPLE_ON] = 0.0
        zhat = known + c + ddot(H, xi)

        flags = 0
        if dcl is None or not -math.inf < dcl < math.inf:  # NaN/inf would poison ξ and P for good
            flags = FLAG_MISSING
            s[cs.MISSING] += 1
            est.innovation = math.nan
            est.nis = math.nan
        else:
            nu = dcl - zhat
            np.dot(P, H, out=PHt)
            S = ddot(H, PHt) + self.config.R
            nis = nu * nu / S
            est.innovation = nu
            est.nis = nis
            outside = nis > self.gate
            max_rej = self.config.max_rejections
            if outside and not s[cs.GATE_OPEN] and s[cs.REJECTED_RUN] < max_rej:
                flags = FLAG_REJECTED
                s[cs.REJECTED] += 1
                s[cs.REJECTED_RUN] += 1
            else:
                if outside:         # released: stays open until as many samples fell inside
                    flags = FLAG_GATE_RELEASED
                    s[cs.GATE_OPEN] = 1.0
                    s[cs.REJECTED_RUN] = max_rej
                elif s[cs.REJECTED_RUN]:
                    s[cs.REJECTED_RUN] = max(s[cs.REJECTED_RUN] - GATE_LEAK, 0.0)
                    s[cs.GATE_OPEN] = float(bool(s[cs.GATE_OPEN]) and s[cs.REJECTED_RUN] > 0)
                s[cs.UPDATES] += 1
                s[cs.NIS_SUM] += nis
                s[cs.NLL_SUM] += math.log(S) + nis
                if NIS_BAND[0] <= nis <= NIS_BAND[1]:
                    s[cs.NIS_IN_BAND] += 1
                # update: ξ = ξ⁻ + K ν with K = P⁻Hᵀ/S; Joseph form with this K: P = P⁻ − w wᵀ, w = P⁻Hᵀ/√S
                daxpy(PHt, xi, a=nu / S)
                self._dscal(1.0 / math.sqrt(S), PHt)
                self._dger(-1.0, PHt, PHt, a=self._PT, overwrite_a=1)
        est.flags = flags | bad_input
        est.bias = float(xi[lay.bias])
        y = ddot(lay.C, self._xi_wiener)
        wiener = g * y if self._gain is not None else self._nl.output_at(env, y)
        est.dcl = known + wiener + ddot(lay.h_lift, xi) + (
            ddot(self._H_ripple, self._xi_ripple) if s[cs.RIPPLE_ON] else 0.0)
        if ig >= 0:
            est.dcl += high * xi[ig]
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
