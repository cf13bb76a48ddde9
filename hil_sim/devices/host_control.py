"""The firmware's command side (PROTOCOL.md, "Version 2"), shared by the serial DAQ and the
SLCAN adapter: which command is applied, the echoed ``cmd_seq``, status bits 4 and 5, and the
watchdog.

A command that arrives is applied at the next sample (a newer one arriving first supersedes
it: it is never echoed). A command whose ``cmd_seq`` is not newer than the last accepted one
is ignored, but like every valid command it feeds the watchdog; an invalid one (bad CRC,
length, version, or ``cmd_seq`` 0) is dropped and counted in ``cmd_errors``. When no valid
command arrived for ``watchdog_ms`` (counted in samples of the device clock) after host
control began, the watchdog fires: status bit5, bit4 cleared, envelope 0 and the actuator off
until the next applied command.

Command faults (:mod:`.faults`: dropped, corrupted, late) sit in front of it, the same for
both devices: :meth:`HostControl.arrive` takes a command as its wire carries it, decides its
fault from a random stream of its own (the samples' faults are unchanged by it), corrupts it
with the device's own corruption if so, decodes it, and hands it on now or, if late,
``cmd_delay_ms`` of the device clock later (:meth:`HostControl.step` delivers it).

This is the framing level only. The plant hook: :attr:`HostControl.envelope_cv`,
:attr:`HostControl.enabled`, :attr:`HostControl.burst_period_ms` and
:attr:`HostControl.applied` say what the firmware would drive now; applying them to the
simulated plant (from the next burst onset) is the bench's job: :class:`hil_sim.hil.HilStream`
(what ``rtlift bench serve`` streams). With a plain experiment stream the samples still carry
the experiment's drive and forces, with the commanded envelope in ``envelope_cv``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from firmware_io.commands import DEFAULT_WATCHDOG_MS, ENVELOPE_LIMIT_CV, WATCHDOG_STEP_MS, Command, is_newer
from firmware_io.samples import STATUS_HOST_CONTROL, STATUS_WATCHDOG
from hil_sim.devices.faults import DeviceStats, FaultPlan


class HostControl:
    """Commands in, per-sample ``(cmd_seq, status, envelope_cv)`` out; counts in ``stats``
    (``commands_valid``, ``commands_applied``, ``commands_superseded``, ``commands_ignored``,
    ``cmd_errors``, ``watchdog_trips``)."""

    def __init__(self, stats: DeviceStats, cmd_seq_modulus: int, fs_hz: float,
                 faults: FaultPlan | None = None, seed: int = 0) -> None:
        self.stats = stats
        self.faults = faults or FaultPlan()
        self._rng = np.random.default_rng((seed, 1))
        self._late: deque[tuple[int, Command | None]] = deque()
        self._delay_samples = max(1, int(round(self.faults.cmd_delay_ms * fs_hz / 1000.0)))
        self.modulus = cmd_seq_modulus
        self.fs_hz = fs_hz
        self.applied: Command | None = None
        """The last applied command (``None`` before any: the device streams version 1)."""
        self.envelope_cv = 0
        """The envelope the firmware drives now, 0.01 V: the applied command's, clamped to
        :data:`~firmware_io.commands.ENVELOPE_LIMIT_CV`; 0 when disabled or after the watchdog."""
        self.enabled = False
        """Whether the actuator is on under host control (flags bit0, and no watchdog)."""
        self.burst_period_ms: int | None = None
        """The commanded burst period (``None``: the experiment's own)."""
        self.watchdog_ms = DEFAULT_WATCHDOG_MS
        self.host_control = False
        self.watchdog = False
        self._pending: Command | None = None
        self._last_seq: int | None = None
        self._fed_at = 0

    @property
    def version(self) -> int:
        return 1 if self.applied is None else 2

    def arrive(self, wire: Any, index: int, decode: Callable[[Any], Command | None],
               corrupt: Callable[[Any, np.random.Generator], Any]) -> None:
        """A command as its wire carries it arrived before sample ``index``, through the
        command faults: dropped (never decoded), corrupted by ``corrupt`` (so ``decode`` fails:
        a ``cmd_errors``), late (held ``cmd_delay_ms``), or handed to :meth:`receive`."""
        st = self.stats
        f = self.faults
        fault = f.command_fault(index, float(self._rng.random())) if f.any_command else None
        if fault == "drop":
            st.commands_dropped += 1
            return
        if fault == "corrupt":
            wire = corrupt(wire, self._rng)
            st.commands_corrupted += 1
        command = decode(wire)
        if fault == "late":
            st.commands_delayed += 1
            self._late.append((index + self._delay_samples, command))
            return
        self.receive(command, index)

    def receive(self, command: Command | None, index: int) -> None:
        """A command arrived before sample ``index`` (``None``: an invalid one)."""
        st = self.stats
        if command is None:
            st.cmd_errors += 1
            return
        st.commands_valid += 1
        self._fed_at = index
        if not is_newer(command.cmd_seq % self.modulus, self._last_seq, self.modulus):
            st.commands_ignored += 1
            return
        if self._pending is not None:
            st.commands_superseded += 1
        self._pending = command
        self._last_seq = command.cmd_seq % self.modulus

    def step(self, index: int, status: int, envelope_cv: int) -> tuple[int | None, int, int]:
        """Sample ``index`` with the experiment's ``status`` and ``envelope_cv``: returns the
        ``cmd_seq`` to echo (``None``: stream version 1), the status with bits 4 and 5, and the
        envelope to report."""
        late = self._late
        while late and late[0][0] <= index:
            self.receive(late.popleft()[1], index)
        cmd = self._pending
        if cmd is not None:
            self._pending = None
            self.applied = cmd
            self.stats.commands_applied += 1
            if cmd.burst_period_ms:
                self.burst_period_ms = cmd.burst_period_ms
            if cmd.watchdog_ms_div10:
                self.watchdog_ms = cmd.watchdog_ms_div10 * WATCHDOG_STEP_MS
            self.enabled = cmd.enable
            self.envelope_cv = min(cmd.envelope_cv, ENVELOPE_LIMIT_CV) if cmd.enable else 0
            self.host_control = True
            self.watchdog = False
        if self.applied is None:
            return None, status, envelope_cv
        if self.host_control and (index - self._fed_at) * 1000.0 >= self.watchdog_ms * self.fs_hz:
            self.host_control = False
            self.watchdog = True
            self.enabled = False
            self.envelope_cv = 0
            self.stats.watchdog_trips += 1
        status &= ~(STATUS_HOST_CONTROL | STATUS_WATCHDOG) & 0xFF
        if self.host_control:
            status |= STATUS_HOST_CONTROL
        if self.watchdog:
            status |= STATUS_WATCHDOG
        return self.applied.cmd_seq % self.modulus, status, self.envelope_cv
