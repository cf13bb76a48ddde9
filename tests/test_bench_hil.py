"""The bench as a real-time HIL plant: under host control the simulated plant follows the
commanded envelope from the next burst onset; before the first command the stream is the
experiment's, sample for sample; the watchdog takes the actuator to 0."""

from __future__ import annotations

import itertools
import time
from types import SimpleNamespace

import numpy as np
import pytest

from firmware_io import open_link
from firmware_io.calibration import Calibration
from firmware_io.commands import ENVELOPE_LIMIT_CV
from firmware_io.samples import STATUS_WATCHDOG
from hil_sim.devices import SerialDaq
from hil_sim.experiments import daq_stream
from hil_sim.hil import HilStream
from rtlift.core.rate import FS_HZ

FS = int(FS_HZ)


def _control(**kw):
    return SimpleNamespace(**{"applied": None, "envelope_cv": 0, "enabled": False,
                              "burst_period_ms": None, **kw})


def test_without_commands_the_stream_is_the_experiments_sample_for_sample():
    stream = HilStream("random", seed=3)
    stream.control = _control()
    got = np.concatenate([p.counts for p in itertools.islice(iter(stream), 24)])
    want = np.concatenate([c.counts for c in itertools.islice(daq_stream("random", seed=3), 3)])
    assert np.array_equal(got, want[:len(got)]) and len(got) == 1200


def test_the_switch_to_host_control_keeps_the_plant_state_exact():
    """At the first onset under control the bench state is the experiment's at that sample:
    an envelope equal to the experiment's would continue the truth seamlessly (same order)."""
    ctl = _control()
    stream = HilStream("static", seed=1)
    stream.control = ctl
    it = iter(stream)
    pieces = [next(it) for _ in range(11)]  # 550 samples: not a chunk boundary
    ctl.applied, ctl.enabled, ctl.envelope_cv = 1, True, 0
    after = next(it)
    assert stream.host_since == 550 and after.t[0] * FS == pytest.approx(550)
    assert abs(after.dcl_true[0] - pieces[-1].dcl_true[-1]) < 0.01


def test_more_envelope_gives_more_lift_and_the_limit_is_the_actuators():
    ctl = _control(applied=1, enabled=True)
    stream = HilStream("random", seed=2)
    stream.control = ctl
    it = iter(stream)
    means = []
    for env in (3000, 9000, 15000, ENVELOPE_LIMIT_CV, ENVELOPE_LIMIT_CV):
        ctl.envelope_cv = env
        means.append(np.concatenate([next(it).dcl_true for _ in range(40)])[-200:].mean())
    assert means[0] < means[1] < means[2] < means[3]
    assert stream.envelope_cv_applied == ENVELOPE_LIMIT_CV and means[3] > 0.15


def _measured_dcl(samples, cal):
    return np.asarray(cal.cl_from_ft(np.array([s.ft for s in samples])), dtype=float)


WATCHDOG_S = 0.3
"""The watchdog :func:`_hold`'s commands set (``watchdog_ms_div10=30``)."""


def _hold(link, envelope_cv, seconds, stalls=None):
    """Send ``envelope_cv`` every burst period (8 Hz) for ``seconds``; the samples received.
    ``stalls`` (a list) gets the host-clock length of every wait of ≥ :data:`WATCHDOG_S` between
    two samples: on a loaded VM the pseudo-terminal carries nothing either way for 0.4–5 s
    (docs/results/control.md, "Host command timing under load"), and the commands sent meanwhile
    reach the device late, so its watchdog may trip once per such stall."""
    out = []
    end = time.perf_counter() + seconds
    next_cmd = 0.0
    last = time.perf_counter()
    while time.perf_counter() < end:
        if time.perf_counter() >= next_cmd:
            link.send_command(envelope_cv, watchdog_ms_div10=30)
            next_cmd = time.perf_counter() + 0.125
        s = link.recv(0.05)
        if s is not None:
            now = time.perf_counter()
            if stalls is not None and now - last >= WATCHDOG_S:
                stalls.append(now - last)
            last = now
            out.append(s)
    return out


@pytest.mark.pty
def test_commands_over_a_pty_move_the_measured_lift_and_the_watchdog_takes_it_to_zero():
    cal = Calibration()
    stream = HilStream("static", seed=4)
    dev = SerialDaq(stream)
    stream.control = dev.control
    with dev, open_link({"kind": "serial", "port": dev.path}) as link:
        dev.start()
        stalls = []
        low = _hold(link, 2000, 2.5, stalls)
        high = _hold(link, 15000, 2.5, stalls)
        quiet = []
        end = time.perf_counter() + 2.5
        while time.perf_counter() < end:  # no more commands: the 300 ms watchdog fires
            s = link.recv(0.05)
            if s is not None:
                quiet.append(s)
        counters = link.counters.as_dict()
    dcl_low = _measured_dcl(low[-400:], cal).mean()
    dcl_high = _measured_dcl(high[-400:], cal).mean()
    dcl_quiet = _measured_dcl(quiet[-300:], cal).mean()
    assert dcl_high - dcl_low > 0.08
    assert dcl_quiet < dcl_low
    assert quiet[-1].status & STATUS_WATCHDOG and quiet[-1].envelope_cv == 0
    assert all(s.volt_cv == 0 for s in quiet[-300:])
    # one trip when the commands stop; one more at most per stall of the wire while they were sent
    assert 1 <= dev.stats.watchdog_trips <= 1 + len(stalls), (dev.stats.watchdog_trips, stalls)
    assert counters["watchdog_trips"] == dev.stats.watchdog_trips
    assert counters["lost"] == 0 and dev.error is None
    _, truth = stream.truth_array()
    assert truth[-200:].max() < 0.02
