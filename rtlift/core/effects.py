"""One home per effect: the parameter schema every part of rtlift shares.

An effect is named and parametrised as in INTERFACES.md. :data:`SCHEMAS` holds, per name, what
the effect means, its parameters with their documented ranges and defaults, and the parameter
sets that may be given instead of the defaults' (a drift is linear or exponential). The
simulated bench draws and checks its injected effects against these ranges (it keeps its own
truth physics), the model's stages take these parameter names, and the diagnosis's catalog
(:data:`rtlift.diagnose.catalog.CATALOG`) adds to each the fit and the evidence that point at it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np


@dataclass(frozen=True)
class EffectSchema:
    """One effect's name, meaning, parameters (defaults and documented ranges, SI units)."""

    name: str
    meaning: str
    defaults: Mapping[str, float] = field(default_factory=dict)
    ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    alternatives: tuple[tuple[str, ...], ...] = ()
    """Parameter sets that may be given instead of the defaults' set (zero_drift)."""

    @property
    def parameter_sets(self) -> tuple[tuple[str, ...], ...]:
        return (tuple(self.defaults), *self.alternatives)

    def draw(self, rng: np.random.Generator) -> dict[str, float]:
        """Parameters drawn uniformly from ``ranges`` (one of the parameter sets)."""
        sets = self.parameter_sets
        chosen = sets[int(rng.integers(len(sets)))]
        return {k: float(rng.uniform(*self.ranges[k])) for k in chosen}


def _schema(name: str, meaning: str, defaults: dict[str, float] | None = None,
            ranges: dict[str, tuple[float, float]] | None = None,
            alternatives: tuple[tuple[str, ...], ...] = ()) -> EffectSchema:
    return EffectSchema(name, meaning, MappingProxyType(defaults or {}), MappingProxyType(ranges or {}),
                        alternatives)


SCHEMAS: Mapping[str, EffectSchema] = MappingProxyType({s.name: s for s in (
    _schema("delay", "measured lift lags the actuation record (DAQ or convective latency)",
            {"seconds": 0.025}, {"seconds": (0.005, 0.1)}),
    _schema("sensor_resonance", "force balance / wing structural mode filtering the measured lift",
            {"frequency_hz": 30.0, "damping_ratio": 0.05},
            {"frequency_hz": (12.0, 80.0), "damping_ratio": (0.02, 0.3)}),
    _schema("actuator_fade", "actuators deliver less Cμ as they heat up over accumulated burst on-time",
            {"final_fraction": 0.6, "time_constant_s": 3.0},
            {"final_fraction": (0.4, 0.9), "time_constant_s": (1.0, 10.0)}),
    _schema("zero_drift", "thermal drift of the sensor zero (ΔCL units)",
            {"rate_per_s": 4.0e-4},
            {"rate_per_s": (2.0e-4, 1.5e-3), "amplitude": (0.01, 0.05), "time_constant_s": (5.0, 60.0)},
            alternatives=(("amplitude", "time_constant_s"),)),
    _schema("periodic_disturbance", "narrow-band pickup (mains, fan blade passing) as sampled (ΔCL units)",
            {"frequency_hz": 20.0, "amplitude": 0.006},
            {"frequency_hz": (1.0, 190.0), "amplitude": (0.002, 0.02)}),
    _schema("hysteresis", "static gain differs between rising and falling Cμ",
            {"magnitude": 0.15}, {"magnitude": (0.05, 0.3)}),
    _schema("output_nonlinearity", "the static nonlinearity acts on y (textbook Wiener) rather than on Cμ"),
)})
