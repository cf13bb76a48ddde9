"""python-can's ``slcan`` driver, reading the port in chunks instead of one byte per call.

python-can's :class:`can.interfaces.slcan.slcanBus` (4.x) reads its serial port one byte per
``read(1)`` call. A sample of this DAQ is three CAN frames, about 70 SLCAN bytes: 70 system
calls and Python round trips per sample, 8x the host CPU of the serial link (measured by
``benchmarks/command_latency.py``), so on a busy machine the host falls behind and the command
latency grows. :class:`ChunkedSlcanBus` is that same driver (opening, bit rate, ``O``/``C``,
every frame's parsing and sending stay python-can's) with one method replaced: ``_read`` takes
everything waiting on the port at once and hands out one SLCAN line (up to its ``\\r`` or
``\\a``) per call, as the original does, keeping the rest in the driver's own buffer.

If a python-can release changes the driver's internals this relies on (``serialPortOrig``,
``_buffer``, ``_OK``, ``_ERROR``), the stock ``_read`` is used. A link config with
``"slcan_chunked_read": false`` uses python-can's driver unchanged.
"""

from __future__ import annotations

import time

from can.exceptions import error_check
from can.interfaces.slcan import slcanBus

_NEEDS = ("serialPortOrig", "_buffer", "_OK", "_ERROR")


class ChunkedSlcanBus(slcanBus):
    """:class:`can.interfaces.slcan.slcanBus` with a chunked ``_read`` (module docstring)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._chunked = all(hasattr(self, name) for name in _NEEDS) and isinstance(self._buffer, bytearray)
        if self._chunked:
            self._terminators = (self._OK[0], self._ERROR[0])

    def pending_bytes(self) -> int:
        """Bytes received (in the driver's buffer and the port's) that no ``recv`` returned yet."""
        if not self._chunked:
            return 0
        try:
            return len(self._buffer) + self.serialPortOrig.in_waiting
        except (OSError, ValueError, AttributeError):
            return len(self._buffer)

    def _line(self) -> str | None:
        """The first complete line in the buffer, removed from it (None if there is none)."""
        buf = self._buffer
        ends = [i for i in (buf.find(t) for t in self._terminators) if i >= 0]
        if not ends:
            return None
        end = min(ends) + 1
        line = bytes(buf[:end]).decode()
        del buf[:end]
        return line

    def _read(self, timeout: float | None) -> str | None:
        if not self._chunked:
            return super()._read(timeout)
        line = self._line()
        if line is not None:
            return line
        port = self.serialPortOrig
        deadline = None if timeout is None else time.perf_counter() + timeout
        with error_check("Could not read from serial device"):
            while True:
                data = port.read(max(1, port.in_waiting))   # blocks up to the port's own timeout
                if data:
                    self._buffer.extend(data)
                    line = self._line()
                    if line is not None:
                        return line
                if deadline is not None and time.perf_counter() >= deadline:
                    return None
