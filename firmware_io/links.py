"""Links: one small transport interface over the serial and CAN wire formats (like
python-can's ``Bus``): ``open_link(config)`` gives a :class:`Link` you iterate for
:class:`~firmware_io.samples.Sample` objects, with exact ``link.counters``.

Config dictionaries (DESIGN.md)::

    {"kind": "serial", "port": "/dev/ttyACM0"}          # any pyserial port or URL
    {"kind": "can", "interface": "slcan", "channel": "/dev/ttyACM0", "bitrate": 500000}

Optional keys: ``log`` (a path: ``.bin``/``.raw`` raw serial capture, ``.asc``/``.blf`` CAN
log, written as frames arrive), ``reconnect`` (``True``, a number of seconds to give up after,
or a dict of :class:`Reconnect` fields: when the device vanishes, reopen it with backoff and
go on with the same counters and log), ``calibration`` (serial only: a
:class:`~firmware_io.calibration.Calibration` or a TOML path, for counts per N and N·m),
``spin`` (serial only: ``true`` busy-polls the port between samples instead of blocking in the
kernel; a number W blocks until W ms before the next sample is due and busy-polls from there).
Any other key of a CAN config is passed to ``can.Bus`` (``ignore_config=True`` is the
default, and ``sleep_after_open=0`` for ``slcan``). ``slcan`` opens python-can's slcan driver
reading the port in chunks (:class:`firmware_io.slcan.ChunkedSlcanBus`; ``"slcan_chunked_read":
false`` for python-can's byte-at-a-time reader).

Protocol version 2: ``link.send_command(envelope_cv, ...)`` sends a command with the link's
next ``cmd_seq`` (serial: a COBS packet through pyserial; CAN: the ``CMD`` frame through
``bus.send``); ``commands_sent``, ``commands_applied``, ``watchdog_trips`` and the command
latency are in ``link.counters``. On a link with a ``log``, every command sent also goes to
``LOG.commands.csv`` (:class:`~firmware_io.logs.CommandLog`) with the number of samples
received before it, so ``rtlift replay`` can rerun the controller and check its commands.
"""

from __future__ import annotations

import argparse
import errno
import math
import os
import select
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, fields
from typing import Any

import can
import serial

from firmware_io.calibration import Calibration
from firmware_io.can_codec import CMD_ID, CanAssembler, encode_command_frame
from firmware_io.can_codec import SEQ_MODULUS as CAN_SEQ_MODULUS
from firmware_io.commands import CAN_CMD_SEQ_MODULUS, SERIAL_CMD_SEQ_MODULUS, CommandTracker
from firmware_io.errors import LinkError
from firmware_io.logs import CommandLog, LoggedCommand, commands_path, open_link_log
from firmware_io.samples import Counters, Sample
from firmware_io.serial_codec import SEQ_MODULUS as SERIAL_SEQ_MODULUS
from firmware_io.serial_codec import SerialDecoder, encode_command
from firmware_io.slcan import ChunkedSlcanBus
from rtlift.core.rate import FS_HZ, PERIOD_S

SERIAL_BAUD = 921_600
CAN_BITRATE = 500_000
SAMPLE_WIRE_BYTES = 43
"""A version-2 sample packet on the serial wire: 41 bytes, COBS code byte and 0x00 delimiter."""
CAN_SAMPLE_WIRE_BYTES = 66
"""A sample's three frames as SLCAN lines (``tIIIL`` + 16 hex digits + CR, 22 bytes each)."""
POLL_S = 0.02
"""Longest single wait inside the serial reader; ``recv(timeout)`` is accurate to this."""


def _one_line(exc: BaseException) -> str:
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


