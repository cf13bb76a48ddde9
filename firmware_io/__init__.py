"""Frames in and out of the DAQ firmware (PROTOCOL.md): serial (COBS + CRC) and CAN (DBC)
links, conversion of samples to Cμ and ΔCL, and logs for replay.

    from firmware_io import open_link, Converter
    with open_link({"kind": "serial", "port": "/dev/ttyACM0"}) as link:
        convert = Converter(calibration)
        for sample in link:
            cmu, env, dcl = convert(sample)      # dcl is None when flagged or while taring
    link.counters                                # received crc_errors lost duplicates events resyncs
    link.send_command(envelope_cv=6000)          # protocol version 2: returns the cmd_seq sent
"""

from __future__ import annotations

from firmware_io.calibration import Calibration, CalibrationError
from firmware_io.commands import Command
from firmware_io.convert import Converter, capture, record_from_samples
from firmware_io.errors import FirmwareIOError, LinkError, LogError
from firmware_io.links import (
    CanLink,
    Link,
    SerialLink,
    link_config,
    open_link,
    parse_can_spec,
)
from firmware_io.logs import RecordWriter, graceful_exit, read_log
from firmware_io.samples import Counters, Sample

__all__ = [
    "Calibration", "CalibrationError", "CanLink", "Command", "Converter", "Counters", "FirmwareIOError", "Link",
    "LinkError", "LogError", "RecordWriter", "Sample", "SerialLink", "capture",
    "graceful_exit", "link_config", "open_link", "parse_can_spec", "read_log",
    "record_from_samples",
]
