"""The watchdog's ramp (PROTOCOL.md "Version 2": "the actuator was ramped to 0"), with known
answers: the firmware's command side (``HostControl``) stepped sample by sample at 400 Hz, and
the HIL plant that latches the envelope at burst onsets. No pty: the device's own order (the
stream is read for sample k, then ``step(k)``) is reproduced in the loop."""

from __future__ import annotations

import itertools

import pytest

from firmware_io.commands import ENVELOPE_LIMIT_CV, SERIAL_CMD_SEQ_MODULUS, Command
from firmware_io.samples import STATUS_HOST_CONTROL, STATUS_WATCHDOG
from hil_sim.devices.faults import DeviceStats
from hil_sim.devices.host_control import WATCHDOG_RAMP_MS, HostControl
from hil_sim.devices.source import serial_wire, wire_samples
from hil_sim.hil import HilStream
from rtlift.core.rate import FS_HZ

FS = int(FS_HZ)
HC, WD = STATUS_HOST_CONTROL, STATUS_WATCHDOG


def _control() -> HostControl:
    return HostControl(DeviceStats(), SERIAL_CMD_SEQ_MODULUS, FS)


def _run(ctl: HostControl, n: int, commands: dict[int, Command]) -> list[tuple[int, int, int, bool]]:
    """``(cmd_seq, status, envelope_cv, enabled)`` for samples 0..n-1; ``commands[k]`` arrives
    before sample k."""
    out = []
    for k in range(n):
        if k in commands:
            ctl.receive(commands[k], k)
        seq, status, env = ctl.step(k, 0, 0)
        out.append((seq, status, env, ctl.enabled))
    return out


def test_the_ramp_is_100_ms_of_the_device_clock():
    assert WATCHDOG_RAMP_MS == 100 and _control().ramp_samples == 40


def test_bit5_from_the_firing_sample_then_a_linear_ramp_to_exactly_zero():
    """Applied at sample 10 with a 50 ms (20-sample) watchdog: it fires at sample 30; the
    envelope falls 200 cV per sample from 8000 to 0 at sample 70; off from then on."""
    ctl = _control()
    got = _run(ctl, 120, {10: Command(1, 8000, watchdog_ms_div10=5)})
    status = [s for _, s, _, _ in got]
    env = [e for _, _, e, _ in got]
    enabled = [on for *_, on in got]
    assert all(seq is None for seq, *_ in got[:10]) and all(seq == 1 for seq, *_ in got[10:])
    assert status[10:30] == [HC] * 20 and status[30:] == [WD] * 90
    assert env[10:31] == [8000] * 21
    assert env[30:71] == [8000 - 200 * j for j in range(41)]
    assert env[70:] == [0] * 50
    assert enabled[10:70] == [True] * 60 and enabled[70:] == [False] * 50
    assert ctl.stats.watchdog_trips == 1


def test_the_ramp_rounds_down_and_starts_from_the_clamped_envelope():
    ctl = _control()
    got = _run(ctl, 80, {0: Command(1, 999, watchdog_ms_div10=1)})  # 10 ms: fires at sample 4
    env = [e for _, _, e, _ in got]
    assert env[4:7] == [999, 974, 949] and env[42:45] == [49, 24, 0]
    limited = _run(_control(), 80, {0: Command(1, 30000, watchdog_ms_div10=1)})
    assert [e for _, _, e, _ in limited][3:6] == [ENVELOPE_LIMIT_CV, ENVELOPE_LIMIT_CV, 19500]


def test_disabled_or_zero_at_firing_is_off_at_once():
    for cmd in (Command(1, 8000, enable=False, watchdog_ms_div10=1), Command(1, 0, watchdog_ms_div10=1)):
        got = _run(_control(), 10, {0: cmd})
        assert [(s, e, on) for _, s, e, on in got[4:]] == [(WD, 0, False)] * 6


