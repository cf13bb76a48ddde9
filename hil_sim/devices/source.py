"""What the emulated DAQ streams: chunks of bench samples (``volts``, ``envelope_volts``,
``counts`` n×6 int, ``status`` u8), as ``hil_sim.experiments.daq_stream`` yields them,
turned into the integers each wire format carries."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from firmware_io.can_codec import FT_FORCE_ID, FT_TORQUE_ID, load_dbc
from hil_sim.physics import BenchPhysics
from rtlift.core.rate import FS_HZ

I16 = (-32768, 32767)
I32 = (-(2**31), 2**31 - 1)


@dataclass
class WireChunk:
    """Per-sample integers of one chunk, as Python lists (cheap to index in the 400 Hz loop)."""

    volt_cv: list[int]
    envelope_cv: list[int]
    status: list[int]
    ft: list[tuple[int, ...]]
    """Serial: six transducer counts (i32). CAN: fx fy fz tx ty tz raw DBC values (i16)."""

    def __len__(self) -> int:
        return len(self.volt_cv)


def _cv(volts: np.ndarray, lo: int, hi: int) -> list[int]:
    return np.clip(np.rint(np.asarray(volts, dtype=float) * 100.0), lo, hi).astype(np.int64).tolist()


def serial_wire(chunk: object) -> WireChunk:
    """Serial packet fields: drive i16 cV, envelope u16 cV, counts i32 (saturated)."""
    counts = np.clip(np.asarray(chunk.counts, dtype=np.int64), *I32).reshape(-1, 6)
    return WireChunk(_cv(chunk.volts, *I16), _cv(chunk.envelope_volts, 0, 65535),
                     (np.asarray(chunk.status, dtype=np.int64) & 0xFF).tolist(),
                     [tuple(row) for row in counts.tolist()])


def can_wire(chunk: object, physics: BenchPhysics | None = None) -> WireChunk:
    """CAN frame fields: drive and envelope u16 cV, forces/torques in the DBC's raw units
    (counts → N, N·m with the transducer's own scaling, :mod:`hil_sim.physics`; then ÷ DBC scale)."""
    phys = physics or BenchPhysics()
    db = load_dbc()
    f_scale = db.get_message_by_frame_id(FT_FORCE_ID).get_signal_by_name("fx").scale
    t_scale = db.get_message_by_frame_id(FT_TORQUE_ID).get_signal_by_name("tx").scale
    counts = np.asarray(chunk.counts, dtype=float).reshape(-1, 6)
    raw = phys.si(counts) / np.array([f_scale] * 3 + [t_scale] * 3)
    raw = np.clip(np.rint(raw), *I16).astype(np.int64)
    return WireChunk(_cv(chunk.volts, 0, 65535), _cv(chunk.envelope_volts, 0, 65535),
                     (np.asarray(chunk.status, dtype=np.int64) & 0xFF).tolist(),
                     [tuple(row) for row in raw.tolist()])


def synthetic_stream(seed: int = 0, fs_hz: float = FS_HZ, physics: BenchPhysics | None = None
                     ) -> Iterator[SimpleNamespace]:
    """A stand-in for ``daq_stream``: one-second chunks of bursts (4 samples every 50) whose
    amplitude follows a slow sine, forces with a burst-following lift and noise, forever."""
    phys = physics or BenchPhysics()
    rng = np.random.default_rng(seed)
    n = int(round(fs_hz))
    k0 = 0
    while True:
        k = np.arange(k0, k0 + n)
        env = 30.0 + 30.0 * np.sin(2 * np.pi * k / (2.0 * fs_hz))
        burst = (k % 50) < 4
        volts = np.where(burst, env, 0.0)
        ft = np.zeros((n, 6))
        ft[:, 0] = -0.5 + 0.02 * rng.standard_normal(n)
        ft[:, 2] = 2.0 + 0.004 * volts + 0.02 * rng.standard_normal(n)
        ft[:, 4] = 0.01 + 0.001 * rng.standard_normal(n)
        counts = np.rint(phys.counts(ft)).astype(np.int64)
        status = (1 | np.where(burst, 8, 0)).astype(np.uint8)
        yield SimpleNamespace(volts=volts, envelope_volts=env, counts=counts, status=status)
        k0 += n


def wire_samples(chunks: Iterable[object], to_wire) -> Iterator[tuple[int, int, int, tuple[int, ...]]]:
    """(volt_cv, envelope_cv, status, ft) per sample, chunk after chunk."""
    for chunk in chunks:
        w = to_wire(chunk)
        yield from zip(w.volt_cv, w.envelope_cv, w.status, w.ft, strict=True)
