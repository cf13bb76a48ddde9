"""Commands host → device (PROTOCOL.md, "Version 2"): the :class:`Command` value object, the
``cmd_seq`` arithmetic both ends share, and :class:`CommandTracker`, what a link counts about
the commands it sends (``commands_sent`` and the send → first-echo latency).

``cmd_seq`` runs 1, 2, …, modulus − 1, 1, … (never 0, which a sample echoes before any
command): modulus 65 536 on serial, 256 on CAN where it travels as a u8.
"""

from __future__ import annotations

from dataclasses import dataclass

from firmware_io.samples import Counters, Sample

SERIAL_CMD_SEQ_MODULUS = 1 << 16
CAN_CMD_SEQ_MODULUS = 256
ENVELOPE_LIMIT_CV = 20_000
"""The firmware clamps the commanded envelope to 200 V (Cμ 0.022 needs about 190 V)."""
DEFAULT_WATCHDOG_MS = 500
WATCHDOG_STEP_MS = 10
"""``watchdog_ms_div10`` is in units of 10 ms."""
PENDING_SLOTS = 256
"""Send times kept for the latency of commands not yet echoed (indexed by ``cmd_seq`` mod 256)."""


def _check(name: str, value: object, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f"command {name} must be an integer in {lo}..{hi}, got {value!r}")
    return value


@dataclass(frozen=True, slots=True)
class Command:
    """One command as the protocol carries it: ``envelope_cv`` the burst envelope in 0.01 V
    (0 = bursts off; the firmware clamps it to :data:`ENVELOPE_LIMIT_CV`), ``burst_period_ms``
    (0 = keep the current one), ``enable`` (flags bit0: off means the actuator is off now,
    whatever the envelope), ``watchdog_ms_div10`` (10 ms units, 0 = keep the current one).
    Out-of-range values raise ``ValueError`` (one line naming the field)."""

    cmd_seq: int
    envelope_cv: int
    burst_period_ms: int = 0
    enable: bool = True
    watchdog_ms_div10: int = 0

    def __post_init__(self) -> None:
        _check("cmd_seq", self.cmd_seq, 1, SERIAL_CMD_SEQ_MODULUS - 1)
        _check("envelope_cv", self.envelope_cv, 0, 0xFFFF)
        _check("burst_period_ms", self.burst_period_ms, 0, 0xFFFF)
        _check("watchdog_ms_div10", self.watchdog_ms_div10, 0, 0xFF)
        if not isinstance(self.enable, bool):
            raise ValueError(f"command enable must be true or false, got {self.enable!r}")

    @property
    def flags(self) -> int:
        return 1 if self.enable else 0


def check_can_cmd_seq(cmd_seq: int) -> int:
    """On CAN ``cmd_seq`` is a u8 and never 0."""
    return _check("cmd_seq", cmd_seq, 1, CAN_CMD_SEQ_MODULUS - 1)


def next_cmd_seq(cmd_seq: int, modulus: int) -> int:
    """The ``cmd_seq`` after ``cmd_seq`` (0: none yet): wraps from modulus − 1 to 1, never 0."""
    return cmd_seq % (modulus - 1) + 1


def is_newer(cmd_seq: int, last: int | None, modulus: int) -> bool:
    """Whether ``cmd_seq`` is newer than the last applied one (``None``: none applied yet):
    ahead of it by 1 … modulus/2 − 1 (PROTOCOL.md: "modulo 65 536, within 32 768")."""
    return last is None or 0 < (cmd_seq - last) % modulus < modulus // 2


class CommandTracker:
    """The host's side of commands on one link: hands out ``cmd_seq`` values, counts
    ``commands_sent`` and records the latency from a command's send to the first sample that
    echoes it (``counters.command_latency``). ``commands_applied`` and ``watchdog_trips`` are
    counted by the decoders, from the samples alone, so a replayed log gives them too.

    Send times live in :data:`PENDING_SLOTS` fixed slots, so memory does not grow; a command
    superseded before it was applied is never echoed and simply has no latency."""

    def __init__(self, counters: Counters, modulus: int) -> None:
        self.counters = counters
        self.modulus = modulus
        self.last_sent = 0
        self._sent_seq = [0] * PENDING_SLOTS
        self._sent_at = [0.0] * PENDING_SLOTS

    def next_seq(self) -> int:
        return next_cmd_seq(self.last_sent, self.modulus)

    def sent(self, cmd_seq: int, host_time: float) -> None:
        """``cmd_seq`` went out at ``host_time`` (``time.perf_counter()``)."""
        self.last_sent = cmd_seq
        self.counters.commands_sent += 1
        slot = cmd_seq % PENDING_SLOTS
        self._sent_seq[slot] = cmd_seq
        self._sent_at[slot] = host_time

    def received(self, sample: Sample) -> None:
        """A delivered sample: the first one echoing a pending command closes its latency.

        Before this host has sent anything, a sample echoing a ``cmd_seq`` is a previous host's
        last command (the device remembers it across sessions): the numbering continues after it,
        so this host's first command is newer and the device applies it (PROTOCOL.md: a command
        not newer than the last applied one is ignored)."""
        cmd_seq = sample.cmd_seq
        if cmd_seq and self.counters.commands_sent == 0:
            self.last_sent = cmd_seq
        if cmd_seq:
            slot = cmd_seq % PENDING_SLOTS
            if self._sent_seq[slot] == cmd_seq:
                self._sent_seq[slot] = 0
                self.counters.command_latency.append(sample.host_time - self._sent_at[slot])
