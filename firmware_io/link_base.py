"""The transport interface every link implements (:class:`Link`): counters, logs, reconnection
with backoff, commands (protocol version 2); the serial and CAN wires are
:mod:`firmware_io.serial_link` and :mod:`firmware_io.can_link`, and :func:`firmware_io.links.open_link`
opens one from a config dictionary."""

from __future__ import annotations

import os
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass, fields
from typing import Any

from firmware_io.commands import DEFAULT_WATCHDOG_MS, WATCHDOG_STEP_MS, CommandTracker
from firmware_io.errors import LinkError
from firmware_io.logs import CommandLog, LoggedCommand, commands_path, open_link_log
from firmware_io.samples import Counters, Sample
from rtlift.core.rate import FS_HZ

DEVICE_SILENCE_S = 5.0
"""Host seconds with the link up and no valid sample after which a run counts the device as gone
(``rtlift record``, ``observe``, ``control``, the demo). Longer than the wire's own stalls: on a
busy VM the pseudo-terminal carried nothing either way for 0.4–5 s while both ends ran
(docs/results/control.md, "Host command timing under load"); nothing is lost in one, the bytes
come after it."""

SERIAL_BAUD = 921_600
CAN_BITRATE = 500_000
SAMPLE_WIRE_BYTES = 43
"""A version-2 sample packet on the serial wire: 41 bytes, COBS code byte and 0x00 delimiter."""
CAN_SAMPLE_WIRE_BYTES = 66
"""A sample's three frames as SLCAN lines (``tIIIL`` + 16 hex digits + CR, 22 bytes each)."""
POLL_S = 0.02
"""Longest single wait inside the serial reader; ``recv(timeout)`` is accurate to this."""


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


