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

``EFFECTS[name]`` holds the bench stage and the shared schema of :mod:`rtlift.core.effects` (defaults,
documented ranges ``ranges[param] = (lo, hi)``, ``draw(rng)``); ``parse_effect(spec)`` raises
:class:`~rtlift.core.errors.UserError` on a bad spec.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from scipy import signal

from rtlift.core.effects import SCHEMAS, EffectSchema
from rtlift.core.errors import UserError


@dataclass(frozen=True)
class EffectInfo:
    """One effect kind on the bench: where it acts here, and its shared parameter schema
    (:data:`rtlift.core.effects.SCHEMAS`: meaning, defaults, documented ranges)."""

    stage: str
    schema: EffectSchema

    name = property(lambda self: self.schema.name)
    defaults = property(lambda self: self.schema.defaults)
    ranges = property(lambda self: self.schema.ranges)
    meaning = property(lambda self: self.schema.meaning)
    alternatives = property(lambda self: self.schema.alternatives)

    def draw(self, rng: np.random.Generator) -> Effect:
        """Parameters drawn uniformly from ``ranges`` (one parameter set for zero_drift)."""
        return Effect(self.name, self.schema.draw(rng))


BENCH_ONLY: Mapping[str, Mapping[str, float]] = MappingProxyType({"actuator_fade": {"onset_s": 0.0}})
"""Parameters the bench takes beyond the shared schema (what the plant does, not what a model
fits): ``actuator_fade:onset_s`` — the actuators start heating (on-time counted) from this
device time on, so a fade can set in during a run."""

STAGE_ON_BENCH = {"delay": "force", "sensor_resonance": "force", "actuator_fade": "actuator",
                  "zero_drift": "offset", "periodic_disturbance": "offset", "hysteresis": "plant"}
EFFECTS: Mapping[str, EffectInfo] = MappingProxyType({name: EffectInfo(stage, SCHEMAS[name])
                                                      for name, stage in STAGE_ON_BENCH.items()})


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
    if name == "zero_drift":
        sets = [set(info.defaults), *map(set, info.alternatives)]
        if set(params) not in sets:
            raise UserError(f"effect {spec!r}: zero_drift takes rate_per_s, or amplitude and "
                            "time_constant_s")
    for key, value in params.items():
        if not math.isfinite(value):
            raise UserError(f"effect {spec!r}: {key} must be a finite number")
    if params.get("onset_s", 0.0) < 0:
        raise UserError(f"effect {spec!r}: onset_s must be at least 0, got {params['onset_s']:g}")
    positive = {"seconds", "frequency_hz", "damping_ratio", "time_constant_s"}
    for key in positive & set(params):
        if params[key] <= 0:
            raise UserError(f"effect {spec!r}: {key} must be positive, got {params[key]:g}")
    if name == "actuator_fade" and not 0.0 <= params["final_fraction"] <= 1.0:
        raise UserError(f"effect {spec!r}: final_fraction must be in [0, 1]")
    if name == "hysteresis" and not -0.9 < params["magnitude"] < 5.0:
        raise UserError(f"effect {spec!r}: magnitude must be in (-0.9, 5)")
    if name == "sensor_resonance" and params["frequency_hz"] >= 190.0:
        raise UserError(f"effect {spec!r}: frequency_hz must be below 190 Hz (fs = 400 Hz)")
    if name == "delay" and params["seconds"] > 10.0:
        raise UserError(f"effect {spec!r}: seconds must be at most 10")


def parse_effect(spec: str) -> Effect:
    """``NAME[:k=v,...]`` → :class:`Effect`; missing parameters take the defaults."""
    text = spec.strip()
    name, _, rest = text.partition(":")
    name = name.strip()
    if name not in EFFECTS:
        raise UserError(f"unknown effect {name!r} in {spec!r} (known: {', '.join(EFFECTS)})")
    info = EFFECTS[name]
    known = set(info.ranges) | set(BENCH_ONLY.get(name, {}))
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
    params = dict(info.defaults)
    params.update({k: v for k, v in BENCH_ONLY.get(name, {}).items() if k in given})
    if name == "zero_drift" and given and "rate_per_s" not in given:
        params = {"amplitude": 0.02, "time_constant_s": 20.0}
    params.update(given)
    _check(name, params, spec)
    return Effect(name, params)


def as_effect(effect: Effect | str) -> Effect:
    return effect if isinstance(effect, Effect) else parse_effect(effect)


# -- streaming processors (one per effect per bench run, state carried between chunks) ----

class ActuatorFade:
    """``actuator_fade``: Cμ · (f + (1 − f) exp(−E/τ)), E = burst on-time so far (s),
    counted from device time ``onset_s`` on (0: from the start)."""

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

    def __init__(self, params: Mapping[str, float], fs_hz: float) -> None:
        self.params = params

    def process(self, t: np.ndarray) -> np.ndarray:
        p = self.params
        if "rate_per_s" in p:
            return p["rate_per_s"] * t
        return p["amplitude"] * (1.0 - np.exp(-t / p["time_constant_s"]))


class PeriodicDisturbance:
    """``periodic_disturbance``: A sin(2π f t + φ₀) as sampled, φ₀ from the seed."""

    def __init__(self, params: Mapping[str, float], fs_hz: float,
                 rng: np.random.Generator) -> None:
        self.f = params["frequency_hz"]
        self.amplitude = params["amplitude"]
        self.phase = float(rng.uniform(0.0, 2.0 * math.pi))

    def process(self, t: np.ndarray) -> np.ndarray:
        return self.amplitude * np.sin(2.0 * math.pi * self.f * t + self.phase)


def processor(effect: Effect, fs_hz: float, rng: np.random.Generator):
    """A fresh streaming processor for an actuator, force or offset effect."""
    kinds = {"actuator_fade": ActuatorFade, "delay": Delay, "sensor_resonance": SensorResonance,
             "zero_drift": ZeroDrift}
    if effect.name == "periodic_disturbance":
        return PeriodicDisturbance(effect.params, fs_hz, rng)
    return kinds[effect.name](effect.params, fs_hz)
