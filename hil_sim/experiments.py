"""The standard campaign at 400 Hz on the bench that runs it (docs/BENCH.md).

The experiments are programs (:mod:`rtlift.core.programs`: one definition for the bench,
``rtlift bench serve`` and ``rtlift record``). The bench puts ``TARE_S`` = 2 s actuator-off in
front of each and renders it per sample (:meth:`~rtlift.core.programs.Program.render`): the
envelope as the program gives it, bursts of 4 samples at the program's onsets. Programs
(envelope as Cμ, burst rate):

- ``static``: bursts at 8 Hz, envelope ramped 0 → 0.022 in 40 s, held 2 s, back to 0 in 40 s
  (slow against the ≈ 1 s reattachment, so the branches coincide), then 2 s off;
- ``single_burst``: 20 isolated bursts at Cμ 0.0022 (60 V), 12 t⁺ apart (phase averaging);
- ``train_T1p75`` / ``train_T3p5`` / ``train_T7``: 10 bursts at 60 V every T, three times,
  with 15 t⁺ rests;
- ``sine_k0125`` / ``sine_k025``: envelope ``0.011 − 0.010 cos(2π f t)``, k = π f c / U∞,
  20 / 40 periods, bursts at the lift-optimal 8 Hz;
- ``random``: band-limited random envelope (Gaussian noise through a 2nd-order 1 Hz
  Butterworth low-pass, mean 0.011, σ 0.0055, clipped to [0.0005, 0.0215]), 58 s, 8 Hz.

The whole campaign is ≈ 301 s of data.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from firmware_io.calibration import Calibration
from hil_sim import FS_HZ, T_CONV_S
from hil_sim.actuation import BURST_SAMPLES, actuate_volts
from hil_sim.effects import Effect, as_effect, processor
from hil_sim.gust import Gust
from hil_sim.physics import BenchPhysics
from hil_sim.plant import PlantParams, TruthPlant
from hil_sim.sensors import (
    STATUS_ACTUATOR_ENABLED,
    STATUS_ADC_SATURATED,
    STATUS_BURST_ON,
    AeroNoise,
    BalanceChain,
    SensorParams,
    coefficients,
    transducer,
)
from rtlift.core.errors import UserError
from rtlift.core.programs import (  # noqa: F401 - the campaign's names, as the bench's users know them
    EXPERIMENTS,
    SINE_CMU_AMPLITUDE,
    SINE_CMU_MEAN,
    SINGLE_BURSTS,
    SINGLE_SPACING_TPLUS,
    STATIC_RAMP_S,
    TARE_S,
    TRAIN_BURSTS,
    TRAIN_REPEATS,
    TRAIN_REST_TPLUS,
    Experiment,
    Program,
    reduced_frequency_hz,
    standard_program,
)
from rtlift.core.records import Record

TARE_SAMPLES = int(TARE_S * FS_HZ)


@dataclass
class BenchRun:
    """What the bench produced, sample by sample at ``fs_hz`` (DESIGN.md "Simulated bench")."""

    t: np.ndarray
    volts: np.ndarray
    envelope_volts: np.ndarray
    cmu: np.ndarray
    cmu_envelope: np.ndarray
    dcl_true: np.ndarray
    counts: np.ndarray
    status: np.ndarray
    meta: dict[str, str] = field(default_factory=dict)
    calibration: Calibration = field(default_factory=Calibration)
    fs_hz: float = FS_HZ
    dcl_sensed: np.ndarray | None = None
    """The noise-free ΔCL as the measurement chain passes it (the balance's mode, the DAQ's filter:
    :class:`~hil_sim.sensors.BalanceChain`), on a plant that has one; else ``None`` (it is ``dcl_true``)."""

    def __len__(self) -> int:
        return len(self.t)

    def to_record(self, name: str | None = None) -> Record:
        """The record the host would write: ΔCL from the counts with the calibration, tared."""
        cal = self.calibration
        cl = np.asarray(cal.cl_from_ft(cal.ft_from_counts(self.counts)))
        tare = cal.tare_cl if cal.tare_cl is not None else cal.tare_from(cl, self.volts, self.fs_hz)
        cmu = np.asarray(cal.cmu_from_volts(self.volts), dtype=float)
        env = np.asarray(cal.cmu_from_volts(self.envelope_volts), dtype=float)
        extra = {"volts": self.volts.copy(), "envelope_volts": self.envelope_volts.copy(),
                 "dcl_true": self.dcl_true.copy()}
        if self.dcl_sensed is not None:
            extra["dcl_sensed"] = self.dcl_sensed.copy()
        return Record(self.t.copy(), cmu, env, cl - tare, dict(self.meta), extra,
                      name or self.meta.get("experiment", "bench"))


class Bench:
    """Actuator chain → truth plant → sensor chain, streaming over chunks with its state."""

    def __init__(self, seed: int, effects: Sequence[Effect], calibration: Calibration,
                 plant: PlantParams | None = None, sensor: SensorParams | None = None,
                 gust: Gust | None = None, physics: BenchPhysics | None = None) -> None:
        self.calibration = calibration
        """The host's calibration: what :meth:`BenchRun.to_record` converts the counts with (the host's part)."""
        self.physics = physics or BenchPhysics()
        """The rig's own constants: what the truth is made with (:mod:`hil_sim.physics`)."""
        self.gust = gust or Gust()
        """Lift disturbance added to the plant's ΔCL (:mod:`hil_sim.gust`), part of the truth."""
        self.fs_hz = FS_HZ
        streams = np.random.SeedSequence(seed).spawn(2 + len(effects))
        self.sensor_rng = np.random.Generator(np.random.PCG64(streams[0]))
        aero_rng = np.random.Generator(np.random.PCG64(streams[1]))
        params = plant or PlantParams()
        for e in effects:      # a plant effect adds to the plant's parameters (its registry record says which)
            params = params.plus({to: e.params[key] for key, to in e.info.bench.plant.items()})
        self.plant = TruthPlant(params, self.fs_hz)
        self.sensor = sensor or SensorParams()
        self.aero_noise = AeroNoise(self.sensor, aero_rng, self.fs_hz)
        chain = BalanceChain(self.sensor, self.fs_hz)
        self.chain = chain if chain else None
        self.sensing = BalanceChain(self.sensor, self.fs_hz) if chain else None
        """The same chain with its own state, passing the noise-free ΔCL (``BenchRun.dcl_sensed``)."""
        self.stages: dict[str, list] = {"actuator": [], "force": [], "offset": []}
        for e, s in zip(effects, streams[2:], strict=True):
            if e.stage in self.stages:
                self.stages[e.stage].append(
                    processor(e, self.fs_hz, np.random.Generator(np.random.PCG64(s))))

    def process(self, t: np.ndarray, env_volts: np.ndarray, gate: np.ndarray,
                meta: dict[str, str]) -> BenchRun:
        """Envelope (V) and burst gate per sample through the actuator, plant and sensor chains."""
        act = actuate_volts(env_volts, gate, self.physics)
        delivered = act.cmu
        for stage in self.stages["actuator"]:
            delivered = stage.process(delivered)
        out = self.plant.process(delivered, act.cmu_envelope)
        dcl_true = out["dcl"]
        if self.gust:
            dcl_true = dcl_true + self.gust.at(t)
        coeffs = coefficients(dcl_true, self.aero_noise.process(out["attached"]), self.sensor)
        for stage in self.stages["force"]:
            coeffs = stage.process(coeffs)
        for stage in self.stages["offset"]:
            coeffs[:, 0] += stage.process(t)
        counts, saturated = transducer(coeffs, self.physics, self.sensor, self.sensor_rng, self.chain)
        status = (np.where(act.envelope_volts > 0, STATUS_ACTUATOR_ENABLED, 0)
                  | np.where(saturated, STATUS_ADC_SATURATED, 0)
                  | np.where(act.burst, STATUS_BURST_ON, 0)).astype(np.uint8)
        return BenchRun(t, act.volts, act.envelope_volts, act.cmu, act.cmu_envelope, dcl_true,
                        counts, status, dict(meta), self.calibration, self.fs_hz, self._sensed(dcl_true))

    def _sensed(self, dcl_true: np.ndarray) -> np.ndarray | None:
        """ΔCL through the balance's mode and the DAQ's filter, noise-free (linear, unit DC gain:
        the same as the lift the forces carry, less the noise)."""
        if self.sensing is None:
            return None
        x = dcl_true[:, None]
        for stage in (self.sensing.mode, self.sensing.filter):
            if stage is not None:
                x = stage.process(x)
        return x[:, 0]