class SerialLink(Link):
    """Samples from COBS packets on a serial port (PROTOCOL.md, "Serial link")."""

    kind = "serial"
    seq_modulus = SERIAL_SEQ_MODULUS
    t_us_modulus = 1 << 32

    def __init__(self, port: str, *, calibration: Calibration | None = None, log: str | None = None,
                 reconnect: Reconnect | None = None, spin: bool = False,
                 spin_window_s: float | None = None) -> None:
        self.closed = True
        self.spin = spin
        """Busy-poll the port while waiting for the next sample instead of blocking in the
        kernel (opt-in low latency: the core stays on this process and its caches warm, at the
        price of that core; ``rtlift observe --spin``)."""
        self.on_idle: Callable[[], None] | None = None
        """Called between polls while spinning (the live loop's observer keeps its working set
        in the cache with it: :meth:`rtlift.observer.Observer.touch`)."""
        self.spin_window_s = spin_window_s
        """With ``spin``: block in the kernel until this long before the next sample is due
        (the last one's receipt + 1/400 s), and spin only from there (None: spin throughout; so
        does a port without a file descriptor to wait on, such as some pyserial URLs)."""
        cal = calibration or Calibration()
        self._queue: deque[Sample] = deque()
        self._decoder = SerialDecoder(self._queue.append, cal.counts_per_n, cal.counts_per_nm)
        self.counters = self._decoder.counters
        self._commands = CommandTracker(self.counters, SERIAL_CMD_SEQ_MODULUS)
        self.port = self._where = port
        self.reconnect = reconnect
        self._ser = None
        self._fd: int | None = None
        self._start(port, log)

    def _open_device(self, port: str) -> None:
        try:
            self._ser = serial.serial_for_url(port, baudrate=SERIAL_BAUD, timeout=POLL_S)
            try:        # a file descriptor to wait on for a spin window (a pyserial URL may have none)
                self._fd = self._ser.fileno()
            except (AttributeError, OSError, ValueError):
                self._fd = None
        except serial.SerialException as exc:
            if exc.errno == errno.ENOENT:
                raise LinkError(f"serial port {port}: no such device") from None
            raise LinkError(f"serial port {port}: cannot open ({_one_line(exc)})") from None
        except (ValueError, OSError) as exc:
            raise LinkError(f"serial port {port}: cannot open ({_one_line(exc)})") from None
        self.port = port

    def _close_device(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except (serial.SerialException, OSError):
                pass

    def _restart_stream(self) -> None:
        self._decoder.restart()

    def _encode_command(self, cmd_seq: int, envelope_cv: int, burst_period_ms: int, enable: bool,
                        watchdog_ms_div10: int) -> bytes:
        return encode_command(cmd_seq, envelope_cv, burst_period_ms, enable, watchdog_ms_div10)

    def _write_command(self, wire: bytes) -> bool:
        try:
            self._ser.write(wire)
        except (serial.SerialException, OSError):
            self._device_gone()
            return False
        return True

    def backlog(self) -> int:
        ser = self._ser
        try:
            waiting = ser.in_waiting if ser is not None else 0
        except (serial.SerialException, OSError):
            waiting = 0
        return len(self._queue) + waiting // SAMPLE_WIRE_BYTES

    @property
    def events(self) -> list[str]:
        return list(self._decoder.events)

    def recv(self, timeout: float | None = None) -> Sample | None:
        queue = self._queue
        if queue:
            return self._delivered(queue.popleft())
        if self.closed or self.disconnected:
            return None
        deadline = None if timeout is None else time.perf_counter() + timeout
        if self._down_since is not None and not self._wait_device(deadline):
            return None
        ser = self._ser
        while True:
            try:
                waiting = ser.in_waiting
                if not waiting and deadline is not None and time.perf_counter() >= deadline:
                    return None
                if not waiting and self.spin:
                    if self.spin_window_s is not None and self._last is not None and self._fd is not None:
                        rest = self._last.host_time + PERIOD_S - self.spin_window_s - time.perf_counter()
                        if deadline is not None:
                            rest = min(rest, deadline - time.perf_counter())
                        if rest > 0.0:              # not due yet: wait in the kernel for data or the window
                            select.select([self._fd], [], [], rest)
                            continue
                        if rest < -PERIOD_S:     # overdue by a period: the device is late, stop spinning
                            select.select([self._fd], [], [], POLL_S)
                            continue
                    if self.on_idle is not None:
                        self.on_idle()
                    continue
                data = ser.read(waiting or 1)
            except (serial.SerialException, OSError):
                self._device_gone()
                if self._down_since is None or not self._wait_device(deadline):
                    return None
                ser = self._ser
                continue
            if data:
                if self._log is not None:
                    self._log.write(data)
                self._decoder.feed(data)
                if queue:
                    return self._delivered(queue.popleft())


class CanLink(Link):
    """Samples assembled from the three CAN frames per ``seq`` (PROTOCOL.md, "CAN bus"),
    through any python-can interface."""

    kind = "can"
    seq_modulus = CAN_SEQ_MODULUS
    t_us_modulus = 655_360

    def __init__(self, interface: str, channel: Any, bitrate: int | None = CAN_BITRATE, *,
                 log: str | None = None, reconnect: Reconnect | None = None, **bus_kwargs: Any) -> None:
        self.closed = True
        self._assembler = CanAssembler()
        self.counters = self._assembler.counters
        self._commands = CommandTracker(self.counters, CAN_CMD_SEQ_MODULUS)
        self.interface = interface
        self.channel = self._where = channel
        self.reconnect = reconnect
        kwargs = dict(bus_kwargs)
        kwargs.setdefault("ignore_config", True)
        self._chunked_slcan = interface == "slcan" and bool(kwargs.pop("slcan_chunked_read", True))
        if interface == "slcan":
            kwargs.setdefault("sleep_after_open", 0)
        if bitrate is not None:
            kwargs["bitrate"] = bitrate
        self._bus_kwargs = kwargs
        if interface not in can.VALID_INTERFACES:
            raise LinkError(f"CAN {interface}:{channel}: unknown CAN interface {interface!r} "
                            f"(python-can knows {', '.join(sorted(can.VALID_INTERFACES))})")
        self._bus = None
        self._start(channel, log)

    def _open_device(self, channel: Any) -> None:
        where = f"CAN {self.interface}:{channel}"
        try:
            if self._chunked_slcan:        # python-can's slcan driver, reading in chunks (firmware_io.slcan)
                kwargs = {k: v for k, v in self._bus_kwargs.items() if k != "ignore_config"}
                self._bus = ChunkedSlcanBus(channel=channel, **kwargs)
            else:
                self._bus = can.Bus(interface=self.interface, channel=channel, **self._bus_kwargs)
        except NotImplementedError as exc:
            raise LinkError(f"{where}: interface not available ({_one_line(exc)})") from None
        except (can.CanError, OSError, ValueError, TypeError, ImportError, serial.SerialException) as exc:
            raise LinkError(f"{where}: cannot open ({_one_line(exc)})") from None
        self.channel = channel

    def _close_device(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError, serial.SerialException, ValueError):
                pass

    def _restart_stream(self) -> None:
        self._assembler.restart()

    def backlog(self) -> int:
        bus = self._bus
        return bus.pending_bytes() // CAN_SAMPLE_WIRE_BYTES if isinstance(bus, ChunkedSlcanBus) else 0

    def _encode_command(self, cmd_seq: int, envelope_cv: int, burst_period_ms: int, enable: bool,
                        watchdog_ms_div10: int) -> can.Message:
        _, data = encode_command_frame(cmd_seq, envelope_cv, burst_period_ms, enable, watchdog_ms_div10)
        return can.Message(arbitration_id=CMD_ID, data=data, is_extended_id=False)

    def _write_command(self, wire: can.Message) -> bool:
        try:
            self._bus.send(wire)
        except (can.CanError, OSError, serial.SerialException):
            self._device_gone()
            return False
        return True

    def recv(self, timeout: float | None = None) -> Sample | None:
        if self.closed or self.disconnected:
            return None
        deadline = None if timeout is None else time.perf_counter() + timeout
        if self._down_since is not None and not self._wait_device(deadline):
            return None
        bus = self._bus
        assembler = self._assembler
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.perf_counter())
            try:
                msg = bus.recv(remaining)
            except (ValueError, IndexError, UnicodeDecodeError):
                # a line the adapter driver could not parse (e.g. slcan on a noisy link)
                self.counters.crc_errors += 1
                continue
            except (can.CanError, OSError, serial.SerialException):
                self._device_gone()
                if self._down_since is None or not self._wait_device(deadline):
                    return None
                bus = self._bus
                continue
            if msg is None:
                if deadline is None:
                    continue
                return None
            if self._log is not None:
                self._log(msg)
            sample = assembler.feed_message(msg)
            if sample is not None:
                return self._delivered(sample)
            if deadline is not None and time.perf_counter() >= deadline:
                return None


