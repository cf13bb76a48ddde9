"""Where a host command comes late under load: ``rtlift control`` end to end over a pty (the
fixture of tests/test_control_e2e.py: serial DAQ, bench model, fade to 75 %, feedback on)
beside CPU load like CI's (``--load`` busy processes at niceness 19, optionally ``--disk``
writers), ``--runs`` times.

Per run it reports the device's watchdog trips and the longest gap between two commands
  * sent by the host (``link.send_command``, host perf_counter, the host's own process),
  * received by the device (its ``HostControl.receive``: wall time and device samples; the
    watchdog counts samples: 200 at the default 500 ms),
the device thread's longest pause between two emitted samples and its longest catch-up burst
(samples emitted less than 0.5 ms apart), and, for every host gap > ``STALL_S``, what the
host's main thread was doing (``sys._current_frames()`` sampled every 10 ms by a thread of the
host) and the GC pauses seen. Both clocks are CLOCK_MONOTONIC, so host and device times compare.

    python -m benchmarks.command_timing --runs 3 --load 3
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import select
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import tty
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import emit  # noqa: E402

MODEL = ROOT / "tests" / "data" / "bench_model.json"
FADE = "actuator_fade:final_fraction=0.75,time_constant_s=0.4"
REFERENCE = "steps:0.08@0,0.14@5"
STALL_S = 0.2
"""A host gap this long (of the 125 ms command period) is a stall worth a stack."""
BURST_S = 0.0005


def probe(out: str, argv: list[str]) -> int:
    """Run ``rtlift ARGV`` in this process with the host-side probes (module docstring)."""
    from firmware_io.link_base import Link
    from rtlift.app.cli import main

    sends: list[tuple[float, int]] = []
    stacks: list[dict] = []
    gcs: list[tuple[float, float]] = []
    gc_start = [0.0]
    original = Link.send_command

    def send_command(self, *a, **k):
        r = original(self, *a, **k)
        sends.append((time.perf_counter(), self.delivered))
        return r

    Link.send_command = send_command
    reads: list[tuple[float, float]] = []
    delivered_ = Link._delivered

    def _delivered(self, sample):
        reads.append((time.perf_counter(), time.process_time()))
        return delivered_(self, sample)

    Link._delivered = _delivered

    def on_gc(phase, info):
        if phase == "start":
            gc_start[0] = time.perf_counter()
        else:
            gcs.append((gc_start[0], time.perf_counter() - gc_start[0]))

    gc.callbacks.append(on_gc)
    main_id = threading.main_thread().ident
    done = threading.Event()

    def sampler():
        seen = None
        while not done.wait(0.01):
            if not sends:
                continue
            last = sends[-1][0]
            now = time.perf_counter()
            if now - last > STALL_S and seen != last:
                seen = last
                frame = sys._current_frames().get(main_id)
                stacks.append({"t": now, "since_send_s": now - last,
                               "stack": traceback.format_stack(frame)[-6:] if frame else []})

    threading.Thread(target=sampler, daemon=True).start()
    try:
        return main(argv)
    finally:
        done.set()
        Path(out).write_text(json.dumps({"sends": sends, "stacks": stacks, "gcs": gcs,
                                               "reads": reads}))


LOADS = {"numpy": "import numpy as np\nwhile True:\n    np.linalg.eigvals(np.random.rand(200, 200))",
         "alloc": "while True:\n    bytearray(1 << 22)", "spin": "while True:\n    pass"}


def _load(n: int, disk: int, tmp: str, kind: str = "numpy", idle: bool = False) -> list[subprocess.Popen]:
    spin = LOADS[kind]
    low = ["chrt", "-i", "0"] if idle else ["nice", "-n", "19"]
    procs = [subprocess.Popen([*low, sys.executable, "-c", spin]) for _ in range(n)]
    write = ("import os,sys\nb=os.urandom(1<<20)\nwhile True:\n"
             " f=open(sys.argv[1],'wb')\n for _ in range(64): f.write(b)\n f.flush(); os.fsync(f.fileno()); f.close()")
    procs += [subprocess.Popen(["nice", "-n", "19", sys.executable, "-c", write, os.path.join(tmp, f"disk{i}")])
              for i in range(disk)]
    return procs


def one_run(tmp: str, seconds: float, k: int) -> dict:
    """One closed-loop run with device-side probes; the numbers of the module docstring."""
    from hil_sim.devices import SerialDaq
    from hil_sim.hil import HilStream

    stream = HilStream("random", seed=5, effects=[FADE])
    dev = SerialDaq(stream)
    stream.control = dev.control
    received: list[tuple[float, int]] = []
    emitted: list[float] = []
    receive, emit_ = dev.control.receive, dev._emit

    def on_receive(command, index):
        received.append((time.perf_counter(), index))
        receive(command, index)

    def on_emit(index, sample):
        emitted.append(time.perf_counter())
        emit_(index, sample)

    dev.control.receive, dev._emit = on_receive, on_emit
    dev_stacks: list[dict] = []
    done = threading.Event()

    def device_sampler():
        seen = None
        while not done.wait(0.01):
            if not emitted or dev._thread is None:
                continue
            last, now = emitted[-1], time.perf_counter()
            if now - last > 2 * STALL_S / 4 and seen != last:
                seen = last
                frame = sys._current_frames().get(dev._thread.ident)
                dev_stacks.append({"index": len(emitted), "since_emit_s": now - last,
                                   "stack": traceback.format_stack(frame)[-5:] if frame else []})

    threading.Thread(target=device_sampler, daemon=True).start()
    probe_out = os.path.join(tmp, f"probe{k}.json")
    cmd = [sys.executable, "-m", "benchmarks.command_timing", "--probe", probe_out, "--", "control",
           "--serial", dev.path, "--model", str(MODEL), "--reference", REFERENCE, "--seconds", str(seconds),
           "--feedback", "on", "--json", os.path.join(tmp, f"summary{k}.json")]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stderr.readline()
        assert "link open" in line, line + proc.stderr.read()
        dev.start()
        _, err = proc.communicate(timeout=120)
    finally:
        done.set()
        dev.stop()
    host = json.loads(Path(probe_out).read_text())
    sends = np.array([t for t, _ in host["sends"]])
    delivered = np.array([n for _, n in host["sends"]])
    rec = np.array(received)
    em = np.diff(np.array(emitted))
    burst, run = 0, 0
    for d in em:
        run = run + 1 if d < BURST_S else 0
        burst = max(burst, run)
    gap_send = np.diff(sends[:-1]) if len(sends) > 2 else np.zeros(1)      # the last: the switch-off
    gap_recv_t = np.diff(rec[:-1, 0]) if len(rec) > 2 else np.zeros(1)
    gap_recv_n = np.diff(rec[:-1, 1]) if len(rec) > 2 else np.zeros(1)
    reads = np.array(host["reads"])
    rd = np.diff(reads[:, 0])
    r = int(np.argmax(rd))
    i = int(np.argmax(gap_recv_n))
    j = int(np.argmax(em))
    h = int(np.argmax(gap_send))
    summary = json.loads(Path(tmp, f"summary{k}.json").read_text())
    return {"exit": proc.returncode, "host_seen_trips": summary["watchdog_trips"],
            "link_stalls": summary["link_stalls"], "link_silence_max_ms": summary["link_silence_max_ms"],
            "device_watchdog_trips": dev.stats.watchdog_trips,
            "commands_sent": len(sends), "host_gap_max_ms": float(gap_send.max() * 1e3),
            "host_gap_max_samples_read": int(delivered[h + 1] - delivered[h]),
            "host_gap_max_at_ms": float((sends[h] - sends[0]) * 1e3),
            "host_read_pause_max_ms": float(rd[r] * 1e3),
            "host_read_pause_cpu_ms": float(np.diff(reads[:, 1])[r] * 1e3),
            "host_read_pause_at_ms": float((reads[r, 0] - sends[0]) * 1e3),
            "gc_over_10ms": [[round((t - sends[0]) * 1e3), round(d * 1e3)] for t, d in host["gcs"] if d > 0.01],
            "device_gap_max_ms": float(gap_recv_t.max() * 1e3), "device_gap_max_samples": int(gap_recv_n.max()),
            "device_gap_max_at_ms_ms": [float((rec[i, 0] - sends[0]) * 1e3), float(gap_recv_t[i] * 1e3)],
            "device_pause_max_ms": float(em.max() * 1e3),
            "device_pause_max_at": [j, float((emitted[j] - sends[0]) * 1e3)],
            "device_stalls": dev_stacks[:4], "device_burst_max_samples": burst,
            "gc_max_ms": float(max((d for _, d in host["gcs"]), default=0.0) * 1e3),
            "host_stalls": host["stacks"][:3], "stderr_tail": err.strip().splitlines()[-1:] if proc.returncode else []}


PTY_CHILD = """
import os, sys, threading, time, select, json
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
late = [0.0]
def keepalive():
    while True:
        a = time.perf_counter(); time.sleep(0.01); late[0] = max(late[0], time.perf_counter() - a - 0.01)
        os.write(fd, b"k")
