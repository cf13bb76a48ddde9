"""Seeded fault injectors on the wire (serial COBS packets, CAN frames) that count exactly what a
decoder must report, and the soak that runs a long stream of them through the decoder, the
converter and the observer loop (``benchmarks/soak.py`` is its command line; the fault-matrix tests
run it on half a minute). The fault kinds are those of :data:`hil_sim.devices.faults.WIRE_FAULTS`
(one vocabulary with the pty devices' ``--fault`` plans)."""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field

import numpy as np

from firmware_io.calibration import Calibration
from firmware_io.can_codec import SEQ_MODULUS as CAN_SEQ_MODULUS
from firmware_io.can_codec import CanAssembler, encode_sample_frames, load_dbc
from firmware_io.convert import Converter
from firmware_io.serial_codec import SEQ_MODULUS, SerialDecoder, encode_event, encode_sample
from hil_sim.devices.faults import WIRE_FAULTS
from hil_sim.devices.serial_daq import cobs_data_positions, invalid_chunks
from hil_sim.devices.source import can_wire, serial_wire, wire_samples
from hil_sim.experiments import daq_stream
from rtlift.app.live import ObserverLoop
from rtlift.core.rate import FS_HZ, PERIOD_S
from rtlift.observer import Observer, ObserverConfig
from testkit.synthetic import make_model

FS = int(FS_HZ)
PERIOD_US = int(round(PERIOD_S * 1e6))
I32 = (-(2**31), 2**31 - 1)
RATES = {
    "corrupt": 1e-3,      # one COBS data byte changed (the CRC catches it): 1 invalid packet, 1 lost
    "zero_byte": 2e-4,    # a byte in the middle becomes 0x00: 2 invalid packets, 1 lost
    "truncate": 2e-4,     # tail and delimiter cut: stub + next packet = 1 invalid packet, 2 lost
    "drop": 1e-3,         # never arrives: 1 lost
    "duplicate": 1e-3,    # sent twice: 1 duplicate
    "late": 5e-4,         # arrives after the next one: 1 lost + 1 duplicate (stale)
    "garbage": 1e-3,      # 1–32 random bytes + 0x00 before it: its invalid chunks
    "event": 1e-4,        # a firmware event packet before it
    "flag": 1e-3,         # sensor-fault or ADC-saturated status: received, predict-only
    "absurd": 2e-4,       # counts at the i32 limits: received, gated by the observer
}
CAN_RATES = {
    "corrupt": 1e-3,      # one frame truncated to DLC 4: 1 crc_error, 1 lost
    "drop": 1e-3,         # one frame never arrives: 1 lost
    "duplicate": 1e-3,    # one frame sent twice: 1 duplicate
    "late": 5e-4,         # the sample's frames arrive after the next sample's: 1 lost + 3 duplicates
    "reorder": 1e-3,      # its three frames in another order: received
    "error_frame": 2e-4,  # an error frame before it: 1 crc_error
    "foreign": 1e-3,      # another node's frame before it: ignored
    "flag": 1e-3,         # sensor-fault or ADC-saturated status: received, predict-only
    "absurd": 2e-4,       # raw forces and torques at the i16 limits: received, gated by the observer
}
assert set(RATES) | set(CAN_RATES) <= set(WIRE_FAULTS), "a fault kind outside hil_sim.devices.faults.WIRE_FAULTS"
CLEAN_EDGE = 10
"""The first and last samples are left intact (the decoder's first sample sets its seq)."""


@dataclass
class Expected:
    """What the injector did, and the decoder counters that follow from it."""

    injected: dict[str, int] = field(default_factory=lambda: dict.fromkeys(RATES, 0))
    received: int = 0
    lost: int = 0
    crc_errors: int = 0
    duplicates: int = 0
    events: int = 0
    resyncs: int = 0
    flagged_received: int = 0

    def counters(self) -> dict[str, int]:
        return {k: getattr(self, k) for k in ("received", "crc_errors", "lost", "duplicates", "events", "resyncs")}


