"""Fault matrix, live links over real pseudo-terminals: ``rtlift observe`` as a user runs it
(a subprocess; stderr as the user sees it) against the emulated serial DAQ and the SLCAN
adapter (python-can's real ``slcan`` driver), with the emulators' exact statistics as the
oracle: link faults mid-stream, a device that vanishes and comes back, a full disk.

Decision for a vanished device: ``rtlift observe`` does not reconnect by itself. It ends
with exit status 1 and one line, the summary and the log complete up to the last byte read;
rerun it (by hand or under a supervisor) when the device is back. A reconnect inside the
run would bridge a gap of unknown length with one observer state and one tare, and the
replugged firmware restarts its ``seq``, so the counters could no longer add up."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_io import read_log
from hil_sim.devices import FaultPlan, SerialDaq, SlcanAdapter, synthetic_stream
from tests.test_faults_support import FS, counters, read_estimates, write_calibration, write_model

pytestmark = pytest.mark.pty

REPO = Path(__file__).resolve().parents[1]
LINKS = {
    "serial": (SerialDaq, ".bin", lambda path: ["--serial", path]),
    "slcan": (SlcanAdapter, ".asc", lambda path: ["--can", f"slcan:{path}"]),
}


def observe(dev, link_args: list[str], tmp_path: Path, *args: str, timeout: float = 30.0) -> tuple[int, list[str]]:
    """``rtlift observe`` in a subprocess; the device starts streaming once the link is open
    (opening a serial port flushes its input). Returns exit status and stderr lines."""
    model = write_model(tmp_path / "model.json")
    cal = write_calibration(tmp_path / "cal.toml")
    cmd = [sys.executable, "-m", "rtlift", "observe", *link_args, "--model", str(model), "--calibration", str(cal),
           *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        first = proc.stderr.readline()
        if "link open" in first:
            dev.start()
        _, rest = proc.communicate(timeout=timeout)
    finally:
        proc.kill()
    return proc.returncode, [line for line in (first + rest).splitlines() if line.strip()]


@pytest.mark.parametrize("kind", ["serial", "slcan"])
def test_live_link_faults(tmp_path, kind, record_property):
    """Corrupted, dropped, duplicated frames and garbage on a live link at 400 Hz: the run
    completes, the counters equal what the device injected, one estimate per sample sent,
    and the log replays to the same counters."""
    make, suffix, link_args = LINKS[kind]
    n = 2 * FS
    rate = 0.02 if kind == "serial" else 0.01  # per packet; per CAN frame (three per sample)
    plan = FaultPlan(corrupt=rate, drop=rate, duplicate=rate, garbage=rate, start=5, stop=n - 5)
    dev = make(synthetic_stream(7), faults=plan, seed=8, max_samples=n)
    log, summary, out = tmp_path / f"run{suffix}", tmp_path / "summary.json", tmp_path / "estimates.csv"
    with dev:
        code, err = observe(dev, link_args(dev.path), tmp_path, "--seconds", str(n / FS), "--log", str(log),
                            "--json", str(summary), "--out", str(out))
    st = dev.stats
    s = json.loads(summary.read_text())
    assert code == 0 and not any("Traceback" in line or "error" in line for line in err), err
    assert min(st.frames_corrupted, st.frames_dropped, st.frames_duplicated, st.garbage_bursts) > 0
    invalid = st.frames_corrupted + (st.garbage_chunks if kind == "serial" else 0)
    assert counters(s) == {"received": st.samples_delivered, "lost": st.samples_lost, "crc_errors": invalid,
                           "duplicates": st.frames_duplicated, "resyncs": st.invalid_runs}
    assert s["received"] + s["lost"] == n and s["end"] == "completed"
    assert len(read_estimates(out)) == n
    replayed = read_log(log)
    assert len(list(replayed)) == s["received"] and counters(replayed.counters.as_dict()) == counters(s)
    record_property("measured", f"{n} sent: received {s['received']} + lost {s['lost']} = {n}; crc_errors "
                                f"{s['crc_errors']}, duplicates {s['duplicates']} as injected; {n} estimate rows; "
                                "log replays to the same counters")


def test_device_disappears_mid_run_and_reappears(tmp_path, record_property):
    """The device vanishes after 1 s (a USB unplug): exit 1 with one line, no traceback, the
    summary and the log hold every sample received. Plugged back (the same by-id path), a
    new run streams normally."""
    port = tmp_path / "ttyDAQ"  # like /dev/serial/by-id/..., repointed when the device comes back
    dev = SerialDaq(synthetic_stream(1), faults=FaultPlan(disconnect_after_s=1.0))
    log, summary = tmp_path / "run.bin", tmp_path / "summary.json"
    with dev:
        port.symlink_to(dev.path)
        code, err = observe(dev, ["--serial", str(port)], tmp_path, "--log", str(log), "--json", str(summary))
    s = json.loads(summary.read_text())
    logged = read_log(log)
    assert code == 1 and not any("Traceback" in line for line in err), err
    assert err[-1] == f"rtlift observe: the device disappeared after {s['received']} samples; summary written"
    assert s["end"] == "disconnected" and s["lost"] == 0 and 0.75 * FS <= s["received"] <= FS
    assert len(list(logged)) == s["received"] and counters(logged.counters.as_dict()) == counters(s)

    back = SerialDaq(synthetic_stream(2), max_samples=FS, first_seq=40000)
    with back:
        port.unlink()
        port.symlink_to(back.path)
        code2, err2 = observe(back, ["--serial", str(port)], tmp_path, "--seconds", "0.5",
                              "--json", str(summary))
    s2 = json.loads(summary.read_text())
    assert code2 == 0 and s2["received"] == FS // 2 and s2["lost"] == 0, err2
    record_property("measured", f"gone after 1 s: exit {code}, '{err[-1]}'; log holds {s['received']} samples = "
                                f"summary; after replug: exit {code2}, received {s2['received']}, lost 0")


@pytest.mark.parametrize("kind", ["serial", "slcan"])
def test_full_disk_for_the_log(tmp_path, kind, record_property):
    """The log's disk is full (/dev/full): the run stops with exit 2 and one line saying so,
    no traceback; the summary accounts for every sample received, each with its estimate."""
    make, suffix, link_args = LINKS[kind]
    dev = make(synthetic_stream(3), max_samples=4 * FS)
    log, summary, out = tmp_path / f"run{suffix}", tmp_path / "summary.json", tmp_path / "estimates.csv"
    log.symlink_to("/dev/full")
    with dev:
        code, err = observe(dev, link_args(dev.path), tmp_path, "--seconds", "3", "--log", str(log),
                            "--json", str(summary), "--out", str(out))
    s = json.loads(summary.read_text())
    assert code == 2 and not any("Traceback" in line for line in err), err
    assert err[-1] == f"rtlift: error: {log}: cannot write log (No space left on device); the run stopped"
    assert s["end"] == "error" and s["received"] > 0 and s["samples_stepped"] == s["received"]
    assert len(read_estimates(out)) == s["received"] + s["samples_filled"] == s["estimates"]
    record_property("measured", f"exit {code}: '{err[-1].replace(str(tmp_path) + '/', '')}'; summary: received "
                                f"{s['received']}, all stepped, {s['estimates']} estimate rows")
