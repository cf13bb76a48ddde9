"""The 400 Hz observer loop over a stream of firmware samples, live or replayed.

The loop is driven by the arrival of samples; the device's ``seq`` is the clock. Per sample::

    gap = (seq − seq_prev) mod seq_modulus
    gap − 1 predict-only steps (missing samples; inputs held at the last sample's)
    (Cμ, Cμ_env, ΔCL | None) = converter(sample)          # tare as firmware_io.Converter
    est = observer.step(Cμ, Cμ_env, ΔCL)
    latency = perf_counter() − sample.host_time            # receive → estimate

then the estimate's row goes to the loop's listeners, one dispatch for received, gap-filled and
bridged samples (python-can's ``Notifier``/``Listener``): the departure monitor, the ``--adapt``
swapper's ring, a live view's drop-oldest ``tap`` (never a wait, never I/O), the estimates file —
all given to :class:`ObserverLoop` when it is made. The same samples in give the same rows out, bit for bit,
whatever the pacing (live link, log replayed as fast as possible or in real time): nothing
here depends on the host clock except the latency figures.
"""

from __future__ import annotations

import math
import os
import time
from array import array
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

from firmware_io.latency import LatencyRecorder
from firmware_io.link_base import DEVICE_SILENCE_S
from firmware_io.logs import FlushedFile
from firmware_io.samples import Sample
from rtlift.core.errors import UserError
from rtlift.core.jsonfile import write_json_atomic
from rtlift.core.rate import FS_HZ
from rtlift.observer import Estimate, Observer

Converter = Callable[[Sample], tuple[float, float, "float | None"]]
"""A sample → ``(Cμ, Cμ_env, ΔCL | None)`` (:class:`firmware_io.convert.Converter`, possibly wrapped)."""

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


class Listener(Protocol):
    """One receiver of the loop's per-sample dispatch (python-can's ``Listener`` to its ``Notifier``).

    :meth:`on_sample` is called once per estimate, in the 400 Hz thread, with the estimate row:
    the loop's sample ``index``, ``t = index / f_s`` (s), the device's ``seq`` (``None`` across a
    reconnect gap ``seq`` cannot tell), the device clock ``t_us`` (µs; ``None`` on a predict-only
    step), the inputs ``cmu``, ``env`` (Cμ, Cμ_env) and the measured ``dcl`` (ΔCL; ``None`` when
    missing, flagged or taring), and ``est``, the observer's :class:`~rtlift.observer.Estimate`
    (the same object every step: copy what you keep). It must not wait, do I/O beyond a buffered
    append, or keep ``est``. :meth:`on_stop` is called once by :meth:`ObserverLoop.stop`."""

    def on_sample(self, index: int, t: float, seq: int | None, t_us: int | None, cmu: float, env: float,
                  dcl: float | None, est: Estimate) -> None: ...

    def on_stop(self) -> None: ...


class Swapper(Protocol):
    """What swaps the loop's observer while it runs (``--adapt``: :class:`rtlift.app.adapt.Adapter`).

    :meth:`before_step` is called with each received sample's index and Cμ before the observer
    steps and may set ``loop.observer`` (the loop binds ``loop`` at its construction);
    :meth:`after_step` receives every estimate's inputs, received or predicted (its rows); ``busy``
    says a swap is being prepared (the loop's step times go to ``steps_busy`` as well)."""

    loop: Any
    busy: bool

    def before_step(self, index: int, cmu: float) -> None: ...

    def after_step(self, index: int, cmu: float, env: float, dcl: float | None) -> None: ...


class Monitor(Protocol):
    """A residual monitor stepped after the observer (:class:`rtlift.observer.monitor.DepartureMonitor`):
    ``step(ΔCL measured | None, model ΔCL, innovation ν, envelope Cμ)`` (the input: its steps are watched)."""

    def step(self, dcl: float | None, model_dcl: float, innovation: float, envelope: float) -> None: ...


class EstimateWriter(FlushedFile):
    """Estimates as CSV (:data:`COLUMNS`; floats as ``repr`` so they read back exactly; empty
    cells for what a filled-in sample does not have), flushed every ``flush_s`` and on close;
    a failing disk is a one-line error (:class:`~firmware_io.errors.LogError`). A :class:`Listener`:
    ``on_sample`` writes the row, ``on_stop`` closes the file."""

    def __init__(self, path: str | os.PathLike, meta: dict[str, Any] | None = None,
                 flush_s: float = FLUSH_S) -> None:
        super().__init__(path, "estimates", flush_s=flush_s)
        self._start(meta, COLUMNS)
        self.rows = 0

    def write(self, index: int, t: float, seq: int | None, t_us: int | None, cmu: float, env: float,
              dcl: float | None, est: Any) -> None:
        self._append(
            f"{index},{t!r},{'' if seq is None else seq},{'' if t_us is None else t_us},{cmu!r},{env!r},"
            f"{'' if dcl is None else repr(dcl)},{est.dcl!r},{est.model_dcl!r},"
            f"{est.innovation!r},{est.nis!r},{est.flags}\n")
        self.rows += 1

    on_sample = write

    def on_stop(self) -> None:
        self.close()


