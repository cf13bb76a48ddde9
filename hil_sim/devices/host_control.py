"""The firmware's command side (PROTOCOL.md, "Version 2"), shared by the serial DAQ and the
SLCAN adapter: which command is applied, the echoed ``cmd_seq``, status bits 4 and 5, and the
watchdog.

A command that arrives is applied at the next sample (a newer one arriving first supersedes
it: it is never echoed). A command whose ``cmd_seq`` is not newer than the last accepted one
is ignored, but like every valid command it feeds the watchdog; an invalid one (bad CRC,
length, version, or ``cmd_seq`` 0) is dropped and counted in ``cmd_errors``. When no valid
command arrived for ``watchdog_ms`` (counted in samples of the device clock) after host
control began, the watchdog fires: status bit5 from that sample on, bit4 cleared, and the
envelope ramps down (:data:`WATCHDOG_RAMP_MS`): from its value ``E`` at the firing sample ``f``
it is ``E * (R - j) // R`` at sample ``f + j`` (``R`` = the ramp in samples, integer
arithmetic), so exactly 0 at ``f + R``. The actuator stays enabled until then and is off
afterwards, until the next applied command; a command applied during the ramp ends it and
takes over at once like any command. A valid command that is not newer (ignored) feeds the
watchdog but does not end the ramp or the watchdog state (PROTOCOL.md: a command not newer
than the last applied one is ignored, after a trip too; a new host continues the numbering from
the ``cmd_seq`` the samples echo, :class:`firmware_io.commands.CommandTracker`).

Sessions. A device that sees a host open its port (:meth:`HostControl.new_session`:
``rtlift bench serve``'s serial DAQ on a hang-up of its pty, the SLCAN adapter on ``O``/``L``)
also goes back to its power-on state: nothing applied (it streams version 1 until the next
command, echoing no old ``cmd_seq``), actuator off at once, the default watchdog, the
experiment's burst period, no ``cmd_seq`` history, nothing pending or late.

Why 100 ms: long enough that the amplifier sees 40 steps at 400 Hz instead of one cut, short
against the default watchdog (500 ms), so the actuator is off at most ``watchdog_ms`` + 100 ms
after the last valid command. It is shorter than the default burst period (125 ms, 8 Hz) on
purpose: the plant latches the envelope at burst onsets (:class:`hil_sim.hil.HilStream`), so at
the default period it gets at most one reduced burst, then none — the safe state comes at most
one burst later than an instant cut. The ramp spares the actuator's drive a step; it is not
meant to shape the lift, which falls over the flow's relaxation time (τ_s ≈ 0.25 s) either way:
shaping it would take a ramp of several τ_s, the actuator on for a second or more after the
host is gone, which a safe state should not be.

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

WATCHDOG_RAMP_MS = 100
"""Time from the watchdog firing to envelope 0, counted in samples of the device clock."""


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
        :data:`~firmware_io.commands.ENVELOPE_LIMIT_CV`; 0 when disabled; on the way down during
        the watchdog's ramp, 0 after it."""
        self.enabled = False
        """Whether the actuator is on under host control (flags bit0, and the watchdog's ramp
        not yet at 0)."""
        self.burst_period_ms: int | None = None
        """The commanded burst period (``None``: the experiment's own)."""
        self.watchdog_ms = DEFAULT_WATCHDOG_MS
        self.host_control = False
        self.watchdog = False
        self._pending: Command | None = None
        self._last_seq: int | None = None
        self._fed_at = 0
        self.ramp_samples = max(1, int(round(WATCHDOG_RAMP_MS * fs_hz / 1000.0)))
        """The watchdog's ramp in samples (40 at 400 Hz)."""
        self._ramp: tuple[int, int] | None = None
        """(firing sample, envelope then) while the watchdog's ramp runs."""
        self.accepts_commands = True
        """``False``: a protocol-version-1 firmware, which reads no commands (``rtlift bench
        serve --protocol 1``): whatever the host writes is ignored, nothing is echoed."""

    def new_session(self) -> None:
        """A host opened the port: the command side's power-on state (module docstring,
        "Sessions"); the counts in ``stats`` go on."""
        self.applied = None
        self.envelope_cv = 0
        self.enabled = False
        self.burst_period_ms = None
        self.watchdog_ms = DEFAULT_WATCHDOG_MS
        self.host_control = False
        self.watchdog = False
        if self._pending is not None:                      # the last host's, not applied: replaced
            self.stats.commands_superseded += 1
        self._pending = None
        self.stats.commands_dropped += len(self._late)     # the last host's, still in transit: never arrive
        self._late.clear()
        self._last_seq = None
        self._ramp = None

    @property
    def pending(self) -> Command | None:
        """The newest valid command received and not yet applied (it is, at the next sample)."""
        return self._pending

    @property
    def version(self) -> int:
        return 1 if self.applied is None else 2

    def arrive(self, wire: Any, index: int, decode: Callable[[Any], Command | None],
               corrupt: Callable[[Any, np.random.Generator], Any]) -> None:
        """A command as its wire carries it arrived before sample ``index``, through the
        command faults: dropped (never decoded), corrupted by ``corrupt`` (so ``decode`` fails:
        a ``cmd_errors``), late (held ``cmd_delay_ms``), or handed to :meth:`receive`."""
        if not self.accepts_commands:
            return
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
            self._ramp = None
        if self.applied is None:
            return None, status, envelope_cv
        if self.host_control and (index - self._fed_at) * 1000.0 >= self.watchdog_ms * self.fs_hz:
            self.host_control = False
            self.watchdog = True
            self.stats.watchdog_trips += 1
            self._ramp = (index, self.envelope_cv if self.enabled else 0)
        if self._ramp is not None:
            self._ramp_down(index)
        status &= ~(STATUS_HOST_CONTROL | STATUS_WATCHDOG) & 0xFF
        if self.host_control:
            status |= STATUS_HOST_CONTROL
        if self.watchdog:
            status |= STATUS_WATCHDOG
        return self.applied.cmd_seq % self.modulus, status, self.envelope_cv

    def _ramp_down(self, index: int) -> None:
        """The watchdog's ramp at sample ``index``: linear from its start to 0, then off."""
        start, env0 = self._ramp
        left = self.ramp_samples - (index - start)
        if left <= 0 or env0 == 0:
            self._ramp = None
            self.envelope_cv = 0
            self.enabled = False
        else:
            self.envelope_cv = env0 * left // self.ramp_samples