@dataclass(frozen=True)
class Reconnect:
    """What a link does when its device vanishes (an unplugged or re-enumerating adapter):
    close it, then try to reopen it — the configured port or channel, then each of
    ``also`` in turn — after ``first_delay_s``, doubling to ``max_delay_s`` between tries,
    until it is back or ``give_up_s`` passed (``None``: forever). While it is down, every
    candidate that is a filesystem path (a serial port, an SLCAN adapter's tty, a udev
    ``/dev/serial/by-id`` link) is looked at every ``watch_s``: one that appears, or now
    names another device node, is opened at once, so the backoff only limits how often a
    failing open is retried, never how soon a device that came back is read. ``fs_hz`` is
    the device's sample rate, for the host-clock check of the gap."""

    give_up_s: float | None = None
    first_delay_s: float = 0.05
    max_delay_s: float = 1.0
    also: tuple[str, ...] = ()
    fs_hz: float = FS_HZ
    watch_s: float = 0.005

    @classmethod
    def from_config(cls, value: Any) -> Reconnect | None:
        """``None``/``False`` (off), ``True``, seconds to give up after, or a dict of fields."""
        if value is None or value is False:
            return None
        if value is True:
            return cls()
        if isinstance(value, (int, float)):
            value = {"give_up_s": value}
        if not isinstance(value, dict):
            raise LinkError(f"reconnect: expected true, seconds or a table, got {value!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(value) - known)
        if unknown:
            raise LinkError(f"reconnect: unknown option {unknown[0]!r} (known: {', '.join(sorted(known))})")
        try:
            r = cls(**{**value, "also": tuple(str(p) for p in value.get("also", ()))})
            ok = ((r.give_up_s is None or r.give_up_s >= 0) and 0 < r.first_delay_s <= r.max_delay_s
                  and r.fs_hz > 0 and r.watch_s > 0)
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise LinkError(f"reconnect: give_up_s >= 0, 0 < first_delay_s <= max_delay_s, fs_hz > 0 and "
                            f"watch_s > 0 expected, got {value!r}")
        return r


def _node(where: Any) -> tuple[int, int, int] | None:
    """The device node a path names now (device, inode, rdev; a symlink followed), or
    ``None`` when it is absent or ``where`` is no path (a PCAN channel name, a URL)."""
    if not (isinstance(where, str) and where.startswith("/")):
        return None
    try:
        st = os.stat(where.split("@", 1)[0])
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_rdev


class Link(ABC):
    """A source of samples. ``recv(timeout)`` returns the next sample, or ``None`` on
    timeout or once the device is gone (then ``disconnected`` is true) or the link is
    closed. Iterating yields samples until the device disappears or the link is closed."""

    kind: str
    seq_modulus: int
    t_us_modulus: int
    counters: Counters
    disconnected: bool = False
    closed: bool = False
    reconnect: Reconnect | None = None
    on_gap: Callable[[int, bool], object] | None = None
    """Called with (samples missed, known from ``seq``) before the first sample after a
    reconnect is returned (an observer loop predicts through the gap)."""
    _down_since: float | None = None
    _down_before: float = 0.0
    _gap_pending: bool = False
    _last: Sample | None = None
    _gap_from: Sample | None = None
    delivered: int = 0
    """Samples ``recv`` has returned (the position a command log records)."""
    command_log_meta: dict[str, Any] | None = None
    """Metadata of the command log (``LOG.commands.csv``), opened with the first command sent
    on a link with a ``log``: what a replay needs to rerun the controller."""
    _log_path: str | None = None
    _command_log: Any = None
    watchdog_ms: int = DEFAULT_WATCHDOG_MS
    """The device watchdog the link's commands set (PROTOCOL.md: ``watchdog_ms``, 500 ms until a
    command sets another)."""
    silence_max_s: float = 0.0
    """The longest silence of the wire (s): the host waited for the device's next bytes with
    nothing received (:meth:`_silence`). The host's own pauses between reads are not in it."""
    stalls: int = 0
    """Silences that held the commands back for the device's watchdog (:meth:`_heard`): a host
    that sends on samples has nothing to send while none arrive, so the watchdog trips whatever
    the host does (on a busy VM the pseudo-terminal carried nothing either way for 0.7–5 s while
    both ends ran: docs/results/control.md, "Host command timing under load")."""
    _silent_since: float | None = None
    _last_sent: float | None = None

    def _waiting(self, now: float) -> None:
        """The host found nothing to read at ``now`` (host clock, s) and waits for the wire."""
        if self._silent_since is None:
            self._silent_since = now

    def _heard(self, now: float) -> None:
        """Bytes arrived at ``now``: the silence since :meth:`_waiting`, if any, ends
        (``silence = now − since``). It is a stall when the last command went out at least
        ``watchdog_ms`` ago (``now − sent ≥ watchdog``: the device heard nothing for as long)
        and the wire's silence is the larger part of that (``silence > since − sent``, the
        host's own share)."""
        since = self._silent_since
        if since is not None:
            self._silent_since = None
            silence = now - since
            if silence > self.silence_max_s:
                self.silence_max_s = silence
            sent = self._last_sent
            if sent is not None and (now - sent) * 1000.0 >= self.watchdog_ms and silence > since - sent:
                self.stalls += 1

    @property
    def down(self) -> bool:
        """The device is gone and the link is trying to get it back (``reconnect``)."""
        return self._down_since is not None

    @property
    def seconds_down(self) -> float:
        """Host seconds the device has been gone in all (the gaps before and the one now)."""
        now = time.perf_counter()
        return self._down_before + (0.0 if self._down_since is None else now - self._down_since)

    def _start(self, where: Any, log: str | None) -> None:
        """Open the device and the log (nothing left open if either fails)."""
        self._open_device(where)
        self.closed = False
        try:
            self._log = open_link_log(log, self.kind) if log else None
            self._log_path = log
        except BaseException:
            self._close_device()
            self.closed = True
            raise

    # -- reconnection (the same for every kind; subclasses open and close the device) ----
    @abstractmethod
    def _open_device(self, where: Any) -> None:
        """Open the port or bus at ``where`` (raise :class:`LinkError` if it is not there)."""

    @abstractmethod
    def _close_device(self) -> None:
        """Close the port or bus only (the log stays open)."""

    @abstractmethod
    def _restart_stream(self) -> None:
        """Forget the partial stream of the device that vanished (counters go on)."""

    def _device_gone(self) -> None:
        """The port or bus failed: reconnect if asked to, else end the link."""
        self._silent_since = None           # a device gone is a reconnect, not a silence of the wire
        self._close_device()
        policy = self.reconnect
        if policy is None:
            self.disconnected = True
            self.close()
            return
        now = time.perf_counter()
        self._down_since = now
        self._delay = policy.first_delay_s
        self._next_try = now + self._delay
        self._gap_from = self._last
        self._watched = {where: _node(where) for where in (self._where, *policy.also)}

    def _wait_device(self, deadline: float | None) -> bool:
        """Try to reopen the device until it is back (``True``), ``deadline`` passed or the
        policy gave up (``False``; then ``disconnected``). A watched path that appeared (or
        names a new node) since the last look is tried at once; all are tried on the backoff."""
        policy = self.reconnect
        while True:
            now = time.perf_counter()
            appeared = []
            for where, before in self._watched.items():
                node = _node(where)
                if node is not None and node != before:
                    appeared.append(where)
                self._watched[where] = node
            if appeared or now >= self._next_try:
                for where in appeared if now < self._next_try else (self._where, *policy.also):
                    try:
                        self._open_device(where)
                    except LinkError:
                        continue
                    self._restart_stream()
                    self.counters.reconnects += 1
                    self._down_before += now - self._down_since
                    self._down_since = None
                    self._gap_pending = self._gap_from is not None
                    return True
                if policy.give_up_s is not None and now - self._down_since >= policy.give_up_s:
                    self.disconnected = True
                    self.close()
                    return False
                if now >= self._next_try:
                    self._delay = min(2 * self._delay, policy.max_delay_s)
                    self._next_try = now + self._delay
            wake = self._next_try if deadline is None else min(self._next_try, deadline)
            if any(isinstance(w, str) and w.startswith("/") for w in self._watched):
                wake = min(wake, now + policy.watch_s)
            if deadline is not None and now >= deadline:
                return False
            time.sleep(max(0.0, wake - now))

    def _close_gap(self, first: Sample) -> None:
        """Count the samples missed between the last sample before the device vanished and
        ``first`` after it came back: from ``seq`` when the host clock and the device clock
        agree with it (the device kept counting), else an estimate from the host clock."""
        self._gap_pending = False
        last = self._gap_from
        c = self.counters
        fs = self.reconnect.fs_hz
        host_steps = (first.host_time - last.host_time) * fs
        seq_steps = (first.seq - last.seq) % self.seq_modulus
        tol = 0.25 * fs + 0.1 * host_steps
        known = host_steps + tol < self.seq_modulus and abs(seq_steps - host_steps) <= tol and seq_steps > 0
        period_us = 1e6 / fs
        if known and host_steps * period_us < self.t_us_modulus / 2:
            dt_us = (first.t_us - last.t_us) % self.t_us_modulus
            known = abs(dt_us - seq_steps * period_us) <= max(period_us / 2, 1e-3 * dt_us)
        if known:
            missed = seq_steps - 1
            c.lost += missed
            c.gap_lost += missed
        else:
            missed = max(0, round(host_steps) - 1)
            c.gaps_unknown += 1
            c.gap_lost_estimated += missed
        if self.on_gap is not None:
            self.on_gap(missed, known)

    _commands: CommandTracker

    def send_command(self, envelope_cv: int, burst_period_ms: int = 0, enable: bool = True,
                     watchdog_ms_div10: int = 0) -> int | None:
        """Send one command (PROTOCOL.md, "Version 2") with the link's next ``cmd_seq`` and
        return that ``cmd_seq``; ``None`` when the device is gone or being reconnected (nothing
        was sent or counted). Values out of range raise ``ValueError`` before anything is
        sent; a link closed by its user raises :class:`LinkError`. Call it from the thread
        that calls ``recv``."""
        if self.disconnected or self._down_since is not None:
            return None
        if self.closed:
            raise LinkError(f"{self.kind} link is closed: cannot send a command")
        tracker = self._commands
        cmd_seq = tracker.next_seq()
        wire = self._encode_command(cmd_seq, envelope_cv, burst_period_ms, enable, watchdog_ms_div10)
        now = time.perf_counter()
        if not self._write_command(wire):
            return None
        tracker.sent(cmd_seq, now)
        self._last_sent = now
        if watchdog_ms_div10:
            self.watchdog_ms = watchdog_ms_div10 * WATCHDOG_STEP_MS
        if self._log_path is not None:
            self._log_command(now, LoggedCommand(self.delivered, cmd_seq, envelope_cv, burst_period_ms,
                                                 bool(enable), watchdog_ms_div10))
        return cmd_seq

    def _log_command(self, host_time: float, command: LoggedCommand) -> None:
        if self._command_log is None:
            self._command_log = CommandLog(commands_path(self._log_path),
                                           {"link": self.kind, **(self.command_log_meta or {})})
            self._command_t0 = host_time
        self._command_log.write(host_time - self._command_t0, command)

    @abstractmethod
    def _encode_command(self, cmd_seq: int, envelope_cv: int, burst_period_ms: int, enable: bool,
                        watchdog_ms_div10: int) -> Any:
        """The command as this link's wire carries it."""

    @abstractmethod
    def _write_command(self, wire: Any) -> bool:
        """Write a command; ``False`` (and the device handled as gone) if the write failed."""

    def _delivered(self, sample: Sample) -> Sample:
        """Bookkeeping of every sample ``recv`` returns."""
        self._last = sample
        self.delivered += 1
        self._commands.received(sample)
        if self._gap_pending:
            self._close_gap(sample)
        return sample

    @abstractmethod
    def recv(self, timeout: float | None = None) -> Sample | None:
        """The next sample; ``None`` after ``timeout`` seconds of silence (``None``: wait
        as long as the device is there) or when the device is gone or the link closed."""

    _log: Any = None

    def close(self) -> None:
        """Release the port or bus and flush and close the log (idempotent)."""
        if self.closed:
            return
        self.closed = True
        self._close_device()
        try:
            if self._log is not None:
                self._log.close()
        finally:
            if self._command_log is not None:
                self._command_log.close()

    def switch_log(self, log: str | None) -> None:
        """Close the frame log (and its command log) and log from now on to ``log`` (``None``:
        stop logging); the link, its counters and its ``cmd_seq`` go on."""
        old, self._log = self._log, None
        commands, self._command_log = self._command_log, None
        self._log_path = None
        try:
            if old is not None:
                old.close()
        finally:
            if commands is not None:
                commands.close()
        if log:
            self._log = open_link_log(log, self.kind)
            self._log_path = log

    def backlog(self) -> int:
        """Samples already received by the host that ``recv`` has not returned yet (a lower
        bound from the bytes waiting; 0 where the interface does not say): how far the device is
        ahead of the sample in hand."""
        return 0

    @property
    def events(self) -> list[str]:
        """Firmware event texts received so far (the most recent ones)."""
        return []

    def __iter__(self) -> Iterator[Sample]:
        while True:
            sample = self.recv(None)
            if sample is None:
                return
            yield sample

    def samples(self, timeout: float) -> Iterator[Sample | None]:
        """Samples as they arrive, ``None`` after each ``timeout`` seconds of silence (so a
        live loop notices a silent device); ends when the device is gone or the link closed."""
        while True:
            sample = self.recv(timeout)
            if sample is None and (self.disconnected or self.closed):
                return
            yield sample

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - never raise from a finaliser
            pass
