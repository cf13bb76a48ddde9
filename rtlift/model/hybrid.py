"""The hybrid Wiener–convolution model (An, Williams & Hemati, eq. 11).

    ΔCL(k) = HF( φ Σ_j ΔCL_single(j) Cμ(k−j) ) + W(Cμ_env(k))
           =          ΔCL_H(k)                +   ΔCL_L(k)

The high-frequency part is the high-pass filtered convolution of the burst-modulated Cμ
with the single-burst kernel; the low-frequency part is the Wiener block driven by the
burst envelope. Augmentation stages (effects the paper lacks) may map the inputs before
and the total after. :meth:`HybridModel.step` is the 400 Hz hot path; :meth:`simulate` is
its batch twin; both carry one explicit state.

The hot path is compiled (:mod:`rtlift.blocks.compiled`, numba) for every model whose
nonlinearity has a compiled form (``input_gain``, ``output``) and whose input stages are at most
one ``delay`` followed by at most one ``actuator_fade`` (and at most one ``onset_hold`` before,
between or after them), with any output stages
(``sensor_resonance``, ``zero_drift``, ``periodic_disturbance``, in their state-space form,
:mod:`rtlift.blocks.compiled_stages`): the paper's model, a model as ``rtlift identify`` writes
it, and what ``rtlift diagnose`` (or ``--adapt``) makes of it by adding those effects; and for
the ``interaction`` structure (:mod:`rtlift.blocks.interaction`: its burst part in the
convolution slot, its ``delivered_envelope`` stage after the same delay and fade, the same output
stages), each with the ``hysteresis`` factor on its Wiener nonlinearity or without. Other orders
of input stages and the first merged form of the interaction structure (``delivered_momentum``)
are not compiled: a model that
carries one steps with :meth:`HybridModel.reference_step`, the pure-Python chain of the
blocks' own ``step`` (``model.compiled`` says which). That chain is also the compiled
step's test oracle; both advance the same state arrays. :meth:`simulate` follows the same
choice: one compiled loop over the samples (:func:`rtlift.blocks.compiled.hybrid_simulate`,
:func:`~rtlift.blocks.compiled_interaction.interaction_simulate`) for a compiled model, else
:meth:`HybridModel.reference_simulate`, the chain of the blocks' vectorised ``simulate``
(numpy, scipy). The compiled step is bound to the blocks on the first step after a block or
stage field of the model is assigned; a part swapped
inside a block (``model.wiener.nonlinearity = ...``) is not seen: build a new model instead.
"""

from __future__ import annotations

import time
from copy import deepcopy
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from rtlift.blocks.actuator_fade import ActuatorFade
from rtlift.blocks.chain import BlockChain
from rtlift.blocks.convolution import RingConvolution
from rtlift.blocks.delay import Delay
from rtlift.blocks.delivered import DeliveredEnvelope
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.interaction import IDENTITY_SOS, InteractionConvolution
from rtlift.blocks.onset_hold import OnsetHold
from rtlift.blocks.stage_base import InputStage, OutputStage
from rtlift.blocks.wiener import WienerBlock

_STRUCTURE = frozenset({"convolution", "highpass", "wiener", "input_stages", "output_stages"})
"""Fields whose assignment changes which step (compiled or reference) the model takes."""


class HybridOutput(NamedTuple):
    total: np.ndarray   # ΔCL after output stages
    high: np.ndarray    # ΔCL_H: high-passed convolution
    low: np.ndarray     # ΔCL_L: Wiener part


