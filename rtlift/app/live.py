"""The 400 Hz observer loop over a stream of firmware samples, live or replayed.

The loop is driven by the arrival of samples; the device's ``seq`` is the clock. Per sample::

    gap = (seq − seq_prev) mod seq_modulus
    gap − 1 predict-only steps (missing samples; inputs held at the last sample's)
    (Cμ, Cμ_env, ΔCL | None) = converter(sample)          # tare as firmware_io.Converter
    est = observer.step(Cμ, Cμ_env, ΔCL)
    latency = perf_counter() − sample.host_time            # receive → estimate

then the estimate row is written (and, with a live view, one small tuple appended to its
drop-oldest ``tap``: never a wait, never I/O). The same samples in give the same rows out, bit for bit,
whatever the pacing (live link, log replayed as fast as possible or in real time): nothing
here depends on the host clock except the latency figures.
"""

from __future__ import annotations

import json
import math
import os
import time
from array import array
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from firmware_io.latency import LatencyRecorder
from firmware_io.logs import FlushedFile
from firmware_io.samples import Sample
from rtlift.core.rate import FS_HZ
from rtlift.observer import Observer

MAX_FILL = int(FS_HZ)
"""At most this many predict-only steps for one gap in ``seq`` (1 s); a longer gap is a
device restart or an ambiguity of the wrapping counter, not something to extrapolate over."""
MAX_BRIDGE_S = 60.0
"""At most this much device time is predicted through (flagged) when a link comes back after a
reconnect; the sample index (and ``t``) still advances by the whole gap."""
FLAG_LINK_GAP = 16
"""Estimate-row flag (beside the observer's FLAG_* bits 1–8): a predict-only step across a
gap while the device was gone (``--reconnect``)."""
FLUSH_S = 0.05
COLUMNS = ("index", "t", "seq", "t_us", "cmu", "cmu_envelope", "dcl", "dcl_hat", "model_dcl",
           "innovation", "nis", "flags")
"""Estimate-file columns; ``t, cmu, cmu_envelope, dcl`` are the record format's (``dcl`` the measured
ΔCL, empty while taring or on a flagged sample), so one tool reads both."""


class EstimateWriter(FlushedFile):
    """Estimates as CSV (:data:`COLUMNS`; floats as ``repr`` so they read back exactly; empty
    cells for what a filled-in sample does not have), flushed every ``flush_s`` and on close;
    a failing disk is a one-line error (:class:`~firmware_io.errors.LogError`)."""

    def __init__(self, path: str | os.PathLike, meta: dict[str, Any] | None = None,
                 flush_s: float = FLUSH_S) -> None:
        super().__init__(path, "estimates", flush_s=flush_s)
        self._start(meta, COLUMNS)
        self.rows = 0

    def write(self, index: int, t: float, seq: int, t_us: int | None, cmu: float, env: float,
              dcl: float | None, est: Any) -> None:
        self._append(
            f"{index},{t!r},{seq},{'' if t_us is None else t_us},{cmu!r},{env!r},"
            f"{'' if dcl is None else repr(dcl)},{est.dcl!r},{est.model_dcl!r},"
            f"{est.innovation!r},{est.nis!r},{est.flags}\n")
        self.rows += 1


@dataclass
class LoopStats:
    """What the loop did: samples received and stepped, gaps filled, estimates, latencies (s,
    a :class:`~firmware_io.latency.LatencyRecorder`), and with ``time_steps`` the duration of each step (s)."""

    samples: int = 0
    filled: int = 0
    bridged: int = 0
    estimates: int = 0
    end: str = "running"
    latencies: LatencyRecorder = field(default_factory=LatencyRecorder)
    step_times: array = field(default_factory=lambda: array("d"))
    steps: LatencyRecorder = field(default_factory=LatencyRecorder)
    """Step durations in fixed memory (``step_stats``), for a run of any length."""
    steps_busy: LatencyRecorder = field(default_factory=LatencyRecorder)
    """The same, of the steps taken while ``--adapt``'s background diagnosis ran (:mod:`.adapt`)."""

    def latency_ms(self) -> tuple[float | None, float | None]:
        return self.latencies.percentile_ms(50), self.latencies.percentile_ms(99)


