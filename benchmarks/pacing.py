"""Wall-clock timing the tests used to assert and now only measure (issue 30: no timing in tests).

The tests keep the functional side (what arrives, what is written, bit for bit); how long it
takes on this machine is measured here, ``--repeats`` times each, medians quoted:

- ``bench_record``: ``rtlift bench record sine_k0125`` as a subprocess, wall and CPU seconds
  (tests/test_bench_cli.py used to assert CPU < 5 s, wall < 15 s);
- ``pty_serial``/``pty_slcan``: ``--seconds`` of 400 Hz samples from the emulated DAQ / SLCAN
  adapter on a pseudo-terminal read through ``firmware_io.open_link``: wall seconds, and the
  overshoot over the device time (tests/test_io_pty.py: within 3 s);
- ``realtime_replay``: ``rtlift replay LOG --realtime`` of a serial log of ``--seconds``:
  wall seconds against the log's device time (tests/test_replay_observe.py: 2.7–6 s for 3 s);
- ``recv_timeout``: ``link.recv(0.1)`` on a silent serial link: seconds until it gives up
  (tests/test_io_links.py: < 0.5 s).

Live observer latency is ``benchmarks/observer_loop.py``'s, command latency
``benchmarks/command_latency.py``'s; they are not repeated here.

    python -m benchmarks.pacing [--repeats 3] [--seconds 3]

Prints JSON as its last line.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks._common import emit, run_cli  # noqa: E402
from benchmarks.soak import _observer_loop  # noqa: E402
from firmware_io import open_link  # noqa: E402
from firmware_io.serial_codec import (
    SEQ_MODULUS,  # noqa: E402
    encode_sample,  # noqa: E402
)
from hil_sim.devices import SerialDaq, SlcanAdapter, synthetic_stream  # noqa: E402
from hil_sim.devices.source import serial_wire, wire_samples  # noqa: E402
from hil_sim.experiments import daq_stream  # noqa: E402
from rtlift.core.rate import FS_HZ, PERIOD_S  # noqa: E402
from rtlift.model.modelfile import save_model  # noqa: E402


def _median(xs: list[float]) -> float:
    return round(float(np.median(xs)), 3)


def bench_record(tmp: Path) -> dict:
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "rtlift", "bench", "record", "sine_k0125",
                           "--out", str(tmp / "x.csv")], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"pacing: rtlift bench record failed: {done.stderr.strip()}")
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu}


def pty_read(make, seconds: float) -> float:
    """Wall seconds from the device's start until ``seconds`` of samples have arrived."""
    n = int(round(seconds * FS_HZ))
    dev = make(daq_stream("train_T1p75", seed=3), max_samples=n)
    config = ({"kind": "serial", "port": dev.path} if make is SerialDaq
              else {"kind": "can", "interface": "slcan", "channel": dev.path, "bitrate": 500000})
    with dev, open_link(config) as link:
        t0 = time.perf_counter()
        dev.start()
        got = 0
        for s in link.samples(2.0):
            if s is None:
                break
            got += 1
            if got == n:
                break
        wall = time.perf_counter() - t0
    if got != n:
        raise SystemExit(f"pacing: {make.__name__} delivered {got} of {n} samples")
    return wall


def serial_log(path: Path, seconds: float) -> Path:
    """A serial capture of ``seconds`` of the synthetic stream (what ``rtlift observe --log`` writes)."""
    n = int(round(seconds * FS_HZ))
    it = wire_samples(synthetic_stream(0), serial_wire)
    frames = []
    for seq in range(n):
        volt_cv, envelope_cv, status, ft = next(it)
        frames.append(encode_sample(seq, int(round(seq * PERIOD_S * 1e6)), volt_cv, ft, status, envelope_cv))
    path.write_bytes(b"".join(frames))
    return path


def realtime_replay(log: Path, model: Path) -> float:
    t0 = time.perf_counter()
    run_cli("replay", log, "--model", model, "--realtime")
    return time.perf_counter() - t0


def recv_timeout(timeout_s: float = 0.1) -> float:
    with open_link({"kind": "serial", "port": "loop://"}) as link:
        t0 = time.perf_counter()
        if link.recv(timeout_s) is not None:
            raise SystemExit("pacing: a silent loop:// link delivered a sample")
        return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs of each measurement (default 3)")
    ap.add_argument("--seconds", type=float, default=3.0, help="device seconds per pty read and replay (default 3)")
    args = ap.parse_args()
    if args.repeats < 1 or not args.seconds > 0:
        raise SystemExit("pacing: --repeats must be ≥ 1 and --seconds positive")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        records = [bench_record(tmp) for _ in range(args.repeats)]
        serial = [pty_read(SerialDaq, args.seconds) for _ in range(args.repeats)]
        slcan = [pty_read(SlcanAdapter, args.seconds) for _ in range(args.repeats)]
        model = tmp / "model.json"
        observer = _observer_loop(1, SEQ_MODULUS)[0]       # the soak's bench-sized model and observer settings
        save_model(observer.model, model, observer=observer.model.observer_config)
        log = serial_log(tmp / "run.bin", args.seconds)
        replays = [realtime_replay(log, model) for _ in range(args.repeats)]
        timeouts = [recv_timeout() for _ in range(10 * args.repeats)]
    emit({
        "repeats": args.repeats, "device_seconds": args.seconds,
        "bench_record_wall_median_s": _median([r["wall_s"] for r in records]),
        "bench_record_cpu_median_s": _median([r["cpu_s"] for r in records]),
        "pty_serial_wall_median_s": _median(serial),
        "pty_serial_overshoot_max_s": round(max(serial) - args.seconds, 3),
        "pty_slcan_wall_median_s": _median(slcan),
        "pty_slcan_overshoot_max_s": round(max(slcan) - args.seconds, 3),
        "realtime_replay_wall_median_s": _median(replays),
        "realtime_replay_overshoot_max_s": round(max(replays) - args.seconds, 3),
        "recv_timeout_0p1_median_s": _median(timeouts),
        "recv_timeout_0p1_max_s": round(max(timeouts), 3),
    })


if __name__ == "__main__":
    main()
