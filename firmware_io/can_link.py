"""The CAN wire (the DBC's frames through python-can): :class:`CanLink`."""

from __future__ import annotations

import time
from typing import Any

import can
import serial

from firmware_io.can_codec import CMD_ID, CanAssembler, encode_command_frame
from firmware_io.can_codec import SEQ_MODULUS as CAN_SEQ_MODULUS
from firmware_io.commands import CAN_CMD_SEQ_MODULUS, CommandTracker
from firmware_io.errors import LinkError
from firmware_io.link_base import CAN_BITRATE, CAN_SAMPLE_WIRE_BYTES, Link, Reconnect, one_line
from firmware_io.samples import Sample
from firmware_io.slcan import ChunkedSlcanBus


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
            raise LinkError(f"{where}: interface not available ({one_line(exc)})") from None
        except (can.CanError, OSError, ValueError, TypeError, ImportError, serial.SerialException) as exc:
            raise LinkError(f"{where}: cannot open ({one_line(exc)})") from None
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
            now = time.perf_counter()
            remaining = None if deadline is None else max(0.0, deadline - now)
            self._waiting(now)
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
            self._heard(time.perf_counter())
            if self._log is not None:
                self._log(msg)
            sample = assembler.feed_message(msg)
            if sample is not None:
                return self._delivered(sample)
            if deadline is not None and time.perf_counter() >= deadline:
                return None
