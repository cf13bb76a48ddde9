"""Every augmentation stage by name (:data:`STAGES`), as a model file lists it, and
:func:`stage_from_spec`, which rebuilds one from its entry. The interface the stages implement,
and the registry their classes put themselves in when defined, is :mod:`rtlift.blocks.stage_base`;
this module imports the model layer's own stage modules (so that they have registered) and
re-exports the registry. A stage an effect defines in its own module of :mod:`rtlift.effects`
is found through the stage providers (:func:`rtlift.blocks.stage_base.stage_class`).

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

from typing import Any

from rtlift.blocks import actuator_fade, delay, delivered, periodic_disturbance, sensor_resonance, zero_drift
from rtlift.blocks.stage_base import STAGES, InputStage, stage_class

OWN_STAGE_MODULES = (delay, actuator_fade, delivered, sensor_resonance, zero_drift, periodic_disturbance)
"""The model layer's stage modules (imported here: their classes have registered)."""

__all__ = ["OWN_STAGE_MODULES", "STAGES", "stage_from_spec"]


def stage_from_spec(name: str, params: dict[str, Any], fs_hz: float) -> InputStage:
    """Rebuild a stage from its model-file entry (``fs_hz`` in Hz);
    :class:`~rtlift.blocks.stage_base.UnknownStageError` (a ValueError) for an unknown name."""
    return stage_class(name).from_params(params, fs_hz)
