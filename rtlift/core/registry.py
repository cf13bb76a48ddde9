"""The one registry of what rtlift can add to a model: one record per effect and per structure.

Each record holds, under the name of INTERFACES.md's effects table:

- ``kind``: ``effect`` (a lift-model effect: it departs from what the model's identification data
  showed) or ``structure`` (a generic ``t,u,y`` model's form is too simple);
- ``doc``: its one line of meaning (the diagnosis report quotes it; INTERFACES.md's table says
  the same, at times in fewer words);
- the parameter schema (:class:`~rtlift.core.effects.EffectSchema`: defaults, units, ranges; a
  structure's parameters are fitted without documented ranges, so its schema holds its meaning
  only);
- where it acts and what streams it: ``path`` (``input``, ``nonlinearity``, ``filter``,
  ``additive``: the signal path's order, which is also the order the diagnosis combines them
  in) and ``stages`` (the streaming stage, or the Wiener nonlinearity forms);
- its diagnosis (:class:`Diagnosis`: fit, evidence, parameters spent, exclusions);
- its observer form (a factory returning a ``StateBlock`` or ``None``: the bias state covers it;
  no form: applied as a known correction);
- its bench injection (:class:`Bench`: the bench stage, the intervals the bench accepts, its
  bench-only parameters);
- the parameters that belong to a record rather than to the effect (a pickup's phases);
- for a structure: how the generic diagnosis fits it and the model structures it is tried in.

Code is named here by ``"module:attribute"`` and resolved by the layer it belongs to
(:func:`resolve`), never by the core at load time: ``rtlift.blocks.stages`` builds ``STAGES``
from the stages named here (each in a module of its own under ``rtlift.blocks``),
``rtlift.diagnose.catalog`` its ``CATALOG``, ``rtlift.observer.layout`` its ``OBSERVER_FORMS``,
``hil_sim.effects`` its ``EFFECTS``, ``rtlift.sysid.diagnose`` its forms and ``rtlift.model.siso``
its ``STRUCTURES``.
``tests/test_registry.py`` checks every part of every record against those tables and the docs.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from rtlift.core.effects import EffectSchema, Interval, schema

PATHS = ("input", "nonlinearity", "filter", "additive")
"""Where a lift effect acts, in the signal path's order (input stages, the Wiener nonlinearity,
filter-kind output stages, additive output stages)."""


@dataclass(frozen=True)
class Diagnosis:
    """How the lift diagnosis fits an effect and what in the residual points at it."""

    fit: str
    evidence: str
    n_params: int | str | None = None
    """Parameters the effect spends: a number, or ``"module:function"`` of the fitted params
    (``None``: a structure, accepted on the validation error alone)."""
    excludes: tuple[str, ...] = ()
    fits_change: bool = False
    """Replaces the model's static map: fitted to what changed since identification
    (:class:`rtlift.diagnose.catalog.Effect`)."""
    bands: str | None = None
    """``"module:function"`` of the frequency bands an accepted fit accounts for in the residual's
    spectrum, ``(params, df) → [(lo_hz, hi_hz)]`` (:func:`rtlift.diagnose.unexplained.explained_bands`);
    ``None``: no band of its own."""


@dataclass(frozen=True)
class Bench:
    """How the simulated bench injects an effect: its stage there (``actuator``, ``plant``,
    ``force``, ``offset``), the interval each parameter must lie in, the parameters the bench
    takes beyond the schema (what the plant does, not what a model fits), with defaults, and for
    a ``plant`` effect the plant parameter each of its parameters adds to."""

    stage: str
    accepts: Mapping[str, Interval] = field(default_factory=dict)
    only: Mapping[str, float] = field(default_factory=dict)
    plant: Mapping[str, str] = field(default_factory=dict)
    """(``plant`` stage) ``{effect parameter: the plant parameter it adds to}``
    (:class:`hil_sim.plant.PlantParams`; the bench's other stages have their own processors)."""


@dataclass(frozen=True)
class Entry:
    """One effect or structure (module docstring)."""

    name: str
    kind: str
    schema: EffectSchema
    path: str = ""
    stages: tuple[str, ...] = ()
    diagnosis: Diagnosis | None = None
    observer: str | None = None
    bench: Bench | None = None
    per_record: tuple[str, ...] = ()
    """Parameters that belong to a record, not to the effect: re-estimated on each record
    (:func:`rtlift.model.validation.predict_record`)."""
    how: str = ""
    """(structures) How the generic diagnosis fits it."""
    forms: tuple[tuple[str, str | None], ...] = ()
    """(structures) The model structures (:data:`MODEL_STRUCTURES`) it is tried in, each with
    where its limit sits (``None``: no limit)."""

    @property
    def doc(self) -> str:
        """The one line of meaning (module docstring)."""
        return self.schema.meaning


@dataclass(frozen=True)
class ModelStructure:
    """A generic ``t,u,y`` model structure ``rtlift identify --record`` identifies."""

    name: str
    doc: str
    model: str


def _entry(name: str, kind: str, meaning: str, params: dict[str, tuple[float, float, float, str]] | None = None,
           alternatives: dict[str, tuple[float, float, float, str]] | None = None, **parts: Any) -> Entry:
    """A record from its meaning and ``{param: (default, lo, hi, unit)}`` (and one alternative set
    alike) and its parts."""
    return Entry(name, kind, schema(name, meaning, params, alternatives), **parts)


def _bench(stage: str, only: dict[str, float] | None = None, plant: dict[str, str] | None = None,
           **accepts: str) -> Bench:
    return Bench(stage, MappingProxyType({k: Interval(v) for k, v in accepts.items()}),
                 MappingProxyType(only or {}), MappingProxyType(plant or {}))


_BLOCKS, _WIENER = "rtlift.blocks", "rtlift.blocks.wiener"
_FITS, _EVIDENCE, _LAYOUT = "rtlift.diagnose.fits", "rtlift.diagnose.catalog", "rtlift.observer.layout"
_SISO, _HIGHER_ORDER = "rtlift.sysid.identify:identify_siso", "rtlift.residual.stats:higher_order"
POSITIVE = "(0, inf)"

REGISTRY: tuple[Entry, ...] = (     # in INTERFACES.md's order
    _entry("delay", "effect", "measured lift lags the actuation record (DAQ or convective latency)",
           {"seconds": (0.025, 0.005, 0.1, "s")},
           path="input", stages=(f"{_BLOCKS}.delay:Delay",),
           diagnosis=Diagnosis(f"{_FITS}:fit_delay", f"{_EVIDENCE}:evidence_delay", 1),
           bench=_bench("force", seconds="(0, 10]")),
    _entry("sensor_resonance", "effect", "force balance / wing structural mode filtering the measured lift",
           {"frequency_hz": (30.0, 12.0, 80.0, "Hz"), "damping_ratio": (0.05, 0.02, 0.3, "1")},
           path="filter", stages=(f"{_BLOCKS}.sensor_resonance:SensorResonance",),
           diagnosis=Diagnosis(f"{_FITS}:fit_sensor_resonance", f"{_EVIDENCE}:evidence_resonance", 2,
                               bands=f"{_EVIDENCE}:bands_resonance"),
           bench=_bench("force", frequency_hz="(0, 190)", damping_ratio=POSITIVE)),
    _entry("actuator_fade", "effect", "actuators deliver less Cμ as they heat up over accumulated burst on-time",
           {"final_fraction": (0.6, 0.4, 0.9, "1"), "time_constant_s": (3.0, 1.0, 10.0, "s")},
           path="input", stages=(f"{_BLOCKS}.actuator_fade:ActuatorFade",),
           diagnosis=Diagnosis(f"{_FITS}:fit_actuator_fade", f"{_EVIDENCE}:evidence_fade", 2),
           bench=_bench("actuator", {"onset_s": 0.0}, final_fraction="[0, 1]", time_constant_s=POSITIVE,
                        onset_s="[0, inf)")),
    _entry("zero_drift", "effect", "thermal drift of the sensor zero (ΔCL units)",
           {"rate_per_s": (4.0e-4, 2.0e-4, 1.5e-3, "ΔCL/s")},
           {"amplitude": (0.02, 0.01, 0.05, "ΔCL"), "time_constant_s": (20.0, 5.0, 60.0, "s")},
           path="additive", stages=(f"{_BLOCKS}.zero_drift:ZeroDrift",),
           diagnosis=Diagnosis(f"{_FITS}:fit_zero_drift", f"{_EVIDENCE}:evidence_drift", f"{_EVIDENCE}:n_params_drift"),
           observer=f"{_LAYOUT}:absorbed_by_bias", bench=_bench("offset", time_constant_s=POSITIVE)),
    _entry("periodic_disturbance", "effect",
           "narrow-band pickup (mains, fan blade passing) as sampled (ΔCL units)",
           {"frequency_hz": (20.0, 1.0, 190.0, "Hz"), "amplitude": (0.006, 0.002, 0.02, "ΔCL")},
           path="additive", stages=(f"{_BLOCKS}.periodic_disturbance:PeriodicDisturbance",),
           diagnosis=Diagnosis(f"{_FITS}:fit_periodic_disturbance", f"{_EVIDENCE}:evidence_pickup",
                               f"{_EVIDENCE}:n_params_pickup", bands=f"{_EVIDENCE}:bands_pickup"),
           observer=f"{_LAYOUT}:oscillator", bench=_bench("offset", frequency_hz=POSITIVE),
           per_record=("phase_rad",)),
    _entry("hysteresis", "effect", "static gain differs between rising and falling Cμ",
           {"magnitude": (0.15, 0.05, 0.3, "1")},
           path="nonlinearity", stages=(f"{_WIENER}:HysteresisGain", f"{_WIENER}:OutputHysteresis"),
           diagnosis=Diagnosis(f"{_FITS}:fit_hysteresis", f"{_EVIDENCE}:evidence_hysteresis", 4,
                               ("output_nonlinearity",), True),
           bench=_bench("plant", plant={"magnitude": "hysteresis"}, magnitude="(-0.9, 5)")),
    _entry("output_nonlinearity", "effect", "the static nonlinearity acts on y (textbook Wiener) rather than on Cμ",
           path="nonlinearity", stages=(f"{_WIENER}:OutputNonlinearity",),
           diagnosis=Diagnosis(f"{_FITS}:fit_output_nonlinearity", f"{_EVIDENCE}:evidence_output_nonlinearity", 10,
                               ("hysteresis",), True)),
    _entry("output_dynamics", "structure",
           "a linear block after the static nonlinearity: Wiener becomes Wiener–Hammerstein (a balance or "
           "amplifier with its own dynamics)",
           diagnosis=Diagnosis(_SISO, _HIGHER_ORDER),
           how="Wiener-Hammerstein re-identified jointly from the best linear approximation's pole/zero splits",
           forms=(("wiener_hammerstein", None),)),
    _entry("nonlinear_feedback", "structure",
           "the output feeds back through a static nonlinearity into the linear block's input "
           "(amplitude-dependent resonance, Duffing-like)",
           diagnosis=Diagnosis(_SISO, _HIGHER_ORDER),
           how="the output's deviation y from an operating point fed back through k2 y^2 + k3 y^3 into a strictly "
               "proper linear block, plus the input's direct path, all refined jointly from the ARX fit",
           forms=(("nonlinear_feedback", None),)),
    _entry("saturation", "structure",
           "a hard limit on the input, a state or the output (overflow, clipping, actuator limits)",
           diagnosis=Diagnosis(_SISO, "rtlift.sysid.diagnose:clip_levels"),
           how="the output (or a feedback form's state: one store, or two in cascade) clipped at the level the "
               "measurement piles up at, the model re-identified jointly with the limit in place (censored "
               "samples for an output limit) in each form",
           forms=(("wiener", "output"), ("wiener_hammerstein", "output"), ("nonlinear_feedback", "output"),
                  ("nonlinear_feedback", "state"), ("store_chain", "state"))),
)

MODEL_STRUCTURES: tuple[ModelStructure, ...] = (     # the first is the default
    ModelStructure("wiener", "an LTI then a static map", "rtlift.model.siso:SisoModel"),
    ModelStructure("wiener_hammerstein", "a second LTI after the map", "rtlift.model.siso:SisoModel"),
    ModelStructure("nonlinear_feedback", "the output fed back through a cubic map into the LTI's input",
                   "rtlift.model.siso:FeedbackModel"),
    ModelStructure("store_chain", "two stores in cascade, each draining through a power-law outflow, "
                   "like two tanks", "rtlift.model.siso:StoreChainModel"),
)

ENTRIES: Mapping[str, Entry] = MappingProxyType({e.name: e for e in REGISTRY})
EFFECTS: tuple[Entry, ...] = tuple(e for e in REGISTRY if e.kind == "effect")
"""The lift-model effects, in INTERFACES.md's order."""
STRUCTURES: tuple[Entry, ...] = tuple(e for e in REGISTRY if e.kind == "structure")
"""The generic ``t,u,y`` structures the diagnosis adds, in INTERFACES.md's order."""
SCHEMAS: Mapping[str, EffectSchema] = MappingProxyType({e.name: e.schema for e in EFFECTS})
MODEL_STRUCTURE_NAMES: tuple[str, ...] = tuple(s.name for s in MODEL_STRUCTURES)


def in_signal_order(entries: tuple[Entry, ...] = EFFECTS) -> tuple[Entry, ...]:
    """The effects in the signal path's order (:data:`PATHS`; stable within one path): the order
    the diagnosis builds a combination in."""
    return tuple(sorted(entries, key=lambda e: PATHS.index(e.path)))


def resolve(path: str) -> Any:
    """The object ``"module:attribute"`` names (imports the module: call it from the layer the
    module belongs to or above)."""
    mod, _, attr = path.partition(":")
    return getattr(importlib.import_module(mod), attr)