class _Injector:
    """Seeded choice of at most one fault per sample (none near the ends)."""

    n: int
    rng: np.random.Generator
    kinds: list[str]
    edges: np.ndarray
    expected: Expected

    def _pick(self, g: int, clean: bool, status: int, values: tuple[int, ...], limits: tuple[int, int]
              ) -> tuple[str | None, int, tuple[int, ...]]:
        """(fault kind or None, status, force/torque values) of sample ``g``; flagged and
        absurd samples are made here."""
        rng = self.rng
        kind = None
        if not clean and CLEAN_EDGE <= g < self.n - CLEAN_EDGE:
            i = int(np.searchsorted(self.edges, rng.random(), side="right"))
            kind = self.kinds[i] if i < len(self.kinds) else None
        if kind is not None:
            self.expected.injected[kind] += 1
        if kind == "flag":
            status |= 0x04 if rng.random() < 0.5 else 0x02
            self.expected.flagged_received += 1
        elif kind == "absurd":
            values = (limits[int(rng.integers(2))],) * 6
        return kind, status, values


class FaultInjector(_Injector):
    """Serial wire bytes of a sample stream with seeded faults (:data:`RATES`, at most one
    per sample), counting in :attr:`expected` exactly what a decoder must report."""

    def __init__(self, n: int, seed: int = 0, rates: dict[str, float] | None = None,
                 first_seq: int = 0, first_t_us: int = 0) -> None:
        self.n = n
        self.rng = np.random.default_rng(seed)
        rates = dict(RATES if rates is None else rates)
        self.kinds = list(rates)
        self.edges = np.cumsum([rates[k] for k in self.kinds])
        self.first_seq = first_seq
        self.first_t_us = first_t_us
        self.expected = Expected()
        self._in_error = False

    # the decoder's resync rule: one per run of invalid packets
    def _valid(self, out: list[bytes], data: bytes) -> None:
        out.append(data)
        self._in_error = False

    def _invalid(self, out: list[bytes], data: bytes, chunks: int) -> None:
        out.append(data)
        if chunks:
            self.expected.crc_errors += chunks
            if not self._in_error:
                self._in_error = True
                self.expected.resyncs += 1

    def _garbage(self) -> bytes:
        while True:
            junk = bytes(self.rng.integers(0, 256, int(self.rng.integers(1, 33))).tolist()) + b"\x00"
            probe = SerialDecoder(lambda s: None)
            probe.feed(b"\x00" + junk)
            if probe.counters.received == probe.counters.events == 0:  # never by chance a valid packet
                return junk

    def wire(self, samples: Iterator[tuple[int, int, int, tuple[int, ...]]], chunk: int = FS) -> Iterator[bytes]:
        """The wire bytes, ``chunk`` samples at a time (the first chunk starts with 0x00)."""
        e = self.expected
        rng = self.rng
        out: list[bytes] = [b"\x00"]
        held: bytes | None = None         # a late packet, sent after the next one
        stub: bytes | None = None         # a truncated packet, glued to the next one
        force_clean = False
        for g in range(self.n):
            volt_cv, envelope_cv, status, counts = next(samples)
            kind, status, counts = self._pick(g, force_clean, status, counts, I32)
            force_clean = False
            frame = encode_sample((self.first_seq + g) % SEQ_MODULUS, (self.first_t_us + g * PERIOD_US) % 2**32,
                                  volt_cv, counts, status, envelope_cv)
            if stub is not None:
                self._invalid(out, stub + frame, 1)
                e.lost += 1
                stub = None
            elif kind == "corrupt":
                pos = cobs_data_positions(frame)[int(rng.integers(len(cobs_data_positions(frame))))]
                new = int(rng.integers(1, 255))
                new = new if new < frame[pos] else new + 1
                self._invalid(out, frame[:pos] + bytes((new,)) + frame[pos + 1:], 1)
                e.lost += 1
            elif kind == "zero_byte":
                pos = int(rng.integers(1, len(frame) - 2))
                self._invalid(out, frame[:pos] + b"\x00" + frame[pos + 1:], 2)
                e.lost += 1
            elif kind == "truncate":
                stub = frame[:int(rng.integers(1, len(frame) - 1))]
                e.lost += 1
                force_clean = True
            elif kind == "drop":
                e.lost += 1
            elif kind == "late":
                held = frame
                e.lost += 1
                e.duplicates += 1
                force_clean = True
            else:
                if kind == "garbage":
                    junk = self._garbage()
                    self._invalid(out, junk, invalid_chunks(junk))
                elif kind == "event":
                    self._valid(out, encode_event("overtemp"))
                    e.events += 1
                self._valid(out, frame)
                e.received += 1
                if kind == "duplicate":
                    self._valid(out, frame)
                    e.duplicates += 1
                if held is not None:
                    self._valid(out, held)
                    held = None
            if (g + 1) % chunk == 0 or g == self.n - 1:
                yield b"".join(out)
                out = []