def spin_window_s(ms: Any) -> float:
    """A spin window given in ms (link config ``"spin": W``, ``rtlift observe --spin W``), in
    seconds; ValueError unless it is a number inside one sample period."""
    try:
        value = float(ms)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(ms, bool) or not 0.0 < value < 1e3 / FS_HZ:
        raise ValueError(f"a window in ms between 0 and {1e3 / FS_HZ:g}, got {ms!r}")
    return value / 1e3


def open_link(config: dict[str, Any]) -> Link:
    """Open the link a config dictionary describes (see the module docstring)."""
    cfg = dict(config)
    kind = cfg.pop("kind", None)
    if kind == "serial":
        port = cfg.pop("port", None)
        if not port:
            raise LinkError("serial link: no port given")
        calibration = cfg.pop("calibration", None)
        if calibration is not None and not isinstance(calibration, Calibration):
            calibration = Calibration.load(calibration)
        log = cfg.pop("log", None)
        reconnect = Reconnect.from_config(cfg.pop("reconnect", None))
        spin = cfg.pop("spin", False)
        window = None
        if not isinstance(spin, bool):
            try:
                window, spin = spin_window_s(spin), True
            except ValueError as exc:
                raise LinkError(f"serial link: spin must be true, false or {exc}") from None
        if cfg:
            raise LinkError(f"serial link: unknown option {sorted(cfg)[0]!r}")
        return SerialLink(str(port), calibration=calibration, log=log, reconnect=reconnect, spin=spin,
                          spin_window_s=window)
    if kind == "can":
        interface = cfg.pop("interface", None)
        channel = cfg.pop("channel", None)
        if not interface:
            raise LinkError("CAN link: no interface given")
        bitrate = cfg.pop("bitrate", CAN_BITRATE)
        log = cfg.pop("log", None)
        reconnect = Reconnect.from_config(cfg.pop("reconnect", None))
        cfg.pop("calibration", None)
        return CanLink(str(interface), channel, bitrate, log=log, reconnect=reconnect, **cfg)
    raise LinkError(f"link kind must be 'serial' or 'can', got {kind!r}")