class ObserverLoop:
    """Feeds samples to an :class:`~rtlift.observer.Observer` (module docstring); ``tap``, a
    ``deque(maxlen=...)``, receives one row per estimate for a live view and drops its oldest."""

    def __init__(self, observer: Observer, converter: Any, seq_modulus: int, *,
                 writer: EstimateWriter | None = None, fs_hz: float = FS_HZ,
                 max_samples: int | None = None, time_steps: bool = False, tap: deque | None = None,
                 monitor: Any = None, step_stats: bool = False) -> None:
        self.observer = observer
        self.monitor = monitor  # rtlift.observer.monitor.DepartureMonitor, stepped after the observer
        self.adapter: Any = None  # rtlift.app.adapt.Adapter (--adapt): may swap ``observer`` at a burst onset
        self.converter = converter
        self.seq_modulus = seq_modulus
        self.writer = writer
        self.fs_hz = fs_hz
        self.max_samples = max_samples
        self.time_steps = time_steps or step_stats
        self._raw_steps = time_steps
        self.tap = tap      # rtlift.app.view.LiveView.tap: (index, dcl | None, dcl_hat, model_dcl, ν, NIS) rows
        self.stats = LoopStats()
        self._last_seq: int | None = None
        self._index = -1
        self._last_cmu = 0.0
        self._last_env = 0.0

    @property
    def done(self) -> bool:
        return self.max_samples is not None and self._index + 1 >= self.max_samples

    def feed(self, sample: Sample) -> None:
        """One received sample (and the predict-only steps of any gap before it)."""
        obs, writer, stats, tap = self.observer, self.writer, self.stats, self.tap
        if self._last_seq is not None:
            gap = (sample.seq - self._last_seq) % self.seq_modulus
            if gap == 0:
                return
            for i in range(1, min(gap, MAX_FILL)):
                self._index += 1
                est = obs.step(self._last_cmu, self._last_env, None)
                stats.filled += 1
                if self.monitor is not None:
                    self.monitor.step(None, est.model_dcl, est.innovation)
                if self.adapter is not None:
                    self.adapter.after_step(self._index, self._last_cmu, self._last_env, None)
                if tap is not None:
                    tap.append((self._index, None, est.dcl, est.model_dcl, est.innovation, est.nis))
                stats.estimates += 1
                if writer is not None:
                    writer.write(self._index, self._index / self.fs_hz,
                                 (self._last_seq + i) % self.seq_modulus, None,
                                 self._last_cmu, self._last_env, None, est)
        self._last_seq = sample.seq
        self._index += 1
        cmu, env, dcl = self.converter(sample)
        if self.adapter is not None:
            self.adapter.before_step(self._index, cmu)
            obs = self.observer
        if self.time_steps:
            t0 = time.perf_counter()
            est = obs.step(cmu, env, dcl)
            t1 = time.perf_counter()
            stats.steps.append(t1 - t0)
            if self.adapter is not None and self.adapter.busy:
                stats.steps_busy.append(t1 - t0)
            if self._raw_steps:
                stats.step_times.append(t1 - t0)
        else:
            est = obs.step(cmu, env, dcl)
            t1 = time.perf_counter()
        stats.latencies.append(t1 - sample.host_time)
        stats.samples += 1
        if self.monitor is not None:
            self.monitor.step(dcl, est.model_dcl, est.innovation)
        if self.adapter is not None:
            self.adapter.after_step(self._index, cmu, env, dcl)
        self._last_cmu, self._last_env = cmu, env
        if tap is not None:
            tap.append((self._index, dcl, est.dcl, est.model_dcl, est.innovation, est.nis))
        stats.estimates += 1
        if writer is not None:
            writer.write(self._index, self._index / self.fs_hz, sample.seq, sample.t_us, cmu, env, dcl, est)

    def bridge(self, missed: int, known: bool) -> None:
        """The link came back after its device vanished (``link.on_gap``): ``missed`` samples
        (from ``seq`` if ``known``, else the host clock's estimate) are predicted through, up to
        :data:`MAX_BRIDGE_S`, each row flagged :data:`FLAG_LINK_GAP` (``seq`` left empty when
        unknown); the next sample starts a new ``seq`` run."""
        obs, writer, stats = self.observer, self.writer, self.stats
        last = self._last_seq
        steps = min(missed, int(MAX_BRIDGE_S * self.fs_hz)) if last is not None else 0
        for i in range(1, steps + 1):
            est = obs.step(self._last_cmu, self._last_env, None)
            est.flags |= FLAG_LINK_GAP
            stats.bridged += 1
            if self.monitor is not None:
                self.monitor.step(None, est.model_dcl, est.innovation)
            if self.tap is not None:
                self.tap.append((self._index + i, None, est.dcl, est.model_dcl, est.innovation, est.nis))
            stats.estimates += 1
            if writer is not None:
                index = self._index + i
                writer.write(index, index / self.fs_hz, (last + i) % self.seq_modulus if known else "", None,
                             self._last_cmu, self._last_env, None, est)
        if last is not None:
            self._index += missed
        self._last_seq = None

    def run(self, samples: Iterable[Sample | None], *, silence_s: float | None = None,
            seconds_down: Callable[[], float] | None = None) -> str:
        """Consume samples until ``max_samples`` device samples are done (``"completed"``), the
        source ends (``"ended"``) or the device fell silent (``"timeout"``, :func:`drive`)."""
        self.stats.end = drive(samples, self.feed, lambda: self.done, silence_s=silence_s,
                               seconds_down=seconds_down)
        return self.stats.end


