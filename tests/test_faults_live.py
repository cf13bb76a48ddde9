"""Fault matrix, live links over real pseudo-terminals: ``rtlift observe`` as a user runs it
(a subprocess; stderr as the user sees it) against the emulated serial DAQ and the SLCAN
adapter (python-can's real ``slcan`` driver), with the emulators' exact statistics as the
oracle: link faults mid-stream, a device that vanishes and comes back, a full disk.

Decision for a vanished device: without ``--reconnect``, ``rtlift observe`` ends with exit
status 1 and one line, the summary and the log complete up to the last byte read. With
``--reconnect`` it reopens the device with backoff and goes on (same log and summary); the gap
is counted from ``seq`` only when the host and device clocks agree with it, else reported as
not knowable with a host-clock estimate."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_io import read_log
from hil_sim.devices import FaultPlan, SerialDaq, SlcanAdapter, synthetic_stream
from rtlift.core.rate import FS_HZ
from tests.test_faults_support import counters, read_estimates, write_calibration, write_model

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
    n = 2 * int(FS_HZ)
    rate = 0.02 if kind == "serial" else 0.01  # per packet; per CAN frame (three per sample)
    plan = FaultPlan(corrupt=rate, drop=rate, duplicate=rate, garbage=rate, start=5, stop=n - 5)
    dev = make(synthetic_stream(7), faults=plan, seed=8, max_samples=n)
    log, summary, out = tmp_path / f"run{suffix}", tmp_path / "summary.json", tmp_path / "estimates.csv"
    with dev:
        code, err = observe(dev, link_args(dev.path), tmp_path, "--seconds", str(n / int(FS_HZ)), "--log", str(log),
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
    assert s["end"] == "disconnected" and s["lost"] == 0 and 0.75 * int(FS_HZ) <= s["received"] <= int(FS_HZ)
    assert len(list(logged)) == s["received"] and counters(logged.counters.as_dict()) == counters(s)

    back = SerialDaq(synthetic_stream(2), max_samples=int(FS_HZ), first_seq=40000)
    with back:
        port.unlink()
        port.symlink_to(back.path)
        code2, err2 = observe(back, ["--serial", str(port)], tmp_path, "--seconds", "0.5",
                              "--json", str(summary))
    s2 = json.loads(summary.read_text())
    # 0.5 s of device time exactly; frames in the same read as the last are received too (load)
    assert code2 == 0 and s2["samples_stepped"] + s2["samples_filled"] == int(FS_HZ) // 2, err2
    assert int(FS_HZ) // 2 <= s2["received"] <= int(FS_HZ) and s2["lost"] == 0, err2
    record_property("measured", f"gone after 1 s: exit {code}, '{err[-1]}'; log holds {s['received']} samples = "
                                f"summary; after replug: exit {code2}, received {s2['received']}, lost 0")


def test_a_slow_device_is_waited_for_and_a_silent_one_ends_the_run(tmp_path, record_property):
    """A device that streams at a fifth of its rate (its clock still says 400 Hz: the simulated
    bench on a loaded machine) is waited for until ``--seconds`` of its samples are in, though
    that takes twice the wall time a limit of ``--seconds`` + 5 s would allow. One that stops
    streaming but keeps its port open ends the run 5 s later: exit 1, one line, the summary
    holds what came."""
    n = 2 * int(FS_HZ)
    slow = SerialDaq(synthetic_stream(3), fs_hz=FS_HZ / 5, period_us=int(round(1e6 / FS_HZ)), max_samples=n)
    summary = tmp_path / "summary.json"
    with slow:
        code, err = observe(slow, ["--serial", slow.path], tmp_path, "--seconds", "2", "--json", str(summary),
                            timeout=60.0)
    s = json.loads(summary.read_text())
    assert code == 0 and s["end"] == "completed" and s["received"] == n and s["lost"] == 0, err
    assert s["host_seconds"] > 2 + 5.0, s["host_seconds"]

    stops = SerialDaq(synthetic_stream(4), max_samples=int(FS_HZ))
    with stops:
        code2, err2 = observe(stops, ["--serial", stops.path], tmp_path, "--seconds", "4", "--json", str(summary))
    s2 = json.loads(summary.read_text())
    assert code2 == 1 and not any("Traceback" in line for line in err2), err2
    assert err2[-1] == "rtlift observe: the device fell silent before --seconds were done"
    assert s2["end"] == "timeout" and s2["received"] == int(FS_HZ) and 1 + 5.0 < s2["host_seconds"] < 1 + 5.0 + 3.0
    record_property("measured", f"slow device: {s['received']} samples in {s['host_seconds']:.1f} s, completed; "
                                f"silent after 1 s: exit {code2} after {s2['host_seconds']:.1f} s, "
                                f"received {s2['received']}")


@pytest.mark.parametrize("kind", ["serial", "slcan"])
def test_full_disk_for_the_log(tmp_path, kind, record_property):
    """The log's disk is full (/dev/full): the run stops with exit 2 and one line saying so,
    no traceback; the summary accounts for every sample received, each with its estimate."""
    make, suffix, link_args = LINKS[kind]
    dev = make(synthetic_stream(3), max_samples=4 * int(FS_HZ))
    log, summary, out = tmp_path / f"run{suffix}", tmp_path / "summary.json", tmp_path / "estimates.csv"
    log.symlink_to("/dev/full")
    with dev:
        code, err = observe(dev, link_args(dev.path), tmp_path, "--seconds", "3", "--log", str(log),
                            "--json", str(summary), "--out", str(out))
    s = json.loads(summary.read_text())
    assert code == 2 and not any("Traceback" in line for line in err), err
    assert err[-1] == f"rtlift: error: {log}: cannot write log (No space left on device); the run stopped"
    # how many came before the log's first failed write depends on load (none when the host's first
    # read is larger than the file's buffer: seen on a loaded machine), so no count is asserted
    assert s["end"] == "error" and s["samples_stepped"] == s["received"]
    assert len(read_estimates(out)) == s["received"] + s["samples_filled"] == s["estimates"]
    record_property("measured", f"exit {code}: '{err[-1].replace(str(tmp_path) + '/', '')}'; summary: received "
                                f"{s['received']}, all stepped, {s['estimates']} estimate rows")


def outside_emulator_stream(seed: int = 16) -> tuple[list[bytes], dict[str, int]]:
    """The stream of issue 16's outside DAQ emulator: 3 200 frames (seq 0..3199), no leading
    0x00 (the first packet starts the stream), 20 corrupted, 15 never sent, 5 garbage chunks
    (each one delimited junk run), 10 duplicated; then the device is unplugged."""
    import numpy as np

    from hil_sim.devices.serial_daq import cobs_data_positions
    from tests.test_faults_support import serial_frame, wire

    rng = np.random.default_rng(seed)
    n = 3200
    ws = wire(n, seed=seed)
    picks = rng.choice(np.arange(1, n - 1), 20 + 15 + 10, replace=False)
    corrupt, drop, dup = set(picks[:20].tolist()), set(picks[20:35].tolist()), set(picks[35:].tolist())
    garbage = set(rng.choice(np.arange(1, n), 5, replace=False).tolist())
    out: list[bytes] = []
    for seq in range(n):
        if seq in garbage:
            out.append(bytes(rng.integers(1, 256, int(rng.integers(1, 33))).tolist()) + b"\x00")
        frame = serial_frame(seq, ws[seq])
        if seq in drop:
            continue
        if seq in corrupt:
            pos = int(rng.choice(cobs_data_positions(frame)))
            frame = frame[:pos] + bytes((frame[pos] % 255 + 1,)) + frame[pos + 1:]
        out.append(frame)
        if seq in dup:
            out.append(frame)
    return out, {"received": 3165, "crc_errors": 25, "lost": 35, "duplicates": 10}


def test_outside_emulator_counts_exactly_from_the_first_packet(tmp_path, record_property):
    """Issue 16: a DAQ emulator written outside the team streams into ``rtlift observe
    --serial`` over a pty without a leading delimiter; every valid sample counts, the first
    one included: received 3 165, crc_errors 25, lost 35, duplicates 10."""
    import threading
    import time
    import tty

    chunks, expect = outside_emulator_stream()
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    path = os.ttyname(slave)

    class Emulator:
        def start(self) -> None:
            threading.Thread(target=self.run, daemon=True).start()

        def run(self) -> None:
            t = time.perf_counter()
            for i, chunk in enumerate(chunks):
                os.write(master, chunk)
                if i % 4 == 3:  # 1 600 frames/s: 4x the DAQ rate, in 4-frame bursts
                    t += 4 / 1600
                    time.sleep(max(0.0, t - time.perf_counter()))
            time.sleep(0.3)
            os.close(master)  # unplugged
            os.close(slave)

    summary = tmp_path / "summary.json"
    code, err = observe(Emulator(), ["--serial", path], tmp_path, "--json", str(summary))
    s = json.loads(summary.read_text())
    assert code == 1 and s["end"] == "disconnected", err
    got = {k: s[k] for k in expect}
    assert got == expect
    record_property("measured", f"outside emulator, 3 200 frames then unplug: {got}")


def test_reconnect_after_a_two_second_unplug(tmp_path, record_property):
    """Issue 16: with ``--reconnect`` an unplug (the pty closed) and a replug 2 s later at the
    same by-id path (re-pointed to the new pty) do not end the run: ``reconnects`` 1, the gap
    counted from ``seq`` (the DAQ kept counting), predicted through and flagged, and the log
    holds every sample received before and after; the gap is accounted for exactly. The port is
    reopened as soon as the path names the new device (issue 26's goal, at most 50 samples missed
    after the return where it was 221 with the backoff alone, is reported, not asserted)."""
    import time

    from rtlift.app.live import FLAG_LINK_GAP

    port = tmp_path / "ttyDAQ"
    dev = SerialDaq(synthetic_stream(1), faults=FaultPlan(disconnect_after_s=1.0))
    model = write_model(tmp_path / "model.json")
    cal = write_calibration(tmp_path / "cal.toml")
    log, summary, out = tmp_path / "run.bin", tmp_path / "summary.json", tmp_path / "estimates.csv"
    total = 1400  # 400 samples, 2 s (800) unplugged, 200 after
    with dev:
        port.symlink_to(dev.path)
        cmd = [sys.executable, "-m", "rtlift", "observe", "--serial", str(port), "--model", str(model),
               "--calibration", str(cal), "--reconnect", "--seconds", str(total / int(FS_HZ)), "--log", str(log),
               "--json", str(summary), "--out", str(out)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONPATH": str(REPO)})
        try:
            assert "link open" in proc.stderr.readline()
            dev.start()
            assert dev.wait(10.0)
            gone = time.perf_counter()
            n1 = dev.stats.samples
            port.unlink()                   # udev removes the by-id link; the device is back 2 s later
            time.sleep(max(0.0, gone + 2.0 - time.perf_counter()))
            fs = int(FS_HZ)
            back = SerialDaq(synthetic_stream(2), max_samples=total - n1 - 2 * fs, first_seq=n1 + 2 * fs,
                             first_t_us=(n1 + 2 * fs) * 2500, unread_lost=True)
            with back:
                port.symlink_to(back.path)
                back.start()
                _, rest = proc.communicate(timeout=30)
        finally:
            proc.kill()
    err = [line for line in rest.splitlines() if line.strip()]
    s = json.loads(summary.read_text())
    rows = read_estimates(out)
    logged = read_log(log)
    seqs = [x.seq for x in logged]
    assert proc.returncode == 0 and s["end"] == "completed", err
    # the gap counted from seq is exact: the first DAQ's samples still in the pty when it was
    # unplugged (a loaded host reads behind; the kernel drops them with the pty), the 2 s away, and
    # what the replacement DAQ sampled before the host reopened the port (its clock runs whether or
    # not the port is open: unread_lost). How soon the port is reopened is a timing goal (issue 26:
    # <= 50 samples at 400 Hz; the backoff alone ~220), measured here and reported by
    # benchmarks/fault_matrix.py, not asserted on a shared machine.
    tail_lost = n1 - sum(1 for q in seqs if q < n1)
    missed_after_return = back.stats.samples_unread
    assert s["gap_lost"] == tail_lost + 2 * int(FS_HZ) + missed_after_return, (s, n1, tail_lost)
    assert s["reconnects"] == 1 and s["gaps_unknown"] == 0, s
    assert s["received"] + s["lost"] == total and s["crc_errors"] == 0 and s["duplicates"] == 0
    bridged = [r for r in rows if int(r["flags"]) & FLAG_LINK_GAP]
    assert len(bridged) == s["samples_bridged"] == s["gap_lost"] and len(rows) == total
    assert len(seqs) == s["received"] and seqs == [int(r["seq"]) for r in rows if r["t_us"]]
    assert seqs[0] == 0 and seqs[-1] == total - 1 and logged.counters.lost == s["lost"]
    record_property("measured", f"unplugged 2 s after 1 s: exit 0, reconnects {s['reconnects']}, gap_lost "
                                f"{s['gap_lost']} (from seq; {tail_lost} left in the pty at the unplug, "
                                f"{missed_after_return} after the return), "
                                f"received {s['received']} + lost {s['lost']} = {total}; "
                                f"{len(bridged)} rows predicted through the gap, flagged; log holds all "
                                f"{len(seqs)} samples")


def test_reconnect_to_a_new_path_on_can_when_the_gap_is_not_knowable(record_property):
    """The SLCAN adapter vanishes; another one (a restarted DAQ: ``seq`` and clock from 0)
    comes up at a new path given in the link config (``reconnect.also``). The link goes on
    through python-can's slcan driver: ``reconnects`` 1, and since ``seq`` cannot tell the gap
    (restarted), it is reported as not knowable with a host-clock estimate, not added to
    ``lost``."""
    import time

    from firmware_io import open_link

    dev = SlcanAdapter(synthetic_stream(1), faults=FaultPlan(disconnect_after_s=0.5))
    back = SlcanAdapter(synthetic_stream(2), max_samples=int(FS_HZ) // 2)
    gaps = []
    with dev, back:
        cfg = {"kind": "can", "interface": "slcan", "channel": dev.path,
               "reconnect": {"also": [back.path], "give_up_s": 5.0}}
        with open_link(cfg) as link:
            link.on_gap = lambda missed, known: gaps.append((missed, known))
            dev.start()
            back.start()
            got = []
            t_end = time.perf_counter() + 30.0
            for sample in link.samples(0.25):
                if sample is not None:
                    got.append(sample.seq)
                if back.finished.is_set() and sample is None or time.perf_counter() > t_end:
                    break
            c = link.counters
    n1 = dev.stats.samples
    assert c.reconnects == 1 and c.gaps_unknown == 1 and c.gap_lost == 0 and c.lost == 0
    assert len(got) == c.received == n1 + int(FS_HZ) // 2 and got[n1] == 0
    assert len(gaps) == 1 and not gaps[0][1] and gaps[0][0] == c.gap_lost_estimated < int(FS_HZ)
    record_property("measured", f"slcan adapter gone after {n1} samples, a restarted one at a new path: "
                                f"reconnects {c.reconnects}, received {c.received} (all sent), gap not "
                                f"knowable from seq, estimated {c.gap_lost_estimated} samples")