def bench_program(program: Program) -> tuple[np.ndarray, np.ndarray]:
    """``TARE_S`` off, then the program rendered per sample: (envelope V, burst gate)."""
    env, gate = program.render(FS_HZ, BURST_SAMPLES)
    return (np.concatenate([np.zeros(TARE_SAMPLES), env]),
            np.concatenate([np.zeros(TARE_SAMPLES, dtype=bool), gate]))


def _setup(name: str, seed: int, effects: Iterable[Effect | str], calibration: Calibration | None,
           gust: Gust | None = None, physics: BenchPhysics | None = None, plant_draw: int = 0
           ) -> tuple[tuple[np.ndarray, np.ndarray], Bench, dict[str, str]]:
    from hil_sim.family import plant_draw as draw_plant

    if name not in EXPERIMENTS:
        raise UserError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise UserError(f"seed must be a non-negative integer, got {seed!r}")
    drawn = draw_plant(plant_draw)
    effs = [as_effect(e) for e in effects]
    cal = calibration or Calibration()
    program = standard_program(name, cal.volts_from_cmu, int(seed), FS_HZ)
    meta = {"experiment": name, "fs_hz": f"{FS_HZ:g}", "seed": str(int(seed)),
            "effects": "; ".join(e.spec() for e in effs) or "none",
            "source": "hil_sim truth plant (docs/BENCH.md)",
            "t_conv_s": f"{T_CONV_S:.6f}", "burst_samples": str(BURST_SAMPLES)}
    if gust:
        meta["gust"] = gust.spec()
    if drawn.number:    # draw 0 is today's bench: its records are today's, byte for byte
        meta["plant_draw"] = str(drawn.number)
    bench = Bench(int(seed), effs, cal, plant=drawn.plant, sensor=drawn.sensor, gust=gust,
                  physics=physics or drawn.physics)
    return bench_program(program), bench, meta


