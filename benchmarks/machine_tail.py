"""The floor the machine sets under the live step's p99, with no rtlift code in it.

The live observer step's p99 (``benchmarks/observer_loop.py``) is the step's own cost plus
whatever the machine does to a thread that wakes 400 times a second. This script measures the
second part alone, in one run, so the two can be compared:

- ``gaps``: a thread reading ``perf_counter`` back to back for ``--seconds`` / 3; every gap
  between two readings longer than 20 / 50 / 100 µs is an interruption (the kernel, another
  process, the hypervisor). Rate per second of each, and the longest.
- ``work``: a fixed workload of ``--work-us`` µs (a pure-Python loop calibrated on this machine in
  a tight loop first) timed three ways, alternated in rounds of 400 repetitions so that all see the
  same machine: back to back (``tight``); after sleeping to an absolute 400 Hz deadline, as
  ``rtlift observe`` waits (``sleep``); and after spinning to the same deadline (``spin``).
  Median and p99 of each, in µs.

If ``work.sleep`` p99 is far above ``work.tight`` p99 for a workload with no I/O and no
allocation, the tail is the machine's wake-up, not the code it wakes. Prints JSON as its last line.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, percentiles_us  # noqa: E402

PERIOD_S = 1.0 / 400.0
ROUND = 400


def _spin(n: int) -> float:
    acc = 0.0
    for i in range(n):
        acc += i * 0.5
    return acc


def calibrate(work_us: float) -> int:
    """Loop count whose tight-loop median is ``work_us``."""
    n = 200
    while True:
        ts = []
        for _ in range(50):
            t0 = time.perf_counter()
            _spin(n)
            ts.append(time.perf_counter() - t0)
        med = float(np.median(ts)) * 1e6
        if med >= work_us or n > 10**7:
            return max(1, int(n * work_us / med))
        n *= 2


def gaps(seconds: float) -> dict:
    """Interruptions of a thread that never sleeps: gaps between consecutive clock readings."""
    pc = time.perf_counter
    end = pc() + seconds
    last = pc()
    found = []
    n = 0
    while last < end:
        now = pc()
        if now - last > 20e-6:
            found.append(now - last)
        last = now
        n += 1
    g = np.asarray(found) * 1e6
    return {"seconds": seconds, "readings": n,
            **{f"per_s_over_{t}us": float(np.sum(g > t) / seconds) for t in (20, 50, 100)},
            "longest_us": float(g.max()) if g.size else 0.0,
            "median_gap_over_20us": float(np.median(g)) if g.size else 0.0}


def work(n: int, seconds: float) -> dict:
    """The fixed workload timed tight, after a sleep to a 400 Hz deadline, after a spin to it."""
    times: dict[str, list[float]] = {"tight": [], "sleep": [], "spin": []}
    pc = time.perf_counter
    end = pc() + seconds
    while pc() < end:
        for mode in ("tight", "sleep", "spin"):
            deadline = pc() + PERIOD_S
            for _ in range(ROUND if mode != "tight" else ROUND // 4):
                if mode == "sleep":
                    d = deadline - pc()
                    if d > 0:
                        time.sleep(d)
                elif mode == "spin":
                    while pc() < deadline:
                        pass
                t0 = pc()
                _spin(n)
                times[mode].append(pc() - t0)
                deadline += PERIOD_S
    out = {}
    for mode, ts in times.items():
        med, p99 = percentiles_us(np.asarray(ts))
        out[mode] = {"n": len(ts), "median_us": med, "p99_us": p99, "p999_us": float(np.percentile(ts, 99.9) * 1e6)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--work-us", type=float, default=20.0)
    a = ap.parse_args()
    n = calibrate(a.work_us)
    result = {"work_loop_count": n, "gaps": gaps(a.seconds / 3), "work": work(n, 2 * a.seconds / 3),
              "loadavg_1min": os.getloadavg()[0]}
    emit(result)


if __name__ == "__main__":
    main()
