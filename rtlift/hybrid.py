"""The hybrid Wiener–convolution model (An, Williams & Hemati, eq. 11).

    ΔCL(k) = HF( φ Σ_j ΔCL_single(j) Cμ(k−j) ) + W(Cμ_env(k))
           =          ΔCL_H(k)                +   ΔCL_L(k)

The high-frequency part is the high-pass filtered convolution of the burst-modulated Cμ
with the single-burst kernel; the low-frequency part is the Wiener block driven by the
burst envelope. Augmentation stages (effects the paper lacks) may map the inputs before
and the total after. :meth:`HybridModel.step` is the 400 Hz hot path; :meth:`simulate` is
its vectorised twin; both carry one explicit state.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from rtlift.blocks.convolution import RingConvolution
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.stages import InputStage, OutputStage
from rtlift.blocks.wiener import WienerBlock


class HybridOutput(NamedTuple):
    total: np.ndarray   # ΔCL after output stages
    high: np.ndarray    # ΔCL_H: high-passed convolution
    low: np.ndarray     # ΔCL_L: Wiener part


@dataclass(eq=False)
class HybridModel:
    convolution: RingConvolution
    highpass: HighPassFilter
    wiener: WienerBlock
    fs_hz: float
    input_stages: tuple[InputStage, ...] = ()
    output_stages: tuple[OutputStage, ...] = ()
    provenance: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    observer_config: dict[str, Any] = field(default_factory=dict)
    fingerprint: dict[str, Any] = field(default_factory=dict)
    """The residual on the identification campaign (:mod:`rtlift.diagnose.fingerprint`)."""
    stable: bool = True

    def __post_init__(self) -> None:
        self.input_stages = tuple(self.input_stages)
        self.output_stages = tuple(self.output_stages)
        for s in self.input_stages:
            if s.where != "input":
                raise ValueError(f"stage '{s.name}' acts on the output, not the input")
        for s in self.output_stages:
            if s.where != "output":
                raise ValueError(f"stage '{s.name}' acts on the input, not the output")

    @property
    def blocks(self) -> tuple[Any, ...]:
        """Every stateful block, in the order of :meth:`get_state`."""
        return (*self.input_stages, self.convolution, self.highpass, self.wiener, *self.output_stages)

    def step(self, cmu: float, cmu_envelope: float) -> tuple[float, float, float]:
        """One sample: returns (ΔCL, ΔCL_H, ΔCL_L). No array allocation, no I/O."""
        for s in self.input_stages:
            cmu, cmu_envelope = s.step(cmu, cmu_envelope)
        high = self.highpass.step(self.convolution.step(cmu))
        low = self.wiener.step(cmu_envelope)
        total = high + low
        for s in self.output_stages:
            total = s.step(total)
        return total, high, low

    def simulate(self, cmu: np.ndarray, cmu_envelope: np.ndarray) -> HybridOutput:
        """Batch twin of :meth:`step` over arrays; starts from and advances the current state."""
        cmu = np.asarray(cmu, dtype=float)
        env = np.asarray(cmu_envelope, dtype=float)
        if cmu.shape != env.shape or cmu.ndim != 1:
            raise ValueError(f"cmu {cmu.shape} and cmu_envelope {env.shape} must be equal 1-D arrays")
        for s in self.input_stages:
            cmu, env = s.simulate(cmu, env)
        high = self.highpass.simulate(self.convolution.simulate(cmu))
        low, _ = self.wiener.simulate(env)
        total = high + low
        for s in self.output_stages:
            total = s.simulate(total)
        return HybridOutput(total, high, low)

    def reset(self) -> None:
        for b in self.blocks:
            b.reset()

    @property
    def state_size(self) -> int:
        return sum(b.state_size for b in self.blocks)

    def get_state(self) -> np.ndarray:
        return np.concatenate([np.atleast_1d(b.get_state()) for b in self.blocks])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (self.state_size,):
            raise ValueError(f"model state must have shape ({self.state_size},), got {s.shape}")
        i = 0
        for b in self.blocks:
            b.set_state(s[i:i + b.state_size])
            i += b.state_size

    def with_stages(self, input_stages=(), output_stages=()) -> HybridModel:
        """A copy of this model (fresh state) with extra stages appended."""
        from rtlift.modelfile import model_from_dict, model_to_dict

        m = model_from_dict(model_to_dict(self), allow_unstable=not self.stable)
        m.input_stages = (*m.input_stages, *input_stages)
        m.output_stages = (*m.output_stages, *output_stages)
        m.__post_init__()
        return m