threading.Thread(target=keepalive, daemon=True).start()
t0 = last = time.perf_counter(); gap = 0.0
while time.perf_counter() - t0 < float(sys.argv[2]):
    if select.select([fd], [], [], 0.5)[0]:
        os.read(fd, 4096); now = time.perf_counter(); gap = max(gap, now - last); last = now
print(json.dumps({"device_to_host_gap_max_ms": gap * 1e3, "host_oversleep_max_ms": late[0] * 1e3}))
"""
PIPE_CHILD = """
import os, sys, time, select, json
fd = int(sys.argv[1]); t0 = last = time.perf_counter(); gap = 0.0
while time.perf_counter() - t0 < float(sys.argv[2]):
    if select.select([fd], [], [], 0.5)[0]:
        os.read(fd, 4096); now = time.perf_counter(); gap = max(gap, now - last); last = now
print(json.dumps({"pipe_gap_max_ms": gap * 1e3}))
"""


def pty_only(seconds: float) -> dict:
    """The bare pseudo-terminal, no rtlift: a device thread writes a 43-byte packet every 2.5 ms
    to the master and reads the master; a host process reads the slave and writes a byte every
    10 ms; beside it the same packets through a pipe to another process. Longest gap each way,
    the pipe's, and how late the host's own 10 ms sleeps woke (is it the host that stalls, or the
    wire?)."""
    master, slave = os.openpty()
    for fd in (master, slave):
        tty.setraw(fd)
    os.set_blocking(master, False)
    child = subprocess.Popen([sys.executable, "-c", PTY_CHILD, os.ttyname(slave), str(seconds)],
                             stdout=subprocess.PIPE, text=True)
    pipe_r, pipe_w = os.pipe()
    piped = subprocess.Popen([sys.executable, "-c", PIPE_CHILD, str(pipe_r), str(seconds)], pass_fds=(pipe_r,),
                             stdout=subprocess.PIPE, text=True)
    os.close(pipe_r)
    back = [0.0]
    refused = [0]

    def read_master():
        last = time.perf_counter()
        while child.poll() is None:
            if select.select([master], [], [], 0.2)[0]:
                try:
                    os.read(master, 4096)
                except BlockingIOError:
                    continue
                now = time.perf_counter()
                back[0] = max(back[0], now - last)
                last = now

    threading.Thread(target=read_master, daemon=True).start()
    deadline = time.perf_counter()
    end = deadline + seconds
    late = 0.0
    while time.perf_counter() < end:
        deadline += 0.0025
        time.sleep(max(0.0, deadline - time.perf_counter()))
        late = max(late, time.perf_counter() - deadline)
        try:
            os.write(master, b"x" * 43)
        except BlockingIOError:
            refused[0] += 1
        os.write(pipe_w, b"x" * 43)
    out = {**json.loads(child.communicate()[0]), **json.loads(piped.communicate()[0])}
    os.close(pipe_w)
    os.close(master)
    os.close(slave)
    return {**out, "host_to_device_gap_max_ms": back[0] * 1e3, "device_late_max_ms": late * 1e3,
            "device_writes_refused": refused[0]}


def main() -> None:
    if "--probe" in sys.argv:
        i = sys.argv.index("--probe")
        sys.exit(probe(sys.argv[i + 1], sys.argv[i + 3:]))
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--load", type=int, default=3, help="busy processes at niceness 19")
    p.add_argument("--disk", type=int, default=0, help="disk writers at niceness 19")
    p.add_argument("--seconds", type=float, default=11.0)
    p.add_argument("--pty-only", action="store_true", help="the bare pseudo-terminal, no rtlift (pty_only)")
    p.add_argument("--load-kind", choices=("numpy", "alloc", "spin"), default="numpy",
                   help="numpy: eigenvalues of 200x200 (CI's computing tests); alloc: 4 MB allocated and "
                        "freed in a loop; spin: a pure-Python busy loop")
    p.add_argument("--idle", action="store_true", help="the load at SCHED_IDLE instead of niceness 19")
    a = p.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        load = _load(a.load, a.disk, tmp, a.load_kind, a.idle)
        try:
            time.sleep(1.0)
            for k in range(a.runs):
                runs.append(pty_only(a.seconds) if a.pty_only else one_run(tmp, a.seconds, k))
                print(json.dumps({key: v for key, v in runs[-1].items() if key != "host_stalls"}),
                      file=sys.stderr, flush=True)
        finally:
            for q in load:
                q.kill()
                q.wait()
    head = {"benchmark": "command_timing", "load": a.load, "load_kind": a.load_kind, "idle": a.idle, "disk": a.disk,
            "seconds": a.seconds, "loadavg": os.getloadavg()[0], "runs": runs}
    if a.pty_only:
        emit({**head, "mode": "pty_only"})
        return
    emit({**head,
          "trips": [r["device_watchdog_trips"] for r in runs],
          "host_gap_max_ms": [round(r["host_gap_max_ms"], 1) for r in runs],
          "device_gap_max_ms": [round(r["device_gap_max_ms"], 1) for r in runs],
          "device_gap_max_samples": [r["device_gap_max_samples"] for r in runs]})


if __name__ == "__main__":
    main()