class CanFaultInjector(_Injector):
    """CAN frames ``(arbitration_id, data)`` of a sample stream with seeded faults
    (:data:`CAN_RATES`, at most one per sample), counting in :attr:`expected` exactly what an
    assembler must report (``resyncs`` and ``events`` stay 0 on CAN)."""

    ERROR = object()
    """Stands for an error frame in the wire list."""

    def __init__(self, n: int, seed: int = 0, rates: dict[str, float] | None = None, first_seq: int = 0) -> None:
        self.n = n
        self.rng = np.random.default_rng(seed)
        rates = dict(CAN_RATES if rates is None else rates)
        self.kinds = list(rates)
        self.edges = np.cumsum([rates[k] for k in self.kinds])
        self.first_seq = first_seq
        self.expected = Expected(injected=dict.fromkeys(rates, 0))
        self._db = load_dbc()

    def frames(self, g: int, volt_cv: int, envelope_cv: int, status: int, ft: tuple[int, ...]) -> list:
        """The sample's three frames, encoded by cantools from the DBC."""
        seq = (self.first_seq + g) % CAN_SEQ_MODULUS
        t_10us = (g * (PERIOD_US // 10)) & 0xFFFF
        return encode_sample_frames(seq, t_10us, volt_cv, envelope_cv, status, ft[:3], ft[3:], self._db)

    def wire(self, samples: Iterator[tuple[int, int, int, tuple[int, ...]]], chunk: int = FS) -> Iterator[list]:
        """The frames, ``chunk`` samples at a time."""
        e = self.expected
        rng = self.rng
        out: list = []
        held: list | None = None
        force_clean = False
        for g in range(self.n):
            volt_cv, envelope_cv, status, ft = next(samples)
            kind, status, ft = self._pick(g, force_clean, status, ft, (-32768, 32767))
            force_clean = False
            frames = self.frames(g, volt_cv, envelope_cv, status, ft)
            if kind == "corrupt":
                j = int(rng.integers(3))
                frames[j] = (frames[j][0], frames[j][1][:4])
                e.crc_errors += 1
                e.lost += 1
            elif kind == "drop":
                del frames[int(rng.integers(3))]
                e.lost += 1
            elif kind == "late":
                held = frames
                frames = []
                e.lost += 1
                e.duplicates += 3
                force_clean = True
            else:
                e.received += 1
                if kind == "duplicate":
                    j = int(rng.integers(3))
                    frames.insert(j + 1, frames[j])
                    e.duplicates += 1
                elif kind == "reorder":
                    frames = [frames[j] for j in rng.permutation(3)]
                elif kind == "error_frame":
                    frames.insert(0, self.ERROR)
                    e.crc_errors += 1
                elif kind == "foreign":
                    frames.insert(0, (0x200, bytes(8)))
            out += frames
            if held is not None and kind is None:
                out += held
                held = None
            if (g + 1) % chunk == 0 or g == self.n - 1:
                yield out
                out = []


def _observer_loop(seed: int, seq_modulus: int) -> tuple[Observer, ObserverLoop, Calibration]:
    """The soak's observer (a bench-sized model) and loop, tared at rest."""
    model = make_model(np.random.default_rng(seed), kernel_len=300)
    cal = Calibration()
    model.observer_config = {"R": (0.02 / cal.q_area) ** 2, "q_x": 1e-8, "q_bias": 1e-9, "p0_bias": 1e-3}
    observer = Observer(model, ObserverConfig.from_dict(model.observer_config))
    tare = float(cal.cl_from_ft(cal.ft_from_counts(np.zeros(6))))
    return observer, ObserverLoop(observer, Converter(cal.with_tare(tare), FS), seq_modulus, fs_hz=FS), cal


def _result(n: int, e: Expected, got: dict[str, int], observer: Observer, loop: ObserverLoop, seconds: float,
            rss_warm: float | None, rss_end: float) -> dict:
    got = {k: got[k] for k in e.counters()}
    mon = observer.monitors()
    st = loop.stats
    checks = {
        "decoder_counters_equal_injected": got == e.counters(),
        "sent_equals_received_plus_lost": got["received"] + got["lost"] == n,
        "loop_steps_equal_received": st.samples == got["received"],
        "loop_fills_equal_lost": st.filled == got["lost"],
        "observer_steps_add_up": mon["updates"] + mon["rejected"] + mon["missing"] == n,
        "missing_equals_flagged_plus_lost": mon["missing"] == e.flagged_received + got["lost"],
    }
    return {
        "samples": n,
        "faults_injected": int(sum(e.injected.values())),
        "accounted_exactly": all(checks.values()),
        "rss_growth_mb": round(rss_end - (rss_warm if rss_warm is not None else rss_end), 3),
        "seconds": round(seconds, 2),
        "us_per_sample": round(seconds / n * 1e6, 2),
        "rss_warm_mb": round(rss_warm or rss_end, 1),
        "rss_end_mb": round(rss_end, 1),
        "injected": e.injected,
        "expected_counters": e.counters(),
        "counters": got,
        "observer": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in mon.items()},
        "checks": checks,
        "expected": {k: v for k, v in asdict(e).items() if k == "flagged_received"},
    }


def can_soak(minutes: float, seed: int = 0, warmup_minutes: float = 1.0, progress: bool = False,
             rates: dict[str, float] | None = None) -> dict:
    """The soak over ``minutes`` of CAN frames (module docstring); the result dict as :func:`soak`'s."""
    import can

    n = int(round(minutes * 60 * FS))
    observer, loop, _ = _observer_loop(seed, CAN_SEQ_MODULUS)
    assembler = CanAssembler()
    error_frame = can.Message(is_error_frame=True)
    injector = CanFaultInjector(n, seed=seed, rates=rates, first_seq=200)
    samples = wire_samples(daq_stream("random", seed=seed), can_wire)
    warm_at = int(min(warmup_minutes * 60 * FS, n // 10))
    rss_warm = None
    t0 = time.perf_counter()
    fed = 0
    feed, feed_loop, error = assembler.feed, loop.feed, injector.ERROR
    for frames in injector.wire(samples):
        for f in frames:
            sample = assembler.feed_message(error_frame) if f is error else feed(f[0], f[1])
            if sample is not None:
                feed_loop(sample)
        fed += FS
        rss_warm = _tick("soak --can", fed, warm_at, rss_warm, progress, t0)
    seconds = time.perf_counter() - t0
    return _result(n, injector.expected, assembler.counters.as_dict(), observer, loop, seconds, rss_warm, rss_mb())


def _tick(label: str, fed: int, warm_at: int, rss_warm: float | None, progress: bool, t0: float) -> float | None:
    """After each second of data: the RSS once warm (returned), a progress line every 10 min."""
    if rss_warm is None and fed >= warm_at:
        rss_warm = rss_mb()
    if progress and fed % (600 * FS) == 0:
        print(f"{label}: {fed / FS / 60:.0f} min of data in {time.perf_counter() - t0:.0f} s, "
              f"RSS {rss_mb():.1f} MiB", file=sys.stderr, flush=True)
    return rss_warm


def rss_mb() -> float:
    """Resident set size from /proc/self/status (MiB)."""
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status")


def soak(minutes: float, seed: int = 0, warmup_minutes: float = 1.0, progress: bool = False,
         rates: dict[str, float] | None = None) -> dict:
    """Run the soak over ``minutes`` of data; the result dict of :func:`main`'s JSON."""
    n = int(round(minutes * 60 * FS))
    observer, loop, cal = _observer_loop(seed, SEQ_MODULUS)
    queue: deque = deque()
    decoder = SerialDecoder(queue.append, cal)
    injector = FaultInjector(n, seed=seed, rates=rates, first_seq=SEQ_MODULUS - 1000, first_t_us=2**32 - 600 * 10**6)
    samples = wire_samples(daq_stream("random", seed=seed), serial_wire)
    reads = np.random.default_rng(seed + 1)
    warm_at = int(min(warmup_minutes * 60 * FS, n // 10))
    rss_warm = None
    t0 = time.perf_counter()
    fed = 0
    for data in injector.wire(samples):
        view = memoryview(data)
        sizes = reads.integers(1, 4097, len(data) // 2048 + 2)
        pos = k = 0
        while pos < len(data):
            step = int(sizes[k % sizes.size])
            decoder.feed(view[pos:pos + step])
            pos += step
            k += 1
            while queue:
                loop.feed(queue.popleft())
        fed += FS
        rss_warm = _tick("soak", fed, warm_at, rss_warm, progress, t0)
    seconds = time.perf_counter() - t0
    return _result(n, injector.expected, decoder.counters.as_dict(), observer, loop, seconds, rss_warm, rss_mb())
