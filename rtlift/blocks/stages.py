"""Every augmentation stage by name (:data:`STAGES`), as a model file lists it, and
:func:`stage_from_spec`, which rebuilds one from its entry. The interface the stages implement is
:mod:`rtlift.blocks.stage_base`; each stage lives in a module of its own, and the table is derived
from the stage classes of this package (every :class:`~rtlift.blocks.stage_base.InputStage` subclass
with a ``name``: the model file's key, which the effect of :mod:`rtlift.effects` that adds the
stage takes as its own).

Catalog (``name``: equation; k = 0 is the first sample after ``reset()``, t_k = k / fs):

- ``delay`` (input): Cμ′(k) = Cμ(k − D), D = round(seconds · fs).
- ``actuator_fade`` (input): g(k) = f + (1 − f) exp(−E(k)/τ), Cμ′ = g Cμ, Cμ_env′ = g Cμ_env,
  E(k) the burst on-time (s) accumulated *before* sample k (E += 1/fs while Cμ(k) > 0), or
  the wall time (``clock`` "time").
- ``delivered_momentum`` (input, part of the ``interaction`` structure as first merged, not an
  effect): Cμ_env′(k) = m(k) = λ m(k−1) + (1 − λ) Cμ(k)/d, λ = exp(−1/(τ fs)); Cμ′ = Cμ.
- ``delivered_envelope`` (input, the ``interaction`` structure's Wiener input, not an effect):
  Cμ_env′(k) = Cμ_env(k) · min(1, q(k)/q₀), q(k) = λ q(k−1) + (1 − λ) [Cμ(k) > 0], q₀ the
  minimum of q at the lift-optimal burst rate; Cμ′ = Cμ.
- ``sensor_resonance`` (output, kind "filter"): the unity-DC-gain mode
  ω²/(s² + 2ζωs + ω²), bilinear with pre-warping at ω (as on the bench).
- ``zero_drift`` (output, kind "additive"): d(k) = offset + rate · t_k, or
  d(k) = offset + amplitude (1 − exp(−t_k/τ)); ``offset`` is the tare's share of the drift.
- ``periodic_disturbance`` (output, kind "additive"): d(k) = Σ_i A_i sin(2π f_i t_k + φ_i), a
  fundamental and its harmonics as sampled (aliased).

The static-gain effects live in the Wiener nonlinearity instead (they need Cμ(k) and y(k)
together): ``hysteresis`` is :class:`rtlift.blocks.wiener.HysteresisGain`,
``output_nonlinearity`` is :class:`rtlift.blocks.wiener.OutputNonlinearity`.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any

import rtlift.blocks
from rtlift.blocks.stage_base import InputStage


def _named_stages() -> dict[str, Any]:
    """Every stage class of :mod:`rtlift.blocks` by its ``name`` (each module imported)."""
    for module in pkgutil.iter_modules(rtlift.blocks.__path__):
        importlib.import_module(f"{rtlift.blocks.__name__}.{module.name}")
    found, todo = {}, [InputStage]
    while todo:
        cls = todo.pop()
        todo += cls.__subclasses__()
        if cls.__dict__.get("name"):
            found[cls.name] = cls
    return found


STAGES: dict[str, Any] = _named_stages()
"""Every stage by name: the effects' stages (the static-gain effects' are Wiener nonlinearities
instead) and the interaction structure's ``delivered_envelope`` (and ``delivered_momentum``, as
first merged), which are not effects."""


def stage_from_spec(name: str, params: dict[str, Any], fs_hz: float) -> InputStage:
    """Rebuild a stage from its model-file entry; ValueError for an unknown name."""
    if name not in STAGES:
        raise ValueError(f"unknown augmentation '{name}' (known: {', '.join(sorted(STAGES))})")
    return STAGES[name].from_params(params, fs_hz)
