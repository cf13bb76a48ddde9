"""Both sides of the wire over real pseudo-terminals: the emulated DAQ (serial) and SLCAN
adapter streaming the simulated bench at 400 Hz, read through pyserial and python-can's
real ``slcan`` driver. The emulators' exact statistics are the oracle of the link counters."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from firmware_io import open_link
from firmware_io.slcan import ChunkedSlcanBus
from hil_sim.devices import FaultPlan, SerialDaq, SlcanAdapter
from hil_sim.experiments import daq_stream
from rtlift.core.rate import FS_HZ

pytestmark = pytest.mark.pty

FS = int(FS_HZ)
REPO = Path(__file__).resolve().parents[1]

NO_GAPS = {k: 0 for k in ("reconnects", "gap_lost", "gaps_unknown", "gap_lost_estimated")}
"""The reconnect counters of a link that never lost its device."""
NO_COMMANDS = {"commands_sent": 0, "commands_applied": 0, "watchdog_trips": 0}
"""The command counters of a link that sent no command to a device that applied none."""


def serial_config(dev):
    return {"kind": "serial", "port": dev.path}


def can_config(dev):
    return {"kind": "can", "interface": "slcan", "channel": dev.path, "bitrate": 500000}


def read_all(link, n, silence_s=2.0):
    out = []
    for s in link.samples(silence_s):
        if s is None:
            break
        out.append(s)
        if len(out) == n:
            break
    return out


def read_paced(link, dev, n):
    """Start ``dev`` and read its ``n`` samples: (samples, seconds it took); every counter of
    ``link`` is exact (nothing lost, corrupted, repeated, no gap, no command)."""
    t0 = time.perf_counter()
    dev.start()
    got = read_all(link, n)
    elapsed = time.perf_counter() - t0
    assert link.counters.as_dict() == {"received": n, "crc_errors": 0, "lost": 0, "duplicates": 0,
                                       "events": 0, "resyncs": 0, **NO_GAPS, **NO_COMMANDS}
    return got, elapsed


def read_until_done(link, dev):
    """Everything the link delivers until the device has finished and gone quiet."""
    got = []
    while True:
        more = read_all(link, 10**9, silence_s=0.5)
        got += more
        if not more and dev.finished.is_set():
            return got


def serial_fields(s):
    return (s.seq, s.t_us, s.volt_cv, s.envelope_cv, s.ft, s.status, s.cmd_seq)


def serial_sent(entry):
    seq, t_us, volt_cv, envelope_cv, counts, status, cmd_seq = entry
    return (seq, t_us, volt_cv, envelope_cv, tuple(c / 1e6 for c in counts[:3]) + tuple(c / 1e9 for c in counts[3:]),
            status, cmd_seq)


def can_fields(s):
    return (s.seq, s.t_us, s.volt_cv, s.envelope_cv, tuple(round(f * 1e3 if i < 3 else f * 1e5)
                                                          for i, f in enumerate(s.ft)), s.status, s.cmd_seq)


def can_sent(entry):
    seq, t_10us, volt_cv, envelope_cv, raw, status, cmd_seq = entry
    return (seq, t_10us * 10, volt_cv, envelope_cv, raw, status, cmd_seq)


def test_serial_ten_seconds_at_400_hz_arrive_complete_and_equal_to_what_was_sent():
    n = 10 * FS
    dev = SerialDaq(daq_stream("train_T1p75", seed=3), max_samples=n, keep_sent=True, first_seq=65536 - 1500)
    with dev, open_link(serial_config(dev)) as link:
        got, elapsed = read_paced(link, dev, n)
    assert dev.error is None
    assert [serial_fields(s) for s in got] == [serial_sent(e) for e in dev.sent]
    assert got[-1].seq == (65536 - 1500 + n - 1) % 65536  # crossed the u16 wrap
    assert elapsed > n / FS - 0.1  # paced at 400 Hz, not as fast as possible (how close: benchmarks/pacing.py)


def test_slcan_ten_seconds_at_400_hz_arrive_complete_through_python_can_slcan():
    n = 10 * FS
    dev = SlcanAdapter(daq_stream("sine_k025", seed=4), max_samples=n, keep_sent=True)
    with dev:
        with open_link(can_config(dev)) as link:
            got, elapsed = read_paced(link, dev, n)
        t_closed = time.perf_counter() + 2.0
        while dev.commands[-1] != "C" and time.perf_counter() < t_closed:
            time.sleep(0.01)
        assert dev.commands[:4] == ["C", "S6", "", "O"] and dev.commands[-1] == "C"  # the driver's open/close
    assert dev.error is None
    assert [can_fields(s) for s in got] == [can_sent(e) for e in dev.sent]
    assert elapsed > n / FS - 0.1


def test_serial_counters_equal_the_faults_injected():
    n = 4 * FS
    plan = FaultPlan(corrupt=0.03, drop=0.03, duplicate=0.03, garbage=0.03, stop=n - 5)
    dev = SerialDaq(daq_stream("random", seed=5), faults=plan, seed=11, max_samples=n, keep_sent=True)
    dev.send_event("overtemp")
    with dev, open_link(serial_config(dev)) as link:
        dev.start()
        got = read_until_done(link, dev)
        st = dev.stats
        assert min(st.frames_corrupted, st.frames_dropped, st.frames_duplicated, st.garbage_chunks) > 0
        assert link.counters.as_dict() == {
            "received": st.samples_delivered, "lost": st.samples_lost,
            "crc_errors": st.frames_corrupted + st.garbage_chunks, "duplicates": st.frames_duplicated,
            "events": 1, "resyncs": st.invalid_runs, **NO_GAPS, **NO_COMMANDS}
        assert link.events == ["overtemp"]
    assert [serial_fields(s) for s in got] == [serial_sent(e) for e in dev.sent]


@pytest.mark.parametrize("chunked", [True, False], ids=["chunked_read", "python_can_read"])
def test_slcan_counters_equal_the_faults_injected(chunked):
    """The same exact accounting through firmware_io's chunked reader (the default) and through
    python-can's own byte-at-a-time one."""
    n = 4 * FS
    plan = FaultPlan(corrupt=0.01, drop=0.01, duplicate=0.01, garbage=0.01, stop=n - 5)
    dev = SlcanAdapter(daq_stream("random", seed=6), faults=plan, seed=12, max_samples=n, keep_sent=True)
    with dev, open_link({**can_config(dev), "slcan_chunked_read": chunked}) as link:
        assert isinstance(link._bus, ChunkedSlcanBus) is chunked
        dev.start()
        got = read_until_done(link, dev)
        st = dev.stats
        assert min(st.frames_corrupted, st.frames_dropped, st.frames_duplicated, st.garbage_bursts) > 0
        assert link.counters.as_dict() == {
            "received": st.samples_delivered, "lost": st.samples_lost, "crc_errors": st.frames_corrupted,
            "duplicates": st.frames_duplicated, "events": 0, "resyncs": 0, **NO_GAPS, **NO_COMMANDS}
    assert [can_fields(s) for s in got] == [can_sent(e) for e in dev.sent]


