"""What a link delivers: one :class:`Sample` per firmware sample, and the link's
:class:`Counters` with PROTOCOL.md's meanings."""

from __future__ import annotations

from dataclasses import asdict, dataclass

STATUS_ACTUATOR_ENABLED = 0x01
STATUS_ADC_SATURATED = 0x02
STATUS_SENSOR_FAULT = 0x04
STATUS_BURST_ON = 0x08
STATUS_FLAGGED = STATUS_ADC_SATURATED | STATUS_SENSOR_FAULT
"""Status bits that make a sample's forces unusable (ΔCL is reported as missing)."""


@dataclass(slots=True)
class Sample:
    """One firmware sample as received.

    ``seq`` wraps at 65 536 (serial) or 256 (CAN); ``t_us`` is the device clock in µs (it
    wraps: 2³² µs on serial, 655 360 µs on CAN where it is sent in 10 µs steps);
    ``volt_cv``/``envelope_cv`` are the drive amplitude and the burst envelope in 0.01 V;
    ``ft`` holds fx fy fz (N) and tx ty tz (N·m) already scaled by the link (no calibration
    matrix); ``status`` has PROTOCOL.md's bits; ``host_time`` is ``time.perf_counter()`` at
    receipt.
    """

    seq: int
    t_us: int
    volt_cv: int
    envelope_cv: int
    ft: tuple[float, float, float, float, float, float]
    status: int
    host_time: float


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
      estimate, not included in ``lost``.
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

    def as_dict(self) -> dict[str, int]:
        return asdict(self)
