"""The serial wire (COBS + CRC packets through pyserial): :class:`SerialLink`."""

from __future__ import annotations

import errno
import select
import time
from collections import deque
from collections.abc import Callable

import serial

from firmware_io.calibration import Calibration
from firmware_io.commands import SERIAL_CMD_SEQ_MODULUS, CommandTracker
from firmware_io.errors import LinkError
from firmware_io.link_base import POLL_S, SAMPLE_WIRE_BYTES, SERIAL_BAUD, Link, Reconnect, one_line
from firmware_io.samples import Sample
from firmware_io.serial_codec import SEQ_MODULUS as SERIAL_SEQ_MODULUS
from firmware_io.serial_codec import SerialDecoder, encode_command
from rtlift.core.rate import PERIOD_S


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
        self._decoder = SerialDecoder(self._queue.append, cal)
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
            raise LinkError(f"serial port {port}: cannot open ({one_line(exc)})") from None
        except (ValueError, OSError) as exc:
            raise LinkError(f"serial port {port}: cannot open ({one_line(exc)})") from None
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
                if not waiting:
                    self._waiting(time.perf_counter())
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
                self._heard(time.perf_counter())
                if self._log is not None:
                    self._log.write(data)
                self._decoder.feed(data)
                if queue:
                    return self._delivered(queue.popleft())
