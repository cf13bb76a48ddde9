"""One HybridModel.step (300-sample kernel) and batch-vs-streaming throughput.

Prints JSON as its last line: step_median_us, step_p99_us, batch_speedup (batch vs
streaming throughput on a 10-minute 400 Hz record, same output), max_abs_difference.
Targets (issue 2): step median ≤ 10 µs, batch ≥ 100× faster than streaming.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, percentiles_us  # noqa: E402
from tests.conftest import burst_input, make_model  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="record length for the throughput test")
    ap.add_argument("--steps", type=int, default=50_000, help="timed single steps")
    args = ap.parse_args()

    rng = np.random.default_rng(0)
    model = make_model(rng, kernel_len=300, order=2, hp_order=2)
    n = int(args.minutes * 60 * 400)
    cmu, env = burst_input(rng, n)

    # single-step latency: time each call with perf_counter_ns around it
    durations = np.empty(args.steps)
    pc = time.perf_counter
    step = model.step
    for i in range(args.steps):
        c, e = float(cmu[i]), float(env[i])
        t0 = pc()
        step(c, e)
        durations[i] = pc() - t0
    step_median, step_p99 = percentiles_us(durations)

    # throughput: the whole record streamed vs in one batch call (same result)
    model.reset()
    t0 = pc()
    streamed = np.fromiter((step(c, e)[0] for c, e in zip(cmu.tolist(), env.tolist(), strict=True)),
                           float, count=n)
    t_stream = pc() - t0
    batch_times = []
    for _ in range(5):
        model.reset()
        t0 = pc()
        batch = model.simulate(cmu, env).total
        batch_times.append(pc() - t0)
    t_batch = float(np.median(batch_times))
    emit({
        "step_median_us": round(step_median, 3),
        "step_p99_us": round(step_p99, 3),
        "batch_speedup": round(t_stream / t_batch, 1),
        "stream_seconds": round(t_stream, 3),
        "batch_seconds": round(t_batch, 4),
        "samples": n,
        "kernel_len": 300,
        "max_abs_difference": float(np.max(np.abs(streamed - batch))),
    })


if __name__ == "__main__":
    main()
