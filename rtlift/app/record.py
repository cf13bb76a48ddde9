"""Record experiment programs on a rig over protocol version 2 (``rtlift record``).

Per experiment, driven by the device's samples (its ``seq`` is the clock, so a device paced
faster than real time records the same thing):

1. settle: ``SETTLE_S`` with the actuator off (the flow relaxes from what came before);
2. tare: ``tare_s`` with the actuator off (the record starts here);
3. the program (:class:`rtlift.core.programs.Program`): each burst onset's command (envelope,
   burst period, enable, watchdog) goes out just after the onset before it (the first one
   ``LEAD_SAMPLES`` ahead), so the firmware has applied it when its onset comes, with a whole
   period of margin. The firmware fires the first burst at its own next onset after the first
   command that turns the actuator on (within 20 samples: the off state's period is 50 ms), so
   the program's time origin is taken from that first burst (``first_burst_delay`` in the
   metadata): the rest of the program keeps its timing exactly;
4. the actuator is commanded off at the end (and on every exit path), and the record is
   written: the device's samples from the tare's start to the program's end, Cμ from the drive
   voltage through the calibration, ΔCL from the balance minus the tare, and the envelope as
   applied: the one the device reports at each onset, held to the next (PROTOCOL.md: an
   envelope takes effect at the next onset; the device's report as it came is the
   ``envelope_volts`` column).

One command is in flight at a time (the next goes out once the device echoed the last, or
``ECHO_TIMEOUT_S`` passed), so no command supersedes another and every one is applied;
when nothing else is due, the current command is repeated every ``KEEPALIVE_SAMPLES`` to feed
the firmware's watchdog. A command echoed only at or after its onset is counted late. An
experiment whose commands the device mostly did not apply (:mod:`rtlift.app.applied`) ends
incomplete: ``rtlift record`` exits 1 with one line.
"""

from __future__ import annotations

import datetime as _dt
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from firmware_io.link_base import DEVICE_SILENCE_S
from rtlift.app.applied import commands_not_applied
from rtlift.core.errors import UserError
from rtlift.core.programs import Program, samples_of_ms
from rtlift.core.rate import FS_HZ
from rtlift.core.records import Record, write_record

SETTLE_S = 1.0
LEAD_SAMPLES = 10
"""Send the first onset's command this many samples (25 ms) ahead of it: ≫ the command latency."""
KEEPALIVE_SAMPLES = 40
"""Repeat the command at least every 100 ms of the device's clock."""
WATCHDOG_DIV10 = 100
"""The watchdog every command sets: 1 s (the protocol's default is 500 ms; a host stalled for
half a second on a busy machine should not end the experiment, a host gone for a second should)."""
OFF_PERIOD_MS = 50
"""The burst period commanded while the actuator is off (settle, tare): the firmware's onsets
come every 20 samples, so the first burst follows the command that turns it on within 20."""
ECHO_TIMEOUT_S = 0.5
"""Host seconds to wait for a command's echo before the next one may go out anyway."""
PROTOCOL_CHECK_SAMPLES = int(FS_HZ)
"""Samples to wait for the echo of the first command before calling the device version 1."""
SILENCE_S = DEVICE_SILENCE_S
"""Host seconds without a valid sample before the device counts as gone (was 2 s: a stall of a
loaded machine's pseudo-terminal cut the demo's run short in a loaded CI)."""
BAD_FRAMES_FLOOR = 100
BAD_FRAMES_SHARE = 0.1
"""An experiment stops when lost + invalid frames exceed FLOOR + SHARE × samples received."""
OFF_ECHO_S = 2.0
"""Host seconds to wait for the echo of the final actuator-off command."""
COUNTER_KEYS = ("received", "lost", "crc_errors", "duplicates", "resyncs", "events", "commands_sent",
                "commands_applied", "watchdog_trips")


class ProtocolError(UserError):
    """The device does not speak protocol version 2 (it never echoes a command)."""


@dataclass
class RecordResult:
    """What one experiment produced (the summary table's row)."""

    name: str
    path: str | None
    complete: bool
    reason: str = ""
    samples: int = 0
    counters: dict[str, int] = field(default_factory=dict)
    commands_late: int = 0
    dcl_range: tuple[float, float] | None = None
    first_burst_delay: int | None = None
    record: Record | None = None
    first_index: int = 0
    """Device sample index (unwrapped ``seq`` since the session's first sample) of the record's first row."""


