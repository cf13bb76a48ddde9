"""Links: one small transport interface over the serial and CAN wire formats (like
python-can's ``Bus``): ``open_link(config)`` gives a :class:`Link` you iterate for
:class:`~firmware_io.samples.Sample` objects, with exact ``link.counters``.

Config dictionaries (DESIGN.md)::

    {"kind": "serial", "port": "/dev/ttyACM0"}          # any pyserial port or URL
    {"kind": "can", "interface": "slcan", "channel": "/dev/ttyACM0", "bitrate": 500000}

Optional keys: ``log`` (a path: ``.bin``/``.raw`` raw serial capture, ``.asc``/``.blf`` CAN
log, written as frames arrive), ``calibration`` (serial only: a
:class:`~firmware_io.calibration.Calibration` or a TOML path, for counts per N and N·m).
Any other key of a CAN config is passed to ``can.Bus`` (``ignore_config=True`` is the
default, and ``sleep_after_open=0`` for ``slcan``).
"""

from __future__ import annotations

import argparse
import errno
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterator
from typing import Any

import can
import serial

from firmware_io.calibration import Calibration
from firmware_io.can_codec import SEQ_MODULUS as CAN_SEQ_MODULUS
from firmware_io.can_codec import CanAssembler
from firmware_io.errors import LinkError
from firmware_io.logs import open_link_log
from firmware_io.samples import Counters, Sample
from firmware_io.serial_codec import SEQ_MODULUS as SERIAL_SEQ_MODULUS
from firmware_io.serial_codec import SerialDecoder

SERIAL_BAUD = 921_600
CAN_BITRATE = 500_000
POLL_S = 0.02
"""Longest single wait inside the serial reader; ``recv(timeout)`` is accurate to this."""


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


class Link(ABC):
    """A source of samples. ``recv(timeout)`` returns the next sample, or ``None`` on
    timeout or once the device is gone (then ``disconnected`` is true) or the link is
    closed. Iterating yields samples until the device disappears or the link is closed."""

    kind: str
    seq_modulus: int
    counters: Counters
    disconnected: bool = False
    closed: bool = False

    @abstractmethod
    def recv(self, timeout: float | None = None) -> Sample | None:
        """The next sample; ``None`` after ``timeout`` seconds of silence (``None``: wait
        as long as the device is there) or when the device is gone or the link closed."""

    @abstractmethod
    def close(self) -> None:
        """Release the port or bus and flush and close the log (idempotent)."""

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

    def __init__(self, port: str, *, calibration: Calibration | None = None, log: str | None = None) -> None:
        self.closed = True
        cal = calibration or Calibration()
        self._queue: deque[Sample] = deque()
        self._decoder = SerialDecoder(self._queue.append, cal.counts_per_n, cal.counts_per_nm)
        self.counters = self._decoder.counters
        self.port = port
        try:
            self._ser = serial.serial_for_url(port, baudrate=SERIAL_BAUD, timeout=POLL_S)
        except serial.SerialException as exc:
            if exc.errno == errno.ENOENT:
                raise LinkError(f"serial port {port}: no such device") from None
            raise LinkError(f"serial port {port}: cannot open ({_one_line(exc)})") from None
        except (ValueError, OSError) as exc:
            raise LinkError(f"serial port {port}: cannot open ({_one_line(exc)})") from None
        self.closed = False
        try:
            self._log = open_link_log(log, "serial") if log else None
        except BaseException:
            self._ser.close()
            self.closed = True
            raise

    @property
    def events(self) -> list[str]:
        return list(self._decoder.events)

    def recv(self, timeout: float | None = None) -> Sample | None:
        queue = self._queue
        if queue:
            return queue.popleft()
        if self.closed or self.disconnected:
            return None
        deadline = None if timeout is None else time.perf_counter() + timeout
        ser = self._ser
        while True:
            try:
                waiting = ser.in_waiting
                if not waiting and deadline is not None and time.perf_counter() >= deadline:
                    return None
                data = ser.read(waiting or 1)
            except (serial.SerialException, OSError):
                self.disconnected = True
                self.close()
                return None
            if data:
                if self._log is not None:
                    self._log.write(data)
                self._decoder.feed(data)
                if queue:
                    return queue.popleft()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._ser.close()
        except (serial.SerialException, OSError):
            pass
        if self._log is not None:
            self._log.close()


class CanLink(Link):
    """Samples assembled from the three CAN frames per ``seq`` (PROTOCOL.md, "CAN bus"),
    through any python-can interface."""

    kind = "can"
    seq_modulus = CAN_SEQ_MODULUS

    def __init__(self, interface: str, channel: Any, bitrate: int | None = CAN_BITRATE, *,
                 log: str | None = None, **bus_kwargs: Any) -> None:
        self.closed = True
        self._assembler = CanAssembler()
        self.counters = self._assembler.counters
        self.interface = interface
        self.channel = channel
        kwargs = dict(bus_kwargs)
        kwargs.setdefault("ignore_config", True)
        if interface == "slcan":
            kwargs.setdefault("sleep_after_open", 0)
        if bitrate is not None:
            kwargs["bitrate"] = bitrate
        where = f"CAN {interface}:{channel}"
        if interface not in can.VALID_INTERFACES:
            raise LinkError(f"{where}: unknown CAN interface {interface!r} "
                            f"(python-can knows {', '.join(sorted(can.VALID_INTERFACES))})")
        try:
            self._bus = can.Bus(interface=interface, channel=channel, **kwargs)
        except NotImplementedError as exc:
            raise LinkError(f"{where}: interface not available ({_one_line(exc)})") from None
        except (can.CanError, OSError, ValueError, TypeError, ImportError) as exc:
            raise LinkError(f"{where}: cannot open ({_one_line(exc)})") from None
        self.closed = False
        try:
            self._log = open_link_log(log, "can") if log else None
        except BaseException:
            self._bus.shutdown()
            self.closed = True
            raise

    def recv(self, timeout: float | None = None) -> Sample | None:
        if self.closed or self.disconnected:
            return None
        deadline = None if timeout is None else time.perf_counter() + timeout
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
                self.disconnected = True
                self.close()
                return None
            if msg is None:
                if deadline is None:
                    continue
                return None
            if self._log is not None:
                self._log(msg)
            sample = assembler.feed_message(msg)
            if sample is not None:
                return sample
            if deadline is not None and time.perf_counter() >= deadline:
                return None

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._bus.shutdown()
        except (can.CanError, OSError, serial.SerialException, ValueError):
            pass
        if self._log is not None:
            self._log.close()


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
        if cfg:
            raise LinkError(f"serial link: unknown option {sorted(cfg)[0]!r}")
        return SerialLink(str(port), calibration=calibration, log=log)
    if kind == "can":
        interface = cfg.pop("interface", None)
        channel = cfg.pop("channel", None)
        if not interface:
            raise LinkError("CAN link: no interface given")
        bitrate = cfg.pop("bitrate", CAN_BITRATE)
        log = cfg.pop("log", None)
        cfg.pop("calibration", None)
        return CanLink(str(interface), channel, bitrate, log=log, **cfg)
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


def link_config_from_args(args: argparse.Namespace, **extra: Any) -> dict[str, Any]:
    """The link config from options added by :func:`add_link_arguments`."""
    return link_config(getattr(args, "serial", None), getattr(args, "can", None), **extra)
