"""What a link delivers: one :class:`Sample` per firmware sample, and the link's
:class:`Counters` with PROTOCOL.md's meanings."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from firmware_io.latency import LatencyRecorder

STATUS_ACTUATOR_ENABLED = 0x01
STATUS_ADC_SATURATED = 0x02
STATUS_SENSOR_FAULT = 0x04
STATUS_BURST_ON = 0x08
STATUS_HOST_CONTROL = 0x10
"""Version 2: a command has been applied and the watchdog has not fired."""
STATUS_WATCHDOG = 0x20
"""Version 2: host control ended, no valid command for ``watchdog_ms``; the actuator is ramped
to 0, then off."""
STATUS_FLAGGED = STATUS_ADC_SATURATED | STATUS_SENSOR_FAULT
"""Status bits that make a sample's forces unusable (ΔCL is reported as missing)."""
COMMAND_KEYS = ("commands_sent", "commands_applied", "watchdog_trips")
"""The keys of :meth:`Counters.as_dict` about commands (protocol version 2)."""


@dataclass(slots=True)
class Sample:
    """One firmware sample as received.

    ``seq`` wraps at 65 536 (serial) or 256 (CAN); ``t_us`` is the device clock in µs (it
    wraps: 2³² µs on serial, 655 360 µs on CAN where it is sent in 10 µs steps);
    ``volt_cv``/``envelope_cv`` are the drive amplitude and the burst envelope in 0.01 V;
    ``ft`` holds fx fy fz (N) and tx ty tz (N·m) already scaled by the link (no calibration
    matrix); ``status`` has PROTOCOL.md's bits; ``host_time`` is ``time.perf_counter()`` at
    receipt; ``cmd_seq`` is the ``cmd_seq`` of the last command the device applied
    (protocol version 2; 0 before any command and in every version-1 sample; a u8 on CAN).
    """

    seq: int
    t_us: int
    volt_cv: int
    envelope_cv: int
    ft: tuple[float, float, float, float, float, float]
    status: int
    host_time: float
    cmd_seq: int = 0


@dataclass(slots=True)
class Counters:
    """Exact link counters (PROTOCOL.md).

    - ``received``: valid samples delivered;
    - ``crc_errors``: packets dropped as invalid (serial: anything between two 0x00
      delimiters that is not a valid packet; CAN: frames of our identifiers with a wrong
      length, error frames, lines the adapter driver cannot parse);
    - ``lost``: samples missing from the ``seq`` sequence between valid samples;
    - ``duplicates``: repeated ``seq`` dropped (serial: packets; CAN: frames);
    - ``events``: firmware event packets;
    - ``resyncs``: times the decoder lost frame sync and dropped bytes to the next
      delimiter (one per run of invalid packets, and one for a partial packet or sample at
      start-up or after a reconnect);
    - ``reconnects``: times a link opened with ``reconnect`` got its device back;
    - ``gap_lost``: samples lost while the device was gone, known from ``seq`` (and the device
      clock): included in ``lost``;
    - ``gaps_unknown``: reconnect gaps whose loss ``seq`` cannot tell (the device restarted, or
      the gap is longer than ``seq`` wraps); ``gap_lost_estimated`` holds their host-clock
      estimate, not included in ``lost``;
    - ``commands_sent``: commands the link wrote (``link.send_command``);
    - ``commands_applied``: distinct ``cmd_seq`` values echoed by samples (a change of the
      echoed non-zero ``cmd_seq``);
    - ``watchdog_trips``: samples with status bit5 (watchdog) after a sample without it;
    - ``command_latency``: send → first echo of each command (s), a fixed-size
      :class:`~firmware_io.latency.LatencyRecorder`; not a counter, so not in ``as_dict``
      (which stays all exact integers): :meth:`command_latency_ms` gives its p50 and p99.
    """

    received: int = 0
    crc_errors: int = 0
    lost: int = 0
    duplicates: int = 0
    events: int = 0
    resyncs: int = 0
    reconnects: int = 0
    gap_lost: int = 0
    gaps_unknown: int = 0
    gap_lost_estimated: int = 0
    commands_sent: int = 0
    commands_applied: int = 0
    watchdog_trips: int = 0
    command_latency: LatencyRecorder = field(default_factory=LatencyRecorder, repr=False, compare=False)

    def as_dict(self) -> dict[str, int]:
        """The exact counters (every field but ``command_latency``)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "command_latency"}

    def command_latency_ms(self) -> dict[str, float | None]:
        """``command_latency_p50_ms`` and ``command_latency_p99_ms`` (``None`` before the first
        echo), as SUMMARY.json of ``rtlift control`` names them."""
        return {"command_latency_p50_ms": self.command_latency.percentile_ms(50),
                "command_latency_p99_ms": self.command_latency.percentile_ms(99)}


class EchoCounter:
    """Counts ``commands_applied`` and ``watchdog_trips`` from delivered samples (shared by
    the serial decoder and the CAN assembler). It outlives a stream restart: a device that
    comes back echoing the same ``cmd_seq`` has applied nothing new."""

    __slots__ = ("counters", "last_cmd_seq", "watchdog")

    def __init__(self, counters: Counters) -> None:
        self.counters = counters
        self.last_cmd_seq = 0
        self.watchdog: bool | None = None

    def see(self, cmd_seq: int, status: int) -> None:
        if cmd_seq and cmd_seq != self.last_cmd_seq:
            self.last_cmd_seq = cmd_seq
            self.counters.commands_applied += 1
        watchdog = bool(status & STATUS_WATCHDOG)
        if watchdog and self.watchdog is False:
            self.counters.watchdog_trips += 1
        self.watchdog = watchdog
