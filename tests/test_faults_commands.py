"""Command faults (protocol version 2) over a real pseudo-terminal: the serial DAQ (pyserial)
and the SLCAN adapter (python-can's slcan driver) drop, corrupt or delay the host's commands by
rate, count each exactly, and the host sees them as what they are — a dropped or corrupted
command is never echoed (``commands_applied`` stays exact), a corrupted one is in the serial
device's ``cmd_errors`` event, a late one is applied late. The device's statistics are the oracle."""

from __future__ import annotations

import time

import pytest

from firmware_io import open_link
from hil_sim.devices import SerialDaq, SlcanAdapter
from hil_sim.devices.faults import FaultPlan, FaultSpecError, parse_faults
from hil_sim.experiments import daq_stream
from rtlift.core.rate import FS_HZ

pytestmark = pytest.mark.pty   # the device tests below run over real pseudo-terminals

FS = int(FS_HZ)
WATCHDOG_DIV10 = 200
"""2 s: no command fault here should trip the watchdog."""


def test_command_fault_specs_parse():
    plan = parse_faults(["cmd_drop:rate=0.1", "cmd_corrupt:rate=0.05", "cmd_late:rate=0.2,delay_ms=30"])
    assert (plan.cmd_drop, plan.cmd_corrupt, plan.cmd_late, plan.cmd_delay_ms) == (0.1, 0.05, 0.2, 30.0)
    assert plan.any_command and not plan.any
    assert parse_faults(["cmd_late:rate=0.1"]).cmd_delay_ms == 50.0


@pytest.mark.parametrize("spec", ["cmd_drop:rate=2", "cmd_late:rate=0.1,delay_ms=0", "cmd_drop:after_s=1",
                                  "cmd_drop:rate=0.6", "cmd_lost:rate=0.1"])
def test_a_bad_command_fault_spec_is_one_line(spec):
    with pytest.raises(FaultSpecError) as exc:
        parse_faults([spec, "cmd_corrupt:rate=0.5"] if spec == "cmd_drop:rate=0.6" else [spec])
    assert "\n" not in str(exc.value)


def _samples(link, n):
    out = []
    end = time.perf_counter() + n / FS + 3.0
    while len(out) < n and time.perf_counter() < end:
        s = link.recv(0.1)
        if s is not None:
            out.append(s)
    assert len(out) == n
    return out


DEVICES = pytest.mark.parametrize("device", [SerialDaq, SlcanAdapter], ids=["serial", "slcan"])


def _run(device, plan: FaultPlan, commands: int, every: int):
    """Send ``commands`` commands, one every ``every`` samples, then read until the device's
    ``cmd_errors`` event has come (once a second) and every late command has landed. The sends are
    also paced by the clock (at least ``every`` sample periods apart): a host that fell behind
    reads ``every`` buffered samples at once, and two commands sent back to back can reach the
    device within one sample, the first then superseded — on a loaded machine, not a fault."""
    dev = device(daq_stream("static", seed=1), faults=plan, seed=3)
    echoed = set()
    config = ({"kind": "serial", "port": dev.path} if device is SerialDaq else
              {"kind": "can", "interface": "slcan", "channel": dev.path})
    with dev, open_link(config) as link:
        dev.start()
        _samples(link, 20)
        sent = -1.0
        for k in range(commands):
            time.sleep(max(0.0, sent + every / FS - time.perf_counter()))
            sent = time.perf_counter()
            link.send_command(1000 + 10 * k, watchdog_ms_div10=WATCHDOG_DIV10)
            echoed.update(s.cmd_seq for s in _samples(link, every))
        echoed.update(s.cmd_seq for s in _samples(link, FS + 40))
        counters = link.counters.as_dict()
        latency = link.counters.command_latency_ms()
        events = list(link.events)
    echoed.discard(0)
    echoed.discard(None)
    return dev.stats, counters, latency, events, echoed


def _exact(st, c, echoed):
    """Every command the host sent is accounted for; only applied ones were echoed (a valid
    command can still be superseded when two reach the device before one sample)."""
    assert c["lost"] == 0 and c["crc_errors"] == 0
    assert c["commands_sent"] == st.commands_dropped + st.cmd_errors + st.commands_valid
    assert c["commands_applied"] == st.commands_applied == len(echoed)
    assert st.commands_applied == st.commands_valid - st.commands_superseded - st.commands_ignored
    assert st.watchdog_trips == 0 and c["watchdog_trips"] == 0


@DEVICES
def test_dropped_commands_are_counted_and_never_echoed(device):
    st, c, _, _, echoed = _run(device, FaultPlan(cmd_drop=0.25), 80, 3)
    assert 8 <= st.commands_dropped <= 35 and st.commands_corrupted == st.commands_delayed == 0
    assert st.cmd_errors == 0
    _exact(st, c, echoed)
    assert c["commands_applied"] == 80 - st.commands_dropped - st.commands_superseded - st.commands_ignored


@DEVICES
def test_corrupted_commands_are_cmd_errors_and_never_echoed(device):
    st, c, _, events, echoed = _run(device, FaultPlan(cmd_corrupt=0.25), 80, 3)
    assert 8 <= st.commands_corrupted <= 35 and st.commands_dropped == st.commands_delayed == 0
    assert st.cmd_errors == st.commands_corrupted
    _exact(st, c, echoed)
    assert c["commands_applied"] == 80 - st.commands_corrupted - st.commands_superseded - st.commands_ignored
    if device is SerialDaq:                         # CAN has no event frame to report it
        assert f"cmd_errors={st.cmd_errors}" in events


@DEVICES
def test_late_commands_are_applied_late(device):
    """Commands 40 samples (100 ms) apart, the late ones 50 ms late: each is still applied, and
    the host's send → echo latency shows the delay."""
    st, c, latency, _, echoed = _run(device, FaultPlan(cmd_late=0.3, cmd_delay_ms=50.0), 30, 40)
    assert 3 <= st.commands_delayed <= 20 and st.commands_dropped == st.commands_corrupted == 0
    _exact(st, c, echoed)
    assert c["commands_applied"] == 30 and st.commands_superseded == st.commands_ignored == 0
    assert latency["command_latency_p99_ms"] >= 45.0