@dataclass(eq=False)
class HybridModel(BlockChain):
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
    """The residual on the identification campaign (:mod:`rtlift.residual.fingerprint`)."""
    stable: bool = True

    def __setattr__(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)
        if name in _STRUCTURE:
            object.__setattr__(self, "_kernel", None)    # bound again on the next step

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "_kernel"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._kernel = None

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

    def _bind_kernel(self) -> tuple[Any, ...]:
        """(compiled step, its arguments after Cμ and Cμ_env, compiled batch, its size
        arguments), or () when this model takes :meth:`reference_step` (module docstring). The
        arguments are the blocks' own state arrays and one copy of their parameters (fixed
        after construction)."""
        kernel: tuple[Any, ...] = ()
        wiener = self.wiener.kernel_arrays()
        if wiener is not None:
            if type(self.convolution) is RingConvolution:
                kernel = self._bind_hybrid(wiener)
            elif type(self.convolution) is InteractionConvolution:
                kernel = self._bind_interaction(wiener)
        object.__setattr__(self, "_kernel", kernel)
        return kernel

    def _input_state(self, stages: tuple[InputStage, ...]) -> tuple[np.ndarray, ...] | None:
        """The compiled step's input-stage arrays when ``stages`` is at most one ``delay`` followed
        by at most one ``actuator_fade``, with at most one ``onset_hold`` before, between or after
        them: the delay's rings and position, then the fade's parameters and state (zeros, "no
        stage", without one); else None. The hold's place: :meth:`_hold_place`."""
        if self._hold_place(stages) is None:
            return None
        delay: tuple[np.ndarray, ...] = (np.empty(0), np.empty(0), np.zeros(1, dtype=np.int64))
        faded: tuple[np.ndarray, ...] = (np.zeros(5), np.zeros(1))
        for st in stages:
            if type(st) is Delay:
                delay = st.kernel_arrays()[1]
            elif type(st) is ActuatorFade:
                (fpar,), (fstate,) = st.kernel_arrays()
                faded = (fpar, fstate)
        return (*delay, *faded)

    @staticmethod
    def _hold_place(stages: tuple[InputStage, ...]) -> float | None:
        """Where the compiled step runs the ``onset_hold`` stage among ``stages`` (at most one
        ``delay`` followed by at most one ``actuator_fade``, at most one hold anywhere among
        them): 0 without one, else :data:`~rtlift.blocks.compiled_stages.HOLD_FIRST`,
        ``HOLD_AFTER_DELAY`` or ``HOLD_AFTER_FADE``; None for any other list (not compiled)."""
        from rtlift.blocks.compiled_stages import HOLD_AFTER_DELAY, HOLD_AFTER_FADE, HOLD_FIRST

        rest = list(stages)
        place = 0.0
        for kind, after in ((None, HOLD_FIRST), (Delay, HOLD_AFTER_DELAY), (ActuatorFade, HOLD_AFTER_FADE)):
            if kind is not None and rest and type(rest[0]) is kind:
                rest.pop(0)
            if not place and rest and type(rest[0]) is OnsetHold:
                rest.pop(0)
                place = after
        return None if rest else place

    def _with_stages(self, par: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``par`` followed by the output stages' and the hysteresis factor's parameters
        (:func:`~rtlift.blocks.compiled_stages.with_outputs`), and the stages' one state array
        (:func:`~rtlift.blocks.compiled_stages.bind_stage_states`: the fade's clock, the factor's
        [h, s, p], the output stages' states, the ``onset_hold`` stage's), each stage's own state
        a view into it; the hold's place in the packed array (:meth:`_hold_place`)."""
        from rtlift.blocks.compiled_stages import bind_stage_states, with_outputs

        nl = self.wiener.nonlinearity
        memory = nl if hasattr(nl, "memory_arrays") else None        # the hysteresis factor
        fade = next((st for st in self.input_stages if type(st) is ActuatorFade), None)
        hold = next((st for st in self.input_stages if type(st) is OnsetHold), None)
        place = self._hold_place(tuple(st for st in self.input_stages if type(st) is not DeliveredEnvelope))
        return (with_outputs(par, self.output_stages, None if memory is None else memory.memory_arrays()[0],
                             place or 0.0),
                bind_stage_states(fade, memory, self.output_stages, hold))

    def _bind_hybrid(self, wiener: tuple[Any, ...]) -> tuple[Any, ...]:
        """The paper's structure: at most one input ``delay``, then at most one ``actuator_fade``,
        at most one ``onset_hold`` before, between or after them (:meth:`_hold_place`); any output
        stages (each in its state-space form, :mod:`rtlift.blocks.compiled_stages`)."""
        delay = self._input_state(self.input_stages)
        if delay is None or not all(type(st).compiled_form for st in self.output_stages):
            return ()
        from rtlift.blocks.compiled import hybrid_simulate, hybrid_step, pack_parameters, state_slots

        (taps,), conv_state = self.convolution.kernel_arrays()
        (coef,), hp_state = self.highpass.kernel_arrays()
        (A, B, C, form, xs, fs, slopes), wiener_state = wiener
        par, sstate = self._with_stages(pack_parameters(taps, coef, A, B, C, form, xs, fs, slopes))
        *delay, fpar, _ = delay
        return (hybrid_step, (par, *delay, fpar, sstate, *conv_state, *hp_state, *wiener_state), hybrid_simulate,
                state_slots(hp_state[0], wiener_state[0]))

    def _bind_interaction(self, wiener: tuple[Any, ...]) -> tuple[Any, ...]:
        """The interaction structure: input stages [``delay``,] [``actuator_fade``,]
        ``delivered_envelope``, the model's ``highpass`` the identity (its HF lives in the burst
        part); any output stages with a compiled form, the hysteresis factor or none. A model whose
        Wiener input is ``delivered_momentum`` (as first merged) takes :meth:`reference_step`."""
        stages = self.input_stages
        identity = self.highpass.sos.shape == IDENTITY_SOS.shape and np.array_equal(self.highpass.sos, IDENTITY_SOS)
        if (not stages or type(stages[-1]) is not DeliveredEnvelope or not identity
                or not all(type(st).compiled_form for st in self.output_stages)):
            return ()
        delay = self._input_state(stages[:-1])
        if delay is None:
            return ()
        from rtlift.blocks.compiled import pack_parameters, state_slots
        from rtlift.blocks.compiled_interaction import interaction_simulate, interaction_step, pack_interaction

        m_par, (m_in,) = stages[-1].kernel_arrays()
        (taps, coef, m_conv_par, knots, gh, gh_slopes, g, g_slopes, gs, gs_slopes), (buf, pos, z, m_conv) = \
            self.convolution.kernel_arrays()
        (A, B, C, form, xs, fs, slopes), (x,) = wiener
        base = pack_parameters(taps, coef, A, B, C, form, xs, fs, slopes)
        own = pack_interaction(base, m_par, m_conv_par, knots, gh, gh_slopes, g, g_slopes, gs, gs_slopes,
                               stages[-1].lift_arrays())
        par, sstate = self._with_stages(own)
        *delay, fpar, _ = delay
        return (interaction_step, (par, *delay, fpar, sstate, m_in, buf, pos, z, m_conv, x), interaction_simulate,
                (*state_slots(z, x), (0.0,) * (own.size - base.size)))

    @property
    def compiled(self) -> bool:
        """True when :meth:`step` is the compiled step (see the module docstring)."""
        return bool(self._bind_kernel() if self._kernel is None else self._kernel)

    def warm_up(self) -> float:
        """Compile the step (or load it from numba's cache) now, not on the first live sample;
        the state is untouched. Returns the seconds taken (≈ 0 for a reference-step model)."""
        t0 = time.perf_counter()
        kernel = self._bind_kernel()
        if kernel:
            fn, args = kernel[:2]
            fn(0.0, 0.0, *(a.copy() if isinstance(a, np.ndarray) else a for a in args))
        return time.perf_counter() - t0

    def step(self, cmu: float, cmu_envelope: float) -> tuple[float, float, float]:
        """One sample: returns (ΔCL, ΔCL_H, ΔCL_L). No array allocation, no I/O; compiled
        when the model allows it, else :meth:`reference_step`."""
        kernel = self._kernel
        if kernel is None:
            kernel = self._bind_kernel()
        if kernel:
            return kernel[0](float(cmu), float(cmu_envelope), *kernel[1])
        return self.reference_step(cmu, cmu_envelope)

    def reference_step(self, cmu: float, cmu_envelope: float) -> tuple[float, float, float]:
        """:meth:`step` in pure Python, block by block (the compiled step's oracle)."""
        for s in self.input_stages:
            cmu, cmu_envelope = s.step(cmu, cmu_envelope)
        high, low = self.parts_step(cmu, cmu_envelope)
        total = high + low
        for s in self.output_stages:
            total = s.step(total)
        return total, high, low

    @property
    def _lift_offset(self) -> bool:
        """Whether the Wiener part's hysteresis factor is driven by the lift in a model whose
        burst part carries slow lift too (the interaction structure): the factor's driver then
        adds that slow term (:class:`rtlift.blocks.wiener._DirectionMemory`'s ``offset``)."""
        return (type(self.convolution) is InteractionConvolution
                and getattr(self.wiener.nonlinearity, "driver", None) == "lift")

    def parts_step(self, cmu: float, cmu_envelope: float) -> tuple[float, float]:
        """(ΔCL_H, ΔCL_L) of the inputs after the input stages, the burst part first: a
        hysteresis factor on the lift sees the flow's whole quasi-steady lift, its Wiener part
        and the burst part's slow term (interaction structure)."""
        high = self.high_step(cmu, cmu_envelope)
        if self._lift_offset:
            self.wiener.nonlinearity.offset = self.convolution.slow
        return high, self.wiener.step(cmu_envelope)

    def parts_simulate(self, cmu: np.ndarray, cmu_envelope: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batch twin of :meth:`parts_step`."""
        if self._lift_offset:
            burst, slow = self.convolution.simulate_parts(cmu, cmu_envelope)
            high = self.highpass.simulate(burst)
            self.wiener.nonlinearity.offset = slow
            low, _ = self.wiener.simulate(cmu_envelope)
            self.wiener.nonlinearity.offset = self.convolution.slow
            return high, low
        return self.high_simulate(cmu, cmu_envelope), self.wiener.simulate(cmu_envelope)[0]

    def high_step(self, cmu: float, cmu_envelope: float) -> float:
        """ΔCL_H(k) of the inputs after the input stages: HF(convolution) (paper), or the
        interaction structure's burst part, which also takes the Wiener input (Cμ_env′)."""
        if type(self.convolution) is InteractionConvolution:
            return self.highpass.step(self.convolution.step(cmu, cmu_envelope))
        return self.highpass.step(self.convolution.step(cmu))

    def high_simulate(self, cmu: np.ndarray, cmu_envelope: np.ndarray) -> np.ndarray:
        """Batch twin of :meth:`high_step`."""
        if type(self.convolution) is InteractionConvolution:
            return self.highpass.simulate(self.convolution.simulate(cmu, cmu_envelope))
        return self.highpass.simulate(self.convolution.simulate(cmu))

    def simulate(self, cmu: np.ndarray, cmu_envelope: np.ndarray) -> HybridOutput:
        """Batch twin of :meth:`step` over arrays; starts from and advances the current state."""
        cmu = np.asarray(cmu, dtype=float)
        env = np.asarray(cmu_envelope, dtype=float)
        if cmu.shape != env.shape or cmu.ndim != 1:
            raise ValueError(f"cmu {cmu.shape} and cmu_envelope {env.shape} must be equal 1-D arrays")
        kernel = self._kernel
        if kernel is None:
            kernel = self._bind_kernel()
        if kernel:                                # the compiled step's model: one compiled loop
            _, args, batch, slots = kernel
            total, high, low = np.empty(cmu.size), np.empty(cmu.size), np.empty(cmu.size)
            batch(np.ascontiguousarray(cmu), np.ascontiguousarray(env), total, high, low, *args, *slots)
            return HybridOutput(total, high, low)
        return self.reference_simulate(cmu, env)

    def reference_simulate(self, cmu: np.ndarray, cmu_envelope: np.ndarray) -> HybridOutput:
        """:meth:`simulate` as a chain of the blocks' own vectorised ``simulate`` (numpy and
        scipy): the path of the models the compiled step does not cover, and the compiled
        batch's second judge."""
        high, low = self.parts_simulate(*self.inputs_simulate(cmu, cmu_envelope))
        total = high + low
        for s in self.output_stages:
            total = s.simulate(total)
        return HybridOutput(total, high, low)

    def inputs_simulate(self, cmu: np.ndarray, cmu_envelope: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Cμ′, Cμ_env′): the inputs after the input stages (their batch twins), advancing their state."""
        cmu = np.asarray(cmu, dtype=float)
        env = np.asarray(cmu_envelope, dtype=float)
        for s in self.input_stages:
            cmu, env = s.simulate(cmu, env)
        return cmu, env

    def copy(self) -> HybridModel:
        """An independent copy at rest: the same parameters, stages and settings, state arrays
        of its own (reset), the compiled step bound again on its first step."""
        model = deepcopy(self)
        model.reset()
        return model

    def with_stages(self, input_stages=(), output_stages=()) -> HybridModel:
        """A copy of this model (fresh state) with extra stages appended."""
        m = self.copy()
        m.input_stages = (*m.input_stages, *input_stages)
        m.output_stages = (*m.output_stages, *output_stages)
        m.__post_init__()
        return m