def parse_can_spec(spec: str) -> dict[str, Any]:
    """``INTERFACE:CHANNEL`` (the ``--can`` form) → a CAN link config (500 kbit/s)."""
    interface, sep, channel = spec.partition(":")
    if not sep or not interface or not channel:
        raise LinkError(f"--can expects INTERFACE:CHANNEL (for example slcan:/dev/ttyACM0), got {spec!r}")
    return {"kind": "can", "interface": interface, "channel": channel, "bitrate": CAN_BITRATE}


def link_config(serial_port: str | None = None, can_spec: str | None = None, **extra: Any) -> dict[str, Any]:
    """The config for the CLI forms ``--serial PORT`` or ``--can INTERFACE:CHANNEL``
    (exactly one), plus ``extra`` keys such as ``log``."""
    if (serial_port is None) == (can_spec is None):
        raise LinkError("give exactly one of --serial PORT or --can INTERFACE:CHANNEL")
    cfg = {"kind": "serial", "port": serial_port} if serial_port is not None else parse_can_spec(can_spec)
    cfg.update({k: v for k, v in extra.items() if v is not None})
    return cfg


def add_link_arguments(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """Add the mutually exclusive ``--serial PORT`` / ``--can INTERFACE:CHANNEL`` options."""
    group = parser.add_mutually_exclusive_group(required=required)
    group.add_argument("--serial", metavar="PORT", help="serial port or pyserial URL of the DAQ")
    group.add_argument("--can", metavar="INTERFACE:CHANNEL",
                       help="python-can interface and channel, e.g. slcan:/dev/ttyACM0")


def add_reconnect_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--reconnect [GIVE_UP_S]`` (read by :func:`link_config_from_args`)."""
    parser.add_argument("--reconnect", nargs="?", const=-1.0, type=float, metavar="GIVE_UP_S",
                        help="when the device vanishes, reopen it with backoff (for ever, or give up after "
                             "GIVE_UP_S seconds) and go on with the same log and summary")


def link_config_from_args(args: argparse.Namespace, **extra: Any) -> dict[str, Any]:
    """The link config from options added by :func:`add_link_arguments` (and
    :func:`add_reconnect_argument`); :class:`LinkError` for a negative give-up time."""
    give_up = getattr(args, "reconnect", None)
    if give_up is not None:
        if give_up != -1.0 and not give_up >= 0:
            raise LinkError(f"--reconnect: give-up time must be >= 0 seconds, got {give_up}")
        extra.setdefault("reconnect", True if give_up == -1.0 else {"give_up_s": give_up})
    return link_config(getattr(args, "serial", None), getattr(args, "can", None), **extra)
