"""A family of plants: plant number N, its parameters drawn (seeded by N) from physical ranges.

Calibrate on some plants, report on others (docs/BENCH.md "A family of plants"):

- :data:`CALIBRATION_DRAWS` (1–49) are for calibration and development: a threshold, a weight,
  a default or a structure may be chosen on them;
- :data:`REPORTING_DRAWS` (100–199) are for reporting only: a figure of generality is a
  distribution over them, and nothing is ever chosen on them;
- draw 0 is our bench (:class:`~hil_sim.plant.PlantParams`, :class:`~hil_sim.sensors.SensorParams`
  and :class:`~hil_sim.physics.BenchPhysics` defaults), bit for bit.

Each parameter of :data:`RANGES` is drawn from its own stream, ``SeedSequence([N, crc32(name)])``,
uniform in ``[lo, hi]`` (``scale`` ``"lin"``) or in ``[log lo, log hi]`` (``"log"``): a parameter
added to the table later does not change the others' draws. The rig (wing, tunnel, actuators'
law, transducer scaling: :class:`~hil_sim.physics.BenchPhysics`) is the same for every draw, so
the host's default calibration describes every plant of the family; what differs is the flow
(the truth plant) and the measurement chain (buffeting, noise, the balance, the DAQ's filter).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, replace

import numpy as np

from hil_sim.physics import BenchPhysics
from hil_sim.plant import PlantParams
from hil_sim.sensors import SensorParams
from rtlift.core.errors import UserError

CALIBRATION_DRAWS: tuple[int, ...] = tuple(range(1, 50))
"""Plants for calibration and development: choices may be made on them."""
REPORTING_DRAWS: tuple[int, ...] = tuple(range(100, 200))
"""Plants for reporting only: never used for a choice."""


@dataclass(frozen=True)
class Range:
    """Where one parameter of a plant of the family is drawn from (module docstring)."""

    part: str
    """``"plant"`` (:class:`PlantParams`) or ``"sensor"`` (:class:`SensorParams`)."""
    lo: float
    hi: float
    scale: str
    """``"lin"``: uniform in [lo, hi]; ``"log"``: log-uniform."""
    source: str
    """Where the range comes from (docs/BENCH.md repeats it)."""

    def draw(self, rng: np.random.Generator) -> float:
        u = float(rng.random())
        if self.scale == "log":
            return math.exp(math.log(self.lo) + u * (math.log(self.hi) - math.log(self.lo)))
        return self.lo + u * (self.hi - self.lo)


RANGES: dict[str, Range] = {
    # the flow (hil_sim/plant.py); our bench's value is the centre unless said
    "delay_tplus": Range("plant", 0.0, 0.4, "lin",
                         "vortex from the slot to the separated shear layer at 0.5–0.7 U∞ over 0–0.2 c; "
                         "our bench 0 (the edge)"),
    "circulation_tplus": Range("plant", 0.6, 1.6, "lin",
                               "circulation build-up behind the attached fraction, Wagner-like ≈ 1 t⁺"),
    "tau_s_tplus": Range("plant", 2.0, 4.5, "lin",
                         "relaxation to stall over a few t⁺ (Amitay & Glezer 2002; Darabi & Wygnanski 2004)"),
    "beta_per_s": Range("plant", 2000.0, 4500.0, "log", "burst effectiveness; bench 3000 s⁻¹ ×/÷ 1.5"),
    "c_sat": Range("plant", 0.013, 0.032, "log", "effectiveness saturation; bench 0.02 ×/÷ 1.6"),
    "lift_attached": Range("plant", 0.21, 0.32, "lin", "L_a, ΔCL of the attached flow; bench 0.265 ± 20 %"),
    "vortex_gain": Range("plant", 90.0, 155.0, "log", "V, the burst vortex's lift; bench 120 ×/÷ 1.3"),
    "vortex_tau_tplus": Range("plant", 0.6, 1.1, "lin",
                              "single-burst peak 1–2 t⁺ after the burst (Amitay & Glezer 2002; Williams et al. "
                              "2010)"),
    "vortex_dip_tplus": Range("plant", 0.15, 0.35, "lin", "the single burst's initial dip (same sources)"),
    "vortex_power": Range("plant", 0.1, 0.5, "lin",
                          "p, how the vortex needs separated vorticity (the static map's shape); bench 0.25"),
    "interaction": Range("plant", 0.65, 0.9, "lin",
                         "κ: trains at 1.75 t⁺ over-predicted by the convolution by > 25 % (the paper)"),
    "memory_tplus": Range("plant", 1.1, 2.0, "lin", "τ_q: a vortex at 0.5–0.7 U∞ leaves the chord in 1.5–2 t⁺"),
    # the measurement chain (hil_sim/sensors.py)
    "buffet_hz": Range("sensor", 5.0, 10.0, "lin",
                       "natural shedding St = f c sin α / U∞ ≈ 0.14–0.28 (bluff-body shedding of a stalled wing); "
                       "bench 7 Hz"),
    "buffet_q": Range("sensor", 1.0, 2.5, "lin", "a broad shedding peak; bench 1.5"),
    "buffet_sigma": Range("sensor", 0.002, 0.0045, "log", "buffeting level in stalled flow; bench 0.003"),
    "turbulence_sigma": Range("sensor", 0.001, 0.0022, "log", "tunnel turbulence; bench 0.0015"),
    "turbulence_corner_hz": Range("sensor", 5.0, 100.0, "log",
                                  "colour of the turbulence (a first-order corner); bench white"),
    "electrical_sigma": Range("sensor", 0.0012, 0.0027, "log", "amplifier and ADC noise; bench 0.0018"),
    "balance_hz": Range("sensor", 90.0, 180.0, "lin",
                        "the balance's mode with the wing on it (a Nano17-class transducer with a light model); "
                        "above the sensor_resonance effect's 12–80 Hz; bench rigid"),
    "balance_damping": Range("sensor", 0.03, 0.15, "log", "a lightly damped structural mode"),
    "filter_hz": Range("sensor", 60.0, 180.0, "lin", "the DAQ's anti-alias low-pass below Nyquist; bench none"),
}
"""Every drawn parameter: its part, range, scale and source (docs/BENCH.md's table)."""


@dataclass(frozen=True)
class PlantDraw:
    """Plant number ``number`` of the family: the truth plant, its measurement chain and the rig."""

    number: int
    plant: PlantParams
    sensor: SensorParams
    physics: BenchPhysics

    def values(self) -> dict[str, float]:
        """The drawn parameters by name (draw 0: our bench's values)."""
        return {name: float(getattr(self.plant if r.part == "plant" else self.sensor, name))
                for name, r in RANGES.items()}


def check_draw(number: object) -> int:
    """``number`` as a plant draw (a non-negative integer), else a one-line :class:`UserError`."""
    if isinstance(number, bool) or not isinstance(number, (int, np.integer)) or number < 0:
        raise UserError(f"plant draw must be a non-negative integer, got {number!r}")
    return int(number)


def plant_draw(number: int) -> PlantDraw:
    """Plant number ``number`` of the family (module docstring); 0 is our bench."""
    n = check_draw(number)
    plant, sensor = PlantParams(), SensorParams()
    if n == 0:
        return PlantDraw(0, plant, sensor, BenchPhysics())
    drawn = {"plant": {}, "sensor": {}}
    for name, r in RANGES.items():
        rng = np.random.default_rng(np.random.SeedSequence([n, zlib.crc32(name.encode())]))
        drawn[r.part][name] = r.draw(rng)
    return PlantDraw(n, replace(plant, **drawn["plant"]), replace(sensor, **drawn["sensor"]), BenchPhysics())


def draws_line(draws: tuple[int, ...] | list[int]) -> str:
    """How a benchmark says which draws it used: ``plant draws: 100-119 (reporting)``."""
    ds = sorted(set(int(d) for d in draws))
    if not ds:
        return "plant draws: none"
    runs, start = [], ds[0]
    for a, b in zip(ds, [*ds[1:], None], strict=True):
        if b != a + 1:
            runs.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    kinds = sorted({"reporting" if d in REPORTING_DRAWS else "calibration" if d in CALIBRATION_DRAWS
                    else "bench" if d == 0 else "other" for d in ds})
    return f"plant draws: {','.join(runs)} ({', '.join(kinds)})"


def static_lift(plant: PlantParams, cmu: float, seconds: float = 6.0) -> float:
    """Noise-free ΔCL of the plant under bursts at the lift-optimal 8 Hz of Cμ ``cmu``: the mean
    over the last 2 s of ``seconds`` from stall (the static map's point at ``cmu``)."""
    from hil_sim import FS_HZ
    from hil_sim.actuation import OPTIMAL_PERIOD_SAMPLES, burst_gate
    from hil_sim.plant import TruthPlant

    n = int(seconds * FS_HZ)
    c = np.where(burst_gate(n, OPTIMAL_PERIOD_SAMPLES), cmu, 0.0)
    dcl = TruthPlant(plant).process(c, np.full(n, cmu))["dcl"]
    return float(dcl[-int(2 * FS_HZ):].mean())


def single_burst(plant: PlantParams, cmu: float = 0.0022, tplus: float = 12.0) -> np.ndarray:
    """Noise-free ΔCL after one burst of Cμ ``cmu`` from stall, ``tplus`` convective times long."""
    from hil_sim import FS_HZ, T_CONV_S
    from hil_sim.actuation import BURST_SAMPLES
    from hil_sim.plant import TruthPlant

    n = int(round(tplus * T_CONV_S * FS_HZ))
    c = np.zeros(n)
    c[:BURST_SAMPLES] = cmu
    return TruthPlant(plant).process(c, np.where(c > 0, cmu, 0.0))["dcl"]


PROPERTY_CMUS = (0.0055, 0.011, 0.0165, 0.022)
"""The static map's points :func:`properties` reads (Cμ, 8 Hz bursts): a quarter of full Cμ to full."""


def properties(number: int) -> dict[str, float]:
    """docs/BENCH.md's properties of plant ``number``, noise-free (the plant alone):

    - ``full``: ΔCL at Cμ 0.022 (8 Hz bursts); ``half_over_full``: ΔCL(0.011)/ΔCL(0.022) (> ½:
      concave); ``slope_ratio``: the static map's slope over its first quarter over that of its
      last quarter (> 1: saturating);
    - the single burst at Cμ 0.0022 (60 V): ``burst_peak`` (ΔCL), ``burst_peak_tplus`` (t⁺ after
      the burst), ``burst_dip`` (the least ΔCL before the peak), ``burst_tail``: the largest
      |ΔCL| 7 t⁺ and more after the burst over the peak."""
    from hil_sim import FS_HZ, T_CONV_S

    p = plant_draw(number).plant
    s = np.array([static_lift(p, c) for c in PROPERTY_CMUS])
    slopes = np.diff(np.concatenate([[0.0], s]))
    kernel = single_burst(p)
    k = int(np.argmax(kernel))
    return {"full": float(s[-1]), "half_over_full": float(s[1] / s[-1]), "slope_ratio": float(slopes[0] / slopes[-1]),
            "burst_peak": float(kernel[k]), "burst_peak_tplus": float(k / FS_HZ / T_CONV_S),
            "burst_dip": float(kernel[:k].min()),
            "burst_tail": float(np.abs(kernel[int(7 * T_CONV_S * FS_HZ):]).max() / kernel[k])}