class _NothingToStop:
    """A :class:`Listener` with nothing to close when the run ends."""

    __slots__ = ()

    def on_stop(self) -> None:
        pass


class MonitorListener(_NothingToStop):
    """A :class:`Monitor` as a :class:`Listener`: ``monitor.step(dcl, est.model_dcl, est.innovation, env)``."""

    __slots__ = ("monitor", "_step")

    def __init__(self, monitor: Monitor) -> None:
        self.monitor = monitor
        self._step = monitor.step

    def on_sample(self, index: int, t: float, seq: int | None, t_us: int | None, cmu: float, env: float,
                  dcl: float | None, est: Estimate) -> None:
        self._step(dcl, est.model_dcl, est.innovation, env)


class SwapperListener(_NothingToStop):
    """A :class:`Swapper`'s rows as a :class:`Listener`: ``after_step(index, cmu, env, dcl)``."""

    __slots__ = ("_after",)

    def __init__(self, swapper: Swapper) -> None:
        self._after = swapper.after_step

    def on_sample(self, index: int, t: float, seq: int | None, t_us: int | None, cmu: float, env: float,
                  dcl: float | None, est: Estimate) -> None:
        self._after(index, cmu, env, dcl)


class Tap(_NothingToStop):
    """A live view's drop-oldest ``deque(maxlen=...)`` (:attr:`rtlift.app.view.LiveView.tap`) as a
    :class:`Listener`: one ``(index, dcl | None, ΔĈL, model ΔCL, ν, NIS)`` tuple per estimate,
    never a wait, never I/O."""

    __slots__ = ("tap", "_append")

    def __init__(self, tap: deque) -> None:
        self.tap = tap
        self._append = tap.append

    def on_sample(self, index: int, t: float, seq: int | None, t_us: int | None, cmu: float, env: float,
                  dcl: float | None, est: Estimate) -> None:
        self._append((index, dcl, est.dcl, est.model_dcl, est.innovation, est.nis))


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
    """Feeds samples to an :class:`~rtlift.observer.Observer` (module docstring) and hands every
    estimate to its listeners, all given here: ``monitor`` (a :class:`Monitor`, first), ``adapter``
    (a :class:`Swapper`: called before each received sample's step, and its rows after the
    monitor), ``tap`` (a live view's deque, :class:`Tap`), ``writer`` (the estimates file), then
    ``listeners`` in their order. One dispatch (:meth:`_emit`) serves received, gap-filled and
    bridged samples alike; the listeners' bound ``on_sample`` methods are kept in a tuple, so a
    sample allocates no list and creates no function."""

    def __init__(self, observer: Observer, converter: Converter, seq_modulus: int, *,
                 writer: EstimateWriter | None = None, fs_hz: float = FS_HZ,
                 max_samples: int | None = None, time_steps: bool = False, tap: deque | None = None,
                 monitor: Monitor | None = None, adapter: Swapper | None = None,
                 listeners: Iterable[Listener] = (), step_stats: bool = False) -> None:
        self.observer = observer
        self.converter = converter
        self.seq_modulus = seq_modulus
        self.fs_hz = fs_hz
        self.max_samples = max_samples
        self.time_steps = time_steps or step_stats
        self._raw_steps = time_steps
        self.stats = LoopStats()
        self._monitor = monitor
        self._adapter = adapter
        self._tap = None if tap is None else Tap(tap)
        self._writer = writer
        self._extra = tuple(listeners)
        self.listeners: tuple[Listener, ...] = ()
        self._on_sample: tuple[Callable[..., None], ...] = ()
        self._register()
        self._last_seq: int | None = None
        self._index = -1
        self._last_cmu = 0.0
        self._last_env = 0.0

    def _register(self) -> None:
        """The listeners in dispatch order, and their bound ``on_sample`` methods."""
        mon, ad = self._monitor, self._adapter
        if ad is not None:
            ad.loop = self
        self.listeners = tuple(x for x in (None if mon is None else MonitorListener(mon),
                                           None if ad is None else SwapperListener(ad),
                                           self._tap, self._writer) if x is not None) + self._extra
        self._on_sample = tuple(listener.on_sample for listener in self.listeners)

    @property
    def monitor(self) -> Monitor | None:
        """The residual monitor stepped after the observer (given at construction)."""
        return self._monitor

    @property
    def adapter(self) -> Swapper | None:
        """What may swap :attr:`observer` at a burst onset (given at construction; set between
        samples by a caller that makes its adapter for an existing loop, e.g.
        :class:`rtlift.app.hil_tracking.InProcessTracking`'s ``on_loop``: registered the same way)."""
        return self._adapter

    @adapter.setter
    def adapter(self, adapter: Swapper | None) -> None:
        self._adapter = adapter
        self._register()

    @property
    def done(self) -> bool:
        return self.max_samples is not None and self._index + 1 >= self.max_samples

    def _emit(self, index: int, seq: int | None, t_us: int | None, cmu: float, env: float, dcl: float | None,
              est: Estimate) -> None:
        """The one per-sample dispatch: count the estimate, hand its row to every listener."""
        self.stats.estimates += 1
        t = index / self.fs_hz
        for on_sample in self._on_sample:
            on_sample(index, t, seq, t_us, cmu, env, dcl, est)

    def _predict(self, seq: int | None, flags: int) -> None:
        """One predict-only step at the next index (inputs held at the last sample's)."""
        self._index += 1
        est = self.observer.step(self._last_cmu, self._last_env, None)
        est.flags |= flags
        self._emit(self._index, seq, None, self._last_cmu, self._last_env, None, est)

    def feed(self, sample: Sample) -> None:
        """One received sample (and the predict-only steps of any gap before it)."""
        stats, adapter = self.stats, self._adapter
        last = self._last_seq
        if last is not None:
            gap = (sample.seq - last) % self.seq_modulus
            if gap == 0:
                return
            for i in range(1, min(gap, MAX_FILL)):
                self._predict((last + i) % self.seq_modulus, 0)
                stats.filled += 1
        self._last_seq = sample.seq
        self._index += 1
        cmu, env, dcl = self.converter(sample)
        if adapter is not None:
            adapter.before_step(self._index, cmu)
        obs = self.observer
        if self.time_steps:
            t0 = time.perf_counter()
            est = obs.step(cmu, env, dcl)
            t1 = time.perf_counter()
            stats.steps.append(t1 - t0)
            if adapter is not None and adapter.busy:
                stats.steps_busy.append(t1 - t0)
            if self._raw_steps:
                stats.step_times.append(t1 - t0)
        else:
            est = obs.step(cmu, env, dcl)
            t1 = time.perf_counter()
        stats.latencies.append(t1 - sample.host_time)
        stats.samples += 1
        self._last_cmu, self._last_env = cmu, env
        self._emit(self._index, sample.seq, sample.t_us, cmu, env, dcl, est)

    def bridge(self, missed: int, known: bool) -> None:
        """The link came back after its device vanished (``link.on_gap``): ``missed`` samples
        (from ``seq`` if ``known``, else the host clock's estimate) are predicted through, up to
        :data:`MAX_BRIDGE_S`, each row flagged :data:`FLAG_LINK_GAP` (``seq`` left empty when
        unknown); the next sample starts a new ``seq`` run."""
        last = self._last_seq
        if last is None:
            return
        steps = min(missed, int(MAX_BRIDGE_S * self.fs_hz))
        start = self._index
        for i in range(1, steps + 1):
            self._predict((last + i) % self.seq_modulus if known else None, FLAG_LINK_GAP)
            self.stats.bridged += 1
        self._index = start + missed
        self._last_seq = None

    def stop(self) -> None:
        """The run is over: every listener's ``on_stop`` (the estimates file closed)."""
        for listener in self.listeners:
            listener.on_stop()

    def run(self, samples: Iterable[Sample | None], *, silence_s: float | None = None,
            seconds_down: Callable[[], float] | None = None) -> str:
        """Consume samples until ``max_samples`` device samples are done (``"completed"``), the
        source ends (``"ended"``) or the device fell silent (``"timeout"``, :func:`drive`)."""
        self.stats.end = drive(samples, self.feed, lambda: self.done, silence_s=silence_s,
                               seconds_down=seconds_down)
        return self.stats.end


SILENCE_S = DEVICE_SILENCE_S
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
    """SUMMARY.json (keys sorted; NaN and Inf as JSON writes them) through
    :func:`~rtlift.core.jsonfile.write_json_atomic`; a failing disk is one :class:`UserError` line."""
    try:
        write_json_atomic(path, data, stage="summary", sort_keys=True, finite=False)
    except OSError as exc:
        raise UserError(f"{path}: cannot write summary ({exc.strerror or exc})") from None