def run_experiment(name: str, seed: int = 0, effects: Iterable[Effect | str] = (),
                   calibration: Calibration | None = None, gust: Gust | None = None,
                   physics: BenchPhysics | None = None, plant_draw: int = 0) -> BenchRun:
    """One experiment of the standard campaign on the simulated bench (``gust``: a lift
    disturbance added to the truth, :mod:`hil_sim.gust`). ``physics`` is the rig (default: the
    paper's wing, :mod:`hil_sim.physics`); ``calibration`` the host's, which turns the program's Cμ
    into drive volts and the counts into the record (default: the one describing the default rig).
    ``plant_draw`` N is plant number N of the family (:func:`hil_sim.family.plant_draw`; 0 is our
    bench); the record's metadata says ``plant_draw: N`` when N ≠ 0."""
    (env, gate), bench, meta = _setup(name, seed, effects, calibration, gust, physics, plant_draw)
    t = np.arange(len(env)) / FS_HZ
    return bench.process(t, env, gate, meta)


def daq_stream(name: str, seed: int = 0, effects: Iterable[Effect | str] = (),
               calibration: Calibration | None = None,
               chunk_s: float = 1.0, plant_draw: int = 0) -> Iterator[BenchRun]:
    """One-second chunks forever: the experiment's program repeated, plant state continuing
    (``plant_draw``: as :func:`run_experiment`)."""
    (env, gate), bench, meta = _setup(name, seed, effects, calibration, plant_draw=plant_draw)
    n = len(env)
    chunk = max(1, int(round(chunk_s * FS_HZ)))
    start = 0
    while True:
        k = np.arange(start, start + chunk)
        idx = k % n
        yield bench.process(k / FS_HZ, env[idx], gate[idx], meta)
        start += chunk


def write_bench_record(run: BenchRun, path: str | os.PathLike) -> None:
    """Write ``run.to_record()`` as a record CSV; :class:`UserError` if the path is unwritable."""
    from rtlift.core.records import write_record

    try:
        write_record(path, run.to_record())
    except OSError as exc:
        raise UserError(f"{path}: cannot write record ({exc.strerror or exc})") from None
