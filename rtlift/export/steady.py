"""The Python observers an exported module must equal (:func:`reference_observer`): the observer
itself for ``--gain full``, and the steady-gain observer, the judge of ``--gain steady``.

The model's step is the compiled one the observer binds (:func:`rtlift.blocks.compiled.hybrid_sample`
or :func:`rtlift.blocks.compiled_interaction.interaction_sample`, on copies of its arrays); the
filter is :mod:`rtlift.export.filter_spec`'s steady form,

    ξ⁻ = F ξ + G u,   ẑ⁻ = ΔCL_H + d + c + H(k) ξ⁻,   ν = z − ẑ⁻,   NIS = ν²/S,   ξ = ξ⁻ + K ν

with the χ² gate, the missing-sample and bad-input rules of :mod:`rtlift.observer`, and the
estimate ΔĈL = ΔCL_H + d + N(u) C x (or f(C x)) + h_liftᵀ ξ.
"""

from __future__ import annotations

import math

import numpy as np

from rtlift.blocks.compiled import hybrid_sample
from rtlift.blocks.compiled_interaction import interaction_sample
from rtlift.export.filter_spec import MODEL_ARGUMENTS, FilterSpec, bound_observer, kernel_arrays
from rtlift.model.hybrid import HybridModel
from rtlift.observer import Observer, ObserverConfig
from rtlift.observer.config import (
    FLAG_BAD_INPUT,
    FLAG_GATE_RELEASED,
    FLAG_MISSING,
    FLAG_REJECTED,
    GATE_LEAK,
)
from rtlift.observer.layout import wiener_gain


class SteadyGainObserver:
    """``step(cmu, env, dcl)`` → (ΔĈL, open-loop ΔCL, ν, NIS, flags), ``dcl`` NaN when missing,
    from rest. ``obs`` is the observer whose model and settings it takes: its model's state
    arrays are the ones this steps (give it an observer of its own, fresh)."""

    def __init__(self, obs: Observer, spec: FilterSpec) -> None:
        if spec.full:
            raise ValueError("SteadyGainObserver needs a steady-gain FilterSpec")
        interaction, args = kernel_arrays(obs)
        self._sample = interaction_sample if interaction else hybrid_sample
        self._margs = tuple(args[name] for name in MODEL_ARGUMENTS[interaction])
        self.spec = spec
        nl = obs.model.wiener.nonlinearity
        self._gain = wiener_gain(nl) if obs.layout.form == "input_gain" else None
        self._nl = nl
        self._C = obs.layout.C.copy()
        self.xi = np.zeros(spec.dim_x)
        self.last = (0.0, 0.0)
        self.rejected_run = 0.0
        self.gate_open = False

    def step(self, cmu: float, env: float, dcl: float) -> tuple[float, float, float, float, int]:
        sp, xi, n = self.spec, self.xi, self.spec.n_wiener
        flags = 0
        if math.isfinite(cmu) and math.isfinite(env):
            self.last = (cmu, env)
        else:
            (cmu, env), dcl, flags = self.last, math.nan, FLAG_BAD_INPUT
        total, high, _, cmu, env, corrections = self._sample(cmu, env, *self._margs)
        known = high + corrections
        xi[:] = sp.F @ xi + env * sp.G
        if self._gain is not None:
            g = self._gain(env)
            c0 = 0.0
        else:
            y = float(self._C @ xi[:n])
            g = self._nl.slope_at(y)
            c0 = self._nl.output_at(env, y) - g * y
        H = sp.h_fixed.copy()
        H[:n] = g * self._C
        zhat = known + c0 + float(H @ xi)
        nu = nis = math.nan
        if not math.isfinite(dcl):
            flags |= FLAG_MISSING
        else:
            nu = dcl - zhat
            nis = nu * nu / sp.S
            if nis > sp.gate and not self.gate_open and self.rejected_run < sp.max_rejections:
                flags |= FLAG_REJECTED
                self.rejected_run += 1
            else:
                if nis > sp.gate:
                    flags |= FLAG_GATE_RELEASED
                    self.gate_open = True
                    self.rejected_run = float(sp.max_rejections)
                elif self.rejected_run:
                    self.rejected_run = max(self.rejected_run - GATE_LEAK, 0.0)
                    self.gate_open = self.gate_open and self.rejected_run > 0
                xi += sp.K * nu
        y = float(self._C @ xi[:n])
        wiener = g * y if self._gain is not None else self._nl.output_at(env, y)
        return known + wiener + float(sp.h_lift @ xi), total, nu, nis, flags

    def run(self, cmu: np.ndarray, env: np.ndarray, dcl: np.ndarray) -> np.ndarray:
        """Rows (ΔĈL, open loop, ν, NIS, flags) over arrays (NaN in ``dcl``: missing)."""
        return np.array([self.step(c, e, z) for c, e, z in zip(np.asarray(cmu, float).tolist(),
                                                                 np.asarray(env, float).tolist(),
                                                                 np.asarray(dcl, float).tolist(), strict=True)])


def reference_observer(model: HybridModel, config: ObserverConfig | None, spec: FilterSpec):
    """A fresh Python observer that the module must equal: :class:`~rtlift.observer.Observer`
    (``--gain full``) or :class:`SteadyGainObserver` (steady); ``step(cmu,
    env, dcl)`` returns (ΔĈL, open loop, ν, NIS, flags) either way."""
    obs = bound_observer(model, config)
    if spec.full:
        return _FullReference(obs)
    return SteadyGainObserver(obs, spec)


class _FullReference:
    """:class:`Observer` with the step's tuple (ν and NIS NaN when missing)."""

    def __init__(self, obs: Observer) -> None:
        self.obs = obs

    def step(self, cmu: float, env: float, dcl: float) -> tuple[float, float, float, float, int]:
        return self.obs.step(cmu, env, dcl).as_tuple()