def test_a_command_during_the_ramp_ends_it_and_applies_at_once():
    """Fired at 30; at 44 the ramp is at 5200; at 45 a new command takes control: its envelope, bit4, and a
    fresh watchdog that fires again 20 samples later, at 65, ramping from the new value."""
    ctl = _control()
    got = _run(ctl, 120, {10: Command(1, 8000, watchdog_ms_div10=5), 45: Command(2, 3000)})
    assert got[44] == (1, WD, 5200, True)
    assert got[45:65] == [(2, HC, 3000, True)] * 20
    assert [e for _, _, e, _ in got[65:106]] == [3000 * (40 - j) // 40 for j in range(41)]
    assert got[105:] == [(2, WD, 0, False)] * 15
    assert ctl.stats.watchdog_trips == 2 and ctl.stats.commands_applied == 2


def test_a_command_after_the_ramp_takes_control_again():
    got = _run(_control(), 110, {10: Command(1, 8000, watchdog_ms_div10=5), 100: Command(2, 4000)})
    assert got[99] == (1, WD, 0, False) and got[100:] == [(2, HC, 4000, True)] * 10


def test_an_ignored_command_feeds_the_watchdog_while_host_control_lasts():
    """cmd_seq 5 applied at 10 (20-sample watchdog); a second 5 at 25 is not newer: ignored, not
    applied, but it feeds the watchdog, which fires at 45 instead of 30."""
    ctl = _control()
    got = _run(ctl, 80, {10: Command(5, 8000, watchdog_ms_div10=5), 25: Command(5, 1000)})
    assert ctl.stats.commands_ignored == 1 and ctl.stats.commands_applied == 1
    assert got[44] == (5, HC, 8000, True) and got[45] == (5, WD, 8000, True)
    assert [e for _, _, e, _ in got[45:80]] == [8000 - 200 * j for j in range(35)]


def test_an_ignored_command_does_not_end_the_ramp():
    """PROTOCOL.md: a command not newer than the last applied one is ignored, after a trip too
    (a new host continues the numbering from the echoed cmd_seq instead)."""
    ctl = _control()
    got = _run(ctl, 80, {10: Command(5, 8000, watchdog_ms_div10=5), 40: Command(5, 1000)})
    assert ctl.stats.commands_ignored == 1
    assert [e for _, _, e, _ in got[30:71]] == [8000 - 200 * j for j in range(41)]
    assert all(s == WD for _, s, _, _ in got[30:])


def test_a_new_session_is_the_power_on_state():
    """A host opens the port mid-control (the last one gone without a trip yet): nothing applied
    (version 1, no echo), actuator off at once, default watchdog and burst period; the new
    host's cmd_seq 1 is then applied though 52 came before."""
    ctl = _control()
    _run(ctl, 20, {10: Command(52, 8000, burst_period_ms=200, watchdog_ms_div10=90)})
    ctl.new_session()
    assert (ctl.applied, ctl.version, ctl.envelope_cv, ctl.enabled, ctl.burst_period_ms) == (None, 1, 0, False, None)
    assert ctl.watchdog_ms == 500 and ctl.step(20, 0, 0) == (None, 0, 0)
    ctl.receive(Command(1, 3000), 21)
    assert ctl.step(21, 0, 0) == (1, HC, 3000) and ctl.stats.commands_ignored == 0


def test_the_plant_gets_the_ramp_at_its_burst_onsets():
    """Applied at sample 100 (200 ms watchdog, fires at 180): the plant is host-driven from the
    onset at 150. The period from 200 is computed when sample 200 is read, before step(200): it
    gets the envelope after step(199), 19 samples into the ramp, 8000·21/40 = 4200 cV; from
    the onset at 250 on (59 samples in) it is off. An instant cut would give 0 from 200."""
    stream = HilStream("static", seed=1)
    ctl = stream.control = _control()
    for k, (_, env, status, _) in enumerate(itertools.islice(wire_samples(stream, serial_wire), 400)):
        if k == 100:
            ctl.receive(Command(1, 8000, watchdog_ms_div10=20), k)
        ctl.step(k, status, env)
    assert stream.host_since == 150
    idx, volts = stream.envelope_array()
    per_period = [sorted(set(volts[(idx >= k0) & (idx < k0 + 50)].round(9))) for k0 in range(150, 400, 50)]
    assert per_period == [[pytest.approx(80.0)], [pytest.approx(42.0)], [0.0], [0.0], [0.0]]
