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

import math
from typing import Any

from firmware_io.calibration import Calibration
from firmware_io.can_link import CanLink
from firmware_io.errors import LinkError
from firmware_io.link_base import CAN_BITRATE, Link, Reconnect
from firmware_io.serial_link import SerialLink
from rtlift.core.rate import FS_HZ

__all__ = ["CanLink", "Link", "Reconnect", "SerialLink", "link_config", "open_link", "parse_can_spec", "spin_window_s"]


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
