"""The bench as a real-time hardware-in-the-loop plant (PROTOCOL.md "Version 2", the plant hook).

:class:`HilStream` is what a device emulator streams: the experiment's chunks, exactly as
:func:`hil_sim.experiments.daq_stream` yields them, until the device is under host control
(``control.applied`` is set: a command was applied). From the next burst onset on, the truth
plant is driven by the firmware's commanded envelope instead, one burst period at a time:

- at each burst onset the envelope is latched from :attr:`HostControl.envelope_cv` (already
  clamped to the actuator limit, 0 when disabled, on its ramp to 0 after the watchdog), so the
  envelope changes only at burst onsets — the update rate the bursts allow;
- the burst period is the commanded ``burst_period_ms`` (default: the lift-optimal 8 Hz);
- after a watchdog trip the firmware ramps the envelope to 0 over
  :data:`~hil_sim.devices.host_control.WATCHDOG_RAMP_MS` (100 ms, 40 samples); each onset
  during the ramp latches the ramp's value there (the period starting at onset k is computed
  when the device reads sample k, before it steps the command side for k: it gets the value
  after sample k − 1), later onsets 0, until the next applied command. At the default 125 ms
  period that is at most one reduced burst, then none.

The plant is stepped on demand: the device asks for the next samples when it needs them, so
the period starting at an onset is computed from the command state at that instant. Before
host control the stream is yielded in burst-period slices of the precomputed one-second
chunks; at the switch the bench's state is recomputed exactly up to the onset from a copy
taken at the chunk's start, so the version-1 stream is unchanged sample for sample.

``truth`` keeps the plant's ΔCL of the last ``truth_seconds`` and ``envelope`` the envelope
driving it (V) (bench truth for benchmarks and tests; the host never sees it). A ``gust``
(:mod:`hil_sim.gust`) is added to the plant's ΔCL on the device clock and is part of ``truth``.
``plant_draw`` N streams plant number N of the family (:mod:`hil_sim.family`; 0: our bench).
"""

from __future__ import annotations

import copy
from collections import deque
from collections.abc import Iterable, Iterator
from types import SimpleNamespace

import numpy as np

from firmware_io.calibration import Calibration
from hil_sim import FS_HZ
from hil_sim.actuation import BURST_SAMPLES, OPTIMAL_PERIOD_SAMPLES, burst_gate
from hil_sim.effects import Effect
from hil_sim.experiments import _setup
from hil_sim.gust import Gust

CHUNK_SAMPLES = int(FS_HZ)
"""The experiment's precomputed chunk (one second), a multiple of the burst period."""
FIELDS = ("t", "volts", "envelope_volts", "cmu", "cmu_envelope", "dcl_true", "counts", "status")


def _slice(run: object, lo: int, hi: int) -> SimpleNamespace:
    return SimpleNamespace(**{f: getattr(run, f)[lo:hi] for f in FIELDS})


def _concatenated(pieces: deque[tuple[int, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    if not pieces:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    idx = np.concatenate([k0 + np.arange(len(d)) for k0, d in pieces])
    return idx, np.concatenate([d for _, d in pieces])


class HilStream:
    """Iterable of bench chunks that obeys ``control`` (a :class:`~hil_sim.devices.host_control.
    HostControl`, attached after the device is built: ``stream.control = device.control``)."""

    def __init__(self, experiment: str, seed: int = 0, effects: Iterable[Effect | str] = (),
                 calibration: Calibration | None = None, truth_seconds: float = 600.0,
                 gust: Gust | None = None, plant_draw: int = 0) -> None:
        (self._env, self._gate), self.bench, self.meta = _setup(experiment, seed, effects, calibration, gust,
                                                                plant_draw=plant_draw)
        self.control = None
        self.host_since: int | None = None
        """Sample index of the first host-controlled burst onset (``None``: not yet)."""
        self.truth: deque[tuple[int, np.ndarray]] = deque(
            maxlen=max(1, int(truth_seconds * FS_HZ / BURST_SAMPLES)))
        """(first sample index, ΔCL of the plant) per yielded piece."""
        self.envelope: deque[tuple[int, np.ndarray]] = deque(maxlen=self.truth.maxlen)
        """(first sample index, envelope driving the plant in V) per yielded piece."""
        self.envelope_cv_applied = 0
        """The envelope driving the plant in the current burst period (0.01 V)."""

    def _under_control(self) -> bool:
        return self.control is not None and self.control.applied is not None

    def truth_array(self) -> tuple[np.ndarray, np.ndarray]:
        """(sample index, ΔCL truth) of what ``truth`` still holds, concatenated."""
        return _concatenated(self.truth)

    def envelope_array(self) -> tuple[np.ndarray, np.ndarray]:
        """(sample index, envelope in V) of what ``envelope`` still holds, concatenated."""
        return _concatenated(self.envelope)

    def __iter__(self) -> Iterator[SimpleNamespace]:
        n = len(self._env)
        k = 0
        while not self._under_control():
            snapshot = copy.deepcopy(self.bench)
            idx = np.arange(k, k + CHUNK_SAMPLES)
            run = self.bench.process(idx / FS_HZ, self._env[idx % n], self._gate[idx % n], self.meta)
            for off in range(0, CHUNK_SAMPLES, OPTIMAL_PERIOD_SAMPLES):
                if self._under_control():
                    self.bench = snapshot
                    if off:
                        part = idx[:off]
                        self.bench.process(part / FS_HZ, self._env[part % n], self._gate[part % n],
                                           self.meta)
                    k += off
                    break
                piece = _slice(run, off, off + OPTIMAL_PERIOD_SAMPLES)
                self.truth.append((k + off, piece.dcl_true))
                self.envelope.append((k + off, piece.envelope_volts))
                yield piece
            else:
                k += CHUNK_SAMPLES
        self.host_since = k
        yield from self._host_controlled(k)

    def _host_controlled(self, k: int) -> Iterator[SimpleNamespace]:
        ctl = self.control
        while True:
            ms = ctl.burst_period_ms
            period = OPTIMAL_PERIOD_SAMPLES if not ms else max(BURST_SAMPLES + 1,
                                                               int(round(ms * FS_HZ / 1000.0)))
            env_cv = ctl.envelope_cv if ctl.enabled else 0
            self.envelope_cv_applied = env_cv
            idx = np.arange(k, k + period)
            run = self.bench.process(idx / FS_HZ, np.full(period, env_cv / 100.0), burst_gate(period, period),
                                     self.meta)
            self.truth.append((k, run.dcl_true))
            self.envelope.append((k, run.envelope_volts))
            yield run
            k += period
