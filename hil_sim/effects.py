"""Effects the model is not told about: composable, seeded, parsed from ``NAME[:k=v,...]``.

Each effect acts at one stage of the bench (docs/BENCH.md, "Effects"):

========================  =========  =====================================================
name                      stage      what it does (SI units; ΔCL-valued amplitudes)
========================  =========  =====================================================
``actuator_fade``         actuator   Cμ delivered = Cμ · (f + (1 − f) exp(−E/τ)), E the
                                     accumulated burst on-time (s) (actuators heat up)
``hysteresis``            plant      static gain on falling Cμ is (1 + m) × that on rising
``delay``                 force      measured forces lag by round(seconds · fs) samples
``sensor_resonance``      force      ω²/(s² + 2ζωs + ω²) on the measured forces (balance /
                                     wing mode), bilinear with pre-warping at ω
``zero_drift``            offset     lift zero drifts: rate · t, or A (1 − exp(−t/τ))
``periodic_disturbance``  offset     A sin(2π f t + φ₀), φ₀ drawn from the seed (pickup as
                                     sampled, e.g. 420 Hz mains aliased to 20 Hz)
========================  =========  =====================================================

``EFFECTS[name]`` holds how the bench injects it (:class:`Bench`: the stage, the intervals the
bench accepts, the bench-only parameters) and its parameter schema (defaults, documented ranges
``ranges[param] = (lo, hi)``, ``draw(rng)``): the bench is the truth plant and declares its own,
which ``tests/test_effects_modules.py`` checks against the effects of :mod:`rtlift.effects`
(the same names, parameters, defaults and ranges; every interval the bench accepts holds the
documented range). ``parse_effect(spec)`` raises :class:`~rtlift.core.errors.UserError` on a
bad spec.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from scipy import signal

from rtlift.core.effects import EffectSchema, Interval, schema
from rtlift.core.errors import UserError


@dataclass(frozen=True)
class Bench:
    """How the simulated bench injects an effect: its stage here (``actuator``, ``plant``,
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
class EffectInfo:
    """One effect kind on the bench: how it is injected here (:class:`Bench`: the stage, the
    intervals its parameters must lie in, the bench-only parameters) and its parameter schema
    (meaning on the bench, defaults, documented ranges)."""

    bench: Bench
    schema: EffectSchema

    name = property(lambda self: self.schema.name)
    stage = property(lambda self: self.bench.stage)
    defaults = property(lambda self: self.schema.defaults)
    ranges = property(lambda self: self.schema.ranges)
    meaning = property(lambda self: self.schema.meaning)
    alternatives = property(lambda self: self.schema.alternatives)

    def draw(self, rng: np.random.Generator) -> Effect:
        """Parameters drawn uniformly from ``ranges`` (one parameter set for zero_drift)."""
        return Effect(self.name, self.schema.draw(rng))


def _info(name: str, stage: str, meaning: str, params: dict[str, tuple[float, float, float, str]],
          alternatives: dict[str, tuple[float, float, float, str]] | None = None,
          only: dict[str, float] | None = None, plant: dict[str, str] | None = None,
          **accepts: str) -> EffectInfo:
    """One injection from its ``{param: (default, lo, hi, unit)}`` (and one alternative set
    alike) and the intervals the bench accepts (``param="(lo, hi]"``)."""
    bench = Bench(stage, MappingProxyType({k: Interval(v) for k, v in accepts.items()}),
                  MappingProxyType(only or {}), MappingProxyType(plant or {}))
    return EffectInfo(bench, schema(name, meaning, params, alternatives))


POSITIVE = "(0, inf)"
EFFECTS: Mapping[str, EffectInfo] = MappingProxyType({i.name: i for i in (      # INTERFACES.md's order
    _info("delay", "force", "measured forces lag by round(seconds · fs) samples",
          {"seconds": (0.025, 0.005, 0.1, "s")}, seconds="(0, 10]"),
    _info("sensor_resonance", "force", "a second-order mode on the measured forces",
          {"frequency_hz": (30.0, 12.0, 80.0, "Hz"), "damping_ratio": (0.05, 0.02, 0.3, "1")},
          frequency_hz="(0, 190)", damping_ratio=POSITIVE),
    _info("actuator_fade", "actuator", "Cμ delivered fades with the accumulated burst on-time",
          {"final_fraction": (0.6, 0.4, 0.9, "1"), "time_constant_s": (3.0, 1.0, 10.0, "s")},
          only={"onset_s": 0.0}, final_fraction="[0, 1]", time_constant_s=POSITIVE, onset_s="[0, inf)"),
    _info("zero_drift", "offset", "the lift zero drifts",
          {"rate_per_s": (4.0e-4, 2.0e-4, 1.5e-3, "ΔCL/s")},
          {"amplitude": (0.02, 0.01, 0.05, "ΔCL"), "time_constant_s": (20.0, 5.0, 60.0, "s")},
          time_constant_s=POSITIVE),
    _info("periodic_disturbance", "offset", "a sinusoid added to the lift (pickup as sampled)",
          {"frequency_hz": (20.0, 1.0, 190.0, "Hz"), "amplitude": (0.006, 0.002, 0.02, "ΔCL")},
          frequency_hz=POSITIVE),
    _info("hysteresis", "plant", "the static gain on falling Cμ is (1 + m) × that on rising",
          {"magnitude": (0.15, 0.05, 0.3, "1")}, plant={"magnitude": "hysteresis"}, magnitude="(-0.9, 5)"),
)})
"""The effects the bench injects, in INTERFACES.md's order."""
STAGE_ON_BENCH: Mapping[str, str] = MappingProxyType({n: i.stage for n, i in EFFECTS.items()})
BENCH_ONLY: Mapping[str, Mapping[str, float]] = MappingProxyType(
    {n: i.bench.only for n, i in EFFECTS.items() if i.bench.only})
"""Parameters the bench takes beyond the shared schema (what the plant does, not what a model
fits): ``actuator_fade:onset_s`` — the actuators start heating (on-time counted) from this
device time on, so a fade can set in during a run."""


@dataclass(frozen=True)
class Effect:
    """One effect with its parameters (SI units, names of INTERFACES.md)."""

    name: str
    params: Mapping[str, float] = field(default_factory=dict)

    @property
    def info(self) -> EffectInfo:
        return EFFECTS[self.name]

    @property
    def stage(self) -> str:
        return self.info.stage

    def spec(self) -> str:
        """The canonical ``NAME:k=v,...`` (round-trips through :func:`parse_effect`)."""
        return self.name + ":" + ",".join(f"{k}={v:g}" for k, v in self.params.items())


def _check(name: str, params: dict[str, float], spec: str) -> None:
    info = EFFECTS[name]
    sets = info.schema.parameter_sets
    if set(params) - set(info.bench.only) not in map(set, sets):
        raise UserError(f"effect {spec!r}: {name} takes " + ", or ".join(" and ".join(s) for s in sets))
    for key, value in params.items():
        if not math.isfinite(value):
            raise UserError(f"effect {spec!r}: {key} must be a finite number")
    for key, interval in info.bench.accepts.items():
        if key in params and params[key] not in interval:
            raise UserError(f"effect {spec!r}: {key} must be in {interval}, got {params[key]:g}")


def parse_effect(spec: str) -> Effect:
    """``NAME[:k=v,...]`` → :class:`Effect`; missing parameters take the defaults."""
    text = spec.strip()
    name, _, rest = text.partition(":")
    name = name.strip()
    if name not in EFFECTS:
        raise UserError(f"unknown effect {name!r} in {spec!r} (known: {', '.join(EFFECTS)})")
    info = EFFECTS[name]
    known = set(info.ranges) | set(info.bench.only)
    given: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq:
            raise UserError(f"effect {spec!r}: expected key=value, got {item!r}")
        if key not in known:
            raise UserError(f"effect {spec!r}: unknown parameter {key!r} "
                            f"(known: {', '.join(sorted(known))})")
        if key in given:
            raise UserError(f"effect {spec!r}: parameter {key!r} given twice")
        try:
            given[key] = float(value)
        except ValueError:
            raise UserError(f"effect {spec!r}: {key} is not a number: {value.strip()!r}") from None
    params = dict(info.schema.defaults_for(set(given) - set(info.bench.only)))
    params.update({k: v for k, v in info.bench.only.items() if k in given})
    params.update(given)
    _check(name, params, spec)
    return Effect(name, params)


def as_effect(effect: Effect | str) -> Effect:
    return effect if isinstance(effect, Effect) else parse_effect(effect)


# -- streaming processors (one per effect per bench run, state carried between chunks) ----

class ActuatorFade:
    """``actuator_fade``: Cμ · (f + (1 − f) exp(−E/τ)), E = burst on-time so far (s),
    counted from device time ``onset_s`` on (0: from the start)."""

    name = "actuator_fade"

    def __init__(self, params: Mapping[str, float], fs_hz: float) -> None:
        self.f = params["final_fraction"]
        self.tau = params["time_constant_s"]
        self.dt = 1.0 / fs_hz
        self.on_time = 0.0
        self.onset = int(round(params.get("onset_s", 0.0) * fs_hz))
        self.samples = 0

    def process(self, cmu: np.ndarray) -> np.ndarray:
        on = np.asarray(cmu) > 0
        if self.samples < self.onset:
            on = on & (np.arange(self.samples, self.samples + len(on)) >= self.onset)
        self.samples += len(on)
        elapsed = self.on_time + self.dt * np.cumsum(on)
        self.on_time = float(elapsed[-1]) if len(elapsed) else self.on_time
        before = elapsed - self.dt * on  # on-time accumulated before this sample
        return cmu * (self.f + (1.0 - self.f) * np.exp(-before / self.tau))


class Delay:
    """``delay``: rows lag by round(seconds · fs) samples (the first rows repeat the start)."""

    name = "delay"

    def __init__(self, params: Mapping[str, float], fs_hz: float) -> None:
        self.n = int(round(params["seconds"] * fs_hz))
        self.buffer: np.ndarray | None = None

    def process(self, x: np.ndarray) -> np.ndarray:
        if self.n == 0:
            return x
        if self.buffer is None:
            self.buffer = np.repeat(x[:1], self.n, axis=0)
        joined = np.concatenate([self.buffer, x])
        self.buffer = joined[len(joined) - self.n:]
        return joined[:len(x)]


class SensorResonance:
    """``sensor_resonance``: unit-DC-gain second-order mode on every column."""

    name = "sensor_resonance"

    def __init__(self, params: Mapping[str, float], fs_hz: float) -> None:
        f = params["frequency_hz"]
        zeta = params["damping_ratio"]
        w = 2.0 * fs_hz * math.tan(math.pi * f / fs_hz)  # pre-warped
        b, a = signal.bilinear([w * w], [1.0, 2.0 * zeta * w, w * w], fs=fs_hz)
        self.b, self.a = b, a
        self.zi: np.ndarray | None = None

    def process(self, x: np.ndarray) -> np.ndarray:
        if self.zi is None:
            self.zi = signal.lfilter_zi(self.b, self.a)[:, None] * x[:1]
        y, self.zi = signal.lfilter(self.b, self.a, x, axis=0, zi=self.zi)
        return y


class ZeroDrift:
    """``zero_drift``: additive lift zero, rate · t or A (1 − exp(−t/τ)), t from power-up."""

    name = "zero_drift"

    def __init__(self, params: Mapping[str, float], fs_hz: float) -> None:
        self.params = params

    def process(self, t: np.ndarray) -> np.ndarray:
        p = self.params
        if "rate_per_s" in p:
            return p["rate_per_s"] * t
        return p["amplitude"] * (1.0 - np.exp(-t / p["time_constant_s"]))


class PeriodicDisturbance:
    """``periodic_disturbance``: A sin(2π f t + φ₀) as sampled, φ₀ from the seed."""

    name = "periodic_disturbance"
    seeded = True

    def __init__(self, params: Mapping[str, float], fs_hz: float,
                 rng: np.random.Generator) -> None:
        self.f = params["frequency_hz"]
        self.amplitude = params["amplitude"]
        self.phase = float(rng.uniform(0.0, 2.0 * math.pi))

    def process(self, t: np.ndarray) -> np.ndarray:
        return self.amplitude * np.sin(2.0 * math.pi * self.f * t + self.phase)


PROCESSORS = {c.name: c for c in (ActuatorFade, Delay, SensorResonance, ZeroDrift, PeriodicDisturbance)}
"""The bench's own physics of each effect it injects at an ``actuator``, ``force`` or ``offset``
stage (tests/test_effects_modules.py checks these against the effects)."""


def processor(effect: Effect, fs_hz: float, rng: np.random.Generator):
    """A fresh streaming processor for an actuator, force or offset effect."""
    cls = PROCESSORS[effect.name]
    return cls(effect.params, fs_hz, rng) if getattr(cls, "seeded", False) else cls(effect.params, fs_hz)