@dataclass
class _State:
    """The command the device should be running now."""

    envelope_cv: int = 0
    period_ms: int = 0
    enable: bool = False


class Recorder:
    """Runs programs on an open link (a :class:`firmware_io.links.Link`) and writes records."""

    def __init__(self, link: Any, calibration: Any, *, tare_s: float | None = None, fs_hz: float = FS_HZ,
                 meta: dict[str, str] | None = None,
                 progress: Callable[[int, str], Any] | None = None) -> None:
        """``progress(total, name)`` makes a progress bar (``update(n)``, ``close()``) per experiment."""
        self.link = link
        tare = calibration.tare_seconds if tare_s is None else float(tare_s)
        if not 0.1 <= tare <= 600:
            raise UserError(f"--tare-seconds must be between 0.1 and 600, got {tare:g}")
        self.calibration = replace(calibration, tare_seconds=tare)
        self.fs_hz = fs_hz
        self.tare_samples = int(round(tare * fs_hz))
        self.settle_samples = int(round(SETTLE_S * fs_hz))
        self.meta = dict(meta or {})
        self.progress = progress
        self.state = _State()
        self._in_flight: int | None = None
        self._in_flight_at = 0.0
        self._last_sent_at = -10**9
        self._index = -1
        self._last_seq: int | None = None

    # -- the device's clock --------------------------------------------------------------
    def _next(self) -> Any:
        """The next sample (``None``: the device is silent or gone), with ``self._index`` its
        unwrapped device index."""
        s = self.link.recv(SILENCE_S)
        if s is None:
            return None
        if self._last_seq is None:
            self._index = 0
        else:
            self._index += (s.seq - self._last_seq) % self.link.seq_modulus
        self._last_seq = s.seq
        if s.cmd_seq and s.cmd_seq == self._in_flight:
            self._in_flight = None
        return s

    # -- commands ------------------------------------------------------------------------
    def _send(self, state: _State) -> int | None:
        cmd_seq = self.link.send_command(state.envelope_cv, state.period_ms, state.enable, WATCHDOG_DIV10)
        self.state = state
        self._last_sent_at = self._index
        if cmd_seq is not None:
            self._in_flight, self._in_flight_at = cmd_seq, time.perf_counter()
        return cmd_seq

    def _free(self) -> bool:
        """No command in flight (or the last one's echo is overdue)."""
        if self._in_flight is not None and time.perf_counter() - self._in_flight_at >= ECHO_TIMEOUT_S:
            self._in_flight = None
        return self._in_flight is None

    def _keepalive(self) -> None:
        if self._free() and self._index - self._last_sent_at >= KEEPALIVE_SAMPLES:
            self._send(self.state)

    def envelope_cv(self, volts: float) -> int:
        return max(0, min(0xFFFF, int(round(volts * 100.0))))

    def check_protocol(self, period_ms: int) -> None:
        """Command the actuator off and wait for the echo; :class:`ProtocolError` if none comes
        (a version-1 device), :class:`UserError` if no sample comes at all."""
        where = self.meta.get("link", "the device")
        s = self._next()
        if s is None:
            raise UserError(f"{where}: no sample from the device in {SILENCE_S:g} s")
        cmd_seq = self._send(_State(0, period_ms, False))
        start = self._index
        while self._index - start < PROTOCOL_CHECK_SAMPLES:
            s = self._next()
            if s is None:
                break
            if s.cmd_seq and s.cmd_seq == cmd_seq:
                return
        raise ProtocolError(f"{where}: the device does not echo commands (a protocol-version-1 device?); "
                            "rtlift record needs protocol version 2 (PROTOCOL.md)")

    def switch_off(self) -> bool:
        """Actuator off (``enable`` false) and wait briefly for the echo; ``False`` if the
        device is gone (its watchdog switches it off)."""
        link = self.link
        if link.closed or link.disconnected:
            return False
        end = time.perf_counter() + ECHO_TIMEOUT_S
        while not self._free() and time.perf_counter() < end:   # not over a command in flight
            if self._next() is None:
                break
        try:
            cmd_seq = link.send_command(0, 0, False, WATCHDOG_DIV10)
        except Exception:  # noqa: BLE001 - best effort on the way out
            return False
        if cmd_seq is None:
            return False
        self.state = _State(0, self.state.period_ms, False)
        end = time.perf_counter() + OFF_ECHO_S
        while time.perf_counter() < end:
            s = link.recv(0.05)
            if s is not None and s.cmd_seq == cmd_seq:
                return True
        return False

    # -- one experiment --------------------------------------------------------------------
    def run(self, program: Program, out_path: str | None, name: str | None = None,
            meta: dict[str, str] | None = None) -> RecordResult:
        """Settle, tare, run ``program``, write ``out_path`` (also partial, on any exit)."""
        name = name or program.name
        started = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        c0 = self.link.counters.as_dict()
        samples: list[tuple[int, Any]] = []
        run = _Run(self, program)
        reason = "interrupted"
        bar = None
        if self.progress is not None:
            bar = self.progress(self.settle_samples + self.tare_samples + run.n, name)
        try:
            reason = run.loop(samples, bar)
        except KeyboardInterrupt:
            reason = "interrupted"
            raise
        except Exception as exc:  # noqa: BLE001 - recorded in the partial record, then raised
            reason = f"failed: {type(exc).__name__}: {exc}"
            raise
        finally:
            if bar is not None:
                if not reason:
                    bar.n = bar.total
                    bar.refresh()
                bar.close()
            off = self.switch_off()
            result = self._finish(name, program, out_path, samples, run, reason, started, c0, off, meta)
            self.last_result = result
        return result

    def _finish(self, name: str, program: Program, out_path: str | None, samples: list, run: _Run,
                reason: str, started: str, c0: dict[str, int], off: bool | None,
                meta: dict[str, str] | None) -> RecordResult:
        from firmware_io.convert import record_from_samples

        c1 = self.link.counters.as_dict()
        counters = {k: int(c1[k] - c0[k]) for k in COUNTER_KEYS}
        if not reason:          # a program the device did not follow is no record of it (issue 44)
            reason = commands_not_applied(counters["commands_sent"], counters["commands_applied"]) or ""
        result = RecordResult(name, None, not reason, reason, counters=counters, commands_late=run.late,
                              first_burst_delay=run.delay)
        start = run.start - self.tare_samples
        end = run.start + run.n
        window = [s for i, s in samples if start <= i < end]
        if not window:
            return result
        result.first_index = next(i for i, _ in samples if start <= i < end)
        record_meta = {"experiment": name, "program": program.source, "fs_hz": f"{self.fs_hz:g}",
                       **self.meta, **(meta or {}), "start_time": started, "complete": str(not reason).lower()}
        if reason:
            record_meta["incomplete"] = reason
        if off is False:
            record_meta["actuator_off"] = "not confirmed (device gone: its watchdog stops the actuator)"
        record_meta.update({"tare_s": f"{self.tare_samples / self.fs_hz:g}",
                            "first_burst_delay_samples": "none" if run.delay is None else str(run.delay),
                            **{k: str(v) for k, v in counters.items()}, "commands_late": str(run.late)})
        try:
            rec = record_from_samples(window, self.calibration, fs_hz=self.fs_hz, seq_modulus=self.link.seq_modulus,
                                      name=name, meta=record_meta)
        except UserError as exc:   # e.g. interrupted before the tare: nothing to tare with
            result.reason = f"{reason or 'complete'}; no record written ({exc})"
            result.complete = False
            return result
        index = result.first_index + np.rint(rec.t * self.fs_hz).astype(np.int64)
        rec.cmu_envelope = np.asarray(self.calibration.cmu_from_volts(
            run.applied_cv(index, np.rint(rec.extra["envelope_volts"] * 100.0)) / 100.0), dtype=float)
        result.samples = len(rec)
        result.record = rec
        if len(rec):
            result.dcl_range = (float(np.min(rec.dcl)), float(np.max(rec.dcl)))
        if out_path is not None:
            try:
                tmp = f"{out_path}.part"
                write_record(tmp, rec)
                os.replace(tmp, out_path)
            except OSError as exc:
                raise UserError(f"{out_path}: cannot write record ({exc.strerror or exc})") from None
            result.path = out_path
        return result