@pytest.mark.parametrize("make,config", [(SerialDaq, serial_config), (SlcanAdapter, can_config)],
                         ids=["serial", "slcan"])
def test_a_device_that_disappears_ends_iteration_cleanly(make, config):
    dev = make(daq_stream("static", seed=1), faults=FaultPlan(disconnect_after_s=0.5), keep_sent=True)
    with dev, open_link(config(dev)) as link:
        dev.start()
        got = list(link)  # ends by itself, no exception
        assert link.disconnected and link.closed and link.recv(0.1) is None
    assert dev.stats.disconnected and dev.stats.samples_delivered == 200
    # what was still in flight when the pty vanished is gone, as on a real unplug
    assert 150 <= len(got) <= 200 and [s.seq for s in got] == [e[0] for e in dev.sent[:len(got)]]


def test_a_silent_device_is_noticed_by_the_timed_iteration():
    dev = SerialDaq(daq_stream("static", seed=2), max_samples=40)
    with dev, open_link(serial_config(dev)) as link:
        dev.start()
        seen = []
        for s in link.samples(0.2):
            seen.append(s)
            if s is None:
                break
        assert len(seen) == 41 and seen[-1] is None and not link.disconnected


def serve(*args):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "rtlift", "bench", "serve", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


@pytest.mark.parametrize("how,config", [("--serial", lambda p: {"kind": "serial", "port": p}),
                                        ("--slcan", lambda p: {"kind": "can", "interface": "slcan", "channel": p})],
                         ids=["serial", "slcan"])
def test_bench_serve_prints_the_pty_path_streams_and_stops_on_sigterm(how, config):
    proc = serve(how, "--experiment", "static", "--fault", "drop:rate=0.05", "--seed", "7")
    try:
        path = proc.stdout.readline().strip()
        with open_link(config(path)) as link:
            got = read_all(link, 200)
            counters = link.counters.as_dict()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert len(got) == 200 and counters["lost"] > 0 and counters["crc_errors"] == 0
    assert "stopped: samples=" in err and "Traceback" not in err


def test_bench_serve_rejects_a_bad_fault_spec_in_one_line():
    proc = serve("--serial", "--fault", "meteor:rate=1")
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 2 and err.count("\n") == 1 and "unknown fault 'meteor'" in err
