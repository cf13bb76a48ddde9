"""Device emulators on pseudo-terminals, driven by the simulated bench: the DAQ's serial
side (:class:`SerialDaq`) and a USB–CAN adapter speaking SLCAN (:class:`SlcanAdapter`)
that python-can's real ``slcan`` driver talks to. Faults are injected from a seeded
:class:`FaultPlan` and counted exactly in ``device.stats``."""

from __future__ import annotations

from hil_sim.devices.faults import DeviceStats, FaultPlan, FaultSpecError, parse_fault, parse_faults
from hil_sim.devices.pty_device import PtyDevice
from hil_sim.devices.serial_daq import SerialDaq
from hil_sim.devices.slcan_adapter import SlcanAdapter
from hil_sim.devices.source import synthetic_stream

__all__ = ["DeviceStats", "FaultPlan", "FaultSpecError", "PtyDevice", "SerialDaq", "SlcanAdapter",
           "parse_fault", "parse_faults", "synthetic_stream"]