SILENCE_S = 5.0
"""Host seconds without a sample, the link up, after which a live run with an end gives up."""


def drive(samples: Iterable[Any], feed: Callable[[Any], None], is_done: Callable[[], bool], *,
          silence_s: float | None = None, seconds_down: Callable[[], float] | None = None) -> str:
    """Feed ``samples`` until ``is_done()`` (``"completed"``), the source ends (``"ended"``) or,
    with ``silence_s``, no sample came for that many host seconds (``"timeout"``: the device fell
    silent). Time the device was gone while the link reconnected (``seconds_down``, e.g.
    ``link.seconds_down``) does not count. ``None`` items (a timed source's silence) only give
    the check its chance: silence counts from the first one, so a run gives up ``silence_s``
    plus the source's own timeout after its last sample. A device that streams behind its rate
    (the simulated bench on a loaded machine) is waited for: a limit on the run's total time
    would end it as "silent" while its samples still arrive."""
    silent_since = None
    down_then = 0.0
    for sample in samples:
        if sample is not None:
            silent_since = None
            feed(sample)
            if is_done():
                return "completed"
        elif silence_s is not None:
            now = time.perf_counter()
            down = seconds_down() if seconds_down else 0.0
            if silent_since is None:
                silent_since, down_then = now, down
            elif now - silent_since - (down - down_then) > silence_s:
                return "timeout"
    return "ended"


def run_live(tool: str, stats: LoopStats, link: Any, feed: Callable[[Any], None], is_done: Callable[[], bool],
             received: Callable[[], int], seconds: float | None) -> tuple[int, str | None]:
    """One live run on an open link, as ``rtlift observe`` and ``rtlift control`` end it:
    :func:`drive` (the silence limit only with ``seconds``) under
    :func:`~firmware_io.logs.graceful_exit`; ``stats.end`` set to how it ended. Returns the exit
    status and the one line for the user (None on a clean end): Ctrl-C 130, SIGTERM/SIGHUP the
    signal's status, a vanished or silent device 1; any other exception propagates (``"error"``)."""
    from firmware_io.logs import graceful_exit

    code, message = 0, None
    with graceful_exit():
        try:
            stats.end = drive(link.samples(0.25), feed, is_done, silence_s=None if seconds is None else SILENCE_S,
                              seconds_down=lambda: link.seconds_down)
        except KeyboardInterrupt:
            stats.end, code = "interrupted", 130
        except SystemExit as exc:
            stats.end, code = "terminated", exc.code if isinstance(exc.code, int) else 143
        except Exception:
            stats.end = "error"
            raise
        else:
            if stats.end == "ended" and link.disconnected:
                stats.end, code = "disconnected", 1
                message = f"{tool}: the device disappeared after {received()} samples; summary written"
            elif stats.end == "timeout" and link.down:
                code, message = 1, f"{tool}: the device was still gone when --seconds were done; summary written"
            elif stats.end == "timeout":
                code, message = 1, f"{tool}: the device fell silent before --seconds were done"
    return code, message


def summary(link_counters: dict[str, int], stats: LoopStats, observer: Observer,
            **extra: Any) -> dict[str, Any]:
    """SUMMARY.json: the exact link counters, estimates made (written with ``--out``), latency percentiles, monitors."""
    p50, p99 = stats.latency_ms()
    out: dict[str, Any] = {
        "version": 1,
        **{k: int(link_counters[k]) for k in ("received", "crc_errors", "lost", "resyncs", "events",
                                              "duplicates")},
        **{k: int(link_counters[k]) for k in ("reconnects", "gap_lost", "gaps_unknown", "gap_lost_estimated")
           if k in link_counters},
        "estimates": stats.estimates,
        "samples_stepped": stats.samples,
        "samples_filled": stats.filled,
        "samples_bridged": stats.bridged,
        "latency_p50_ms": p50,
        "latency_p99_ms": p99,
        **_step_percentiles(stats),
        "end": stats.end,
    }
    mon = observer.monitors()
    out["observer"] = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in mon.items()}
    out.update(extra)
    return out


def _step_percentiles(stats: LoopStats) -> dict[str, float]:
    """Observer step duration p50/p99 (µs) when the loop timed its steps."""
    out = {}
    for key, rec in (("step", stats.steps), ("step_busy", stats.steps_busy)):
        if len(rec):
            out.update({f"{key}_p50_us": rec.percentile(50) * 1e6, f"{key}_p99_us": rec.percentile(99) * 1e6,
                        f"{key}_max_us": rec.max_s * 1e6, f"{key}_n": len(rec)})
    return out


def write_summary(path: str | os.PathLike, data: dict[str, Any]) -> None:
    from rtlift.core.errors import UserError

    tmp = f"{path}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(data, f, indent=1, sort_keys=True)
            f.write("\n")
        os.replace(tmp, path)
    except OSError as exc:
        raise UserError(f"{path}: cannot write summary ({exc.strerror or exc})") from None
