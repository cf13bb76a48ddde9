"""The link's silences (firmware_io.link_base.Link): the longest wait for the wire, and the
stalls that held the commands back for the device's watchdog — the rule on given host times, and
the watchdog a command sets."""

from __future__ import annotations

import pytest

from firmware_io.commands import CommandTracker
from firmware_io.link_base import Link
from firmware_io.samples import Counters


class _Wire(Link):
    """A link whose wire is a list (nothing opened)."""

    kind = "test"
    seq_modulus = 1 << 16
    t_us_modulus = 1 << 32

    def __init__(self) -> None:
        self.counters = Counters()
        self._commands = CommandTracker(self.counters, 1 << 8)
        self.wrote: list = []

    def _open_device(self, where):
        return None

    def _close_device(self):
        return None

    def _restart_stream(self):
        return None

    def _encode_command(self, cmd_seq, envelope_cv, burst_period_ms, enable, watchdog_ms_div10):
        return (cmd_seq, envelope_cv, watchdog_ms_div10)

    def _write_command(self, wire):
        self.wrote.append(wire)
        return True

    def recv(self, timeout=None):
        return None


def test_a_silence_that_held_the_commands_for_the_watchdog_is_a_stall_and_the_host_share_is_not():
    link = _Wire()
    link._last_sent = 10.0
    link._waiting(10.05)
    link._waiting(10.30)                # a later look at the same silence: it began at 10.05
    link._heard(10.60)                  # 600 ms since the command, 550 of them silence
    assert link.stalls == 1 and link.silence_max_s == pytest.approx(0.55, abs=1e-12)
    link._last_sent = 20.0
    link._waiting(20.30)                # the host kept 300 ms of it itself: not the wire's
    link._heard(20.55)
    assert link.stalls == 1 and link.silence_max_s == pytest.approx(0.55, abs=1e-12)
    link._last_sent = 30.0
    link._waiting(30.01)
    link._heard(30.49)                  # 490 ms: under the 500 ms watchdog
    assert link.stalls == 1
    link._heard(31.5)                   # bytes with no wait before them: no silence
    assert link.stalls == 1 and link.silence_max_s == pytest.approx(0.55, abs=1e-12)


def test_the_watchdog_a_command_sets_is_the_one_stalls_are_judged_by():
    link = _Wire()
    assert link.watchdog_ms == 500
    link.send_command(10, watchdog_ms_div10=100)          # 1 s, as rtlift record sets it
    assert link.watchdog_ms == 1000 and link.wrote == [(1, 10, 100)]
    sent = link._last_sent
    link._waiting(sent + 0.01)
    link._heard(sent + 0.8)                               # 800 ms: a stall at 500, not at 1000
    assert link.stalls == 0 and link.silence_max_s == pytest.approx(0.79, abs=1e-9)
    link.send_command(10)                                 # 0: keeps the watchdog in force
    assert link.watchdog_ms == 1000
    link._waiting(link._last_sent)
    link._heard(link._last_sent + 1.2)
    assert link.stalls == 1