class _Run:
    """The schedule of one experiment on the device's clock (module docstring)."""

    def __init__(self, rec: Recorder, program: Program) -> None:
        self.rec = rec
        self.program = program
        fs = rec.fs_hz
        self.n = program.samples(fs)
        self.onsets = program.onsets(fs)
        cv = rec.envelope_cv
        self.off = _State(0, OFF_PERIOD_MS, False)
        # (program sample of the onset, of the onset before it, the state from that onset on); a
        # state is sent just after the onset before it, or LEAD_SAMPLES ahead for the first; the
        # program's end switches the actuator off
        states = [(o.sample, _State(cv(o.envelope_v), o.period_ms, o.envelope_v > 0)) for o in self.onsets]
        last_period = states[-1][1].period_ms if states else OFF_PERIOD_MS
        states.append((self.n, _State(0, last_period, False)))
        self.steps: list[tuple[int, int | None, _State]] = []
        for j, (at, state) in enumerate(states):
            if j == 0 or state != states[j - 1][1]:
                self.steps.append((at, states[j - 1][0] if j else None, state))
        self.first_on = next((k for k, (_, _, st) in enumerate(self.steps) if st.enable), None)
        self.start = 0
        self.delay: int | None = None
        self.late = 0
        self._onset_of: dict[int, int] = {}

    def applied_cv(self, index: np.ndarray, reported_cv: np.ndarray) -> np.ndarray:
        """The envelope in effect at device samples ``index`` (0.01 V): the one the device reports
        at each onset, held to the next (PROTOCOL.md: a command's envelope takes effect at the
        next burst onset); 0 before the first onset."""
        onsets = self.start + np.array([o.sample for o in self.onsets] + [self.n], dtype=np.int64)
        at = np.searchsorted(index, onsets)
        ok = at < len(index)
        value = np.zeros(len(onsets))
        value[ok] = reported_cv[at[ok]]
        which = np.searchsorted(onsets, index, side="right") - 1
        return np.where(which >= 0, value[np.maximum(which, 0)], 0.0)

    def loop(self, samples: list, bar: Any = None) -> str:
        """Receive and command until the program's end; '' when complete, else why not."""
        rec = self.rec
        link = rec.link
        c0 = link.counters
        bad0 = c0.lost + c0.crc_errors
        got = 0
        s = rec._next()
        if s is None:
            return "device gone" if link.disconnected else f"device silent for {SILENCE_S:g} s"
        t0 = rec._index
        rec._send(self.off)
        self.start = t0 + rec.settle_samples + rec.tare_samples
        nominal = self.start
        step = 0
        first = self.steps[self.first_on][0] if self.first_on is not None else 0
        aligned = self.first_on is None
        wait_until = None
        while True:
            i = rec._index
            # kept from LEAD_SAMPLES before the tare's nominal start: the first burst can come up to
            # LEAD_SAMPLES - 1 before its nominal onset (the command goes out LEAD_SAMPLES ahead and the
            # off state's onsets run on their own clock), and the program's origin, hence the tare,
            # moves with it (the record then had one row too few and every burst one sample early)
            if i >= t0 + rec.settle_samples - LEAD_SAMPLES:
                samples.append((i, s))
            if bar is not None and bar.n + 1 < bar.total:
                bar.update(1)
            got += 1
            if self._onset_of and s.cmd_seq in self._onset_of:
                if i >= self._onset_of.pop(s.cmd_seq):
                    self.late += 1
            if not aligned:
                if s.volt_cv > 0 and i > nominal + first - LEAD_SAMPLES:
                    self.start = i - first
                    self.delay = self.start - nominal
                    aligned = True
                elif wait_until is not None and i >= wait_until:
                    aligned = True      # no burst seen: keep the nominal timing
            if aligned and i >= self.start + self.n - 1:
                return ""
            bad = link.counters.lost + link.counters.crc_errors - bad0
            if bad > BAD_FRAMES_FLOOR + BAD_FRAMES_SHARE * got:
                return f"link too bad ({bad} samples lost or frames invalid in {got})"
            sent = False
            if step < len(self.steps) and (aligned or step <= self.first_on):
                at, before, state = self.steps[step]
                due = self.start + (at - LEAD_SAMPLES if before is None or step == self.first_on else before + 1)
                if i + link.backlog() >= due and rec._free():   # where the device is now, not the sample in hand
                    cmd_seq = rec._send(state)
                    if cmd_seq is not None:
                        self._onset_of[cmd_seq] = self.start + at
                    if step == self.first_on:
                        wait_until = self.start + at + int(rec.fs_hz) + samples_of_ms(OFF_PERIOD_MS, rec.fs_hz)
                    step += 1
                    sent = True
            if not sent:
                rec._keepalive()
            s = rec._next()
            if s is None:
                return "device gone" if link.disconnected else f"device silent for {SILENCE_S:g} s"
