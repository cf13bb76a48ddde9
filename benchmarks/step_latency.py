"""One HybridModel.step (300-sample kernel), compiled and reference, and batch-vs-streaming throughput.

Prints JSON as its last line: step_median_us, step_p99_us (the compiled ``HybridModel.step``),
reference_step_median_us, reference_step_p99_us (the pure-Python ``reference_step``, same run,
same model), warm_up_seconds (compile or cache load), batch_speedup (batch vs streaming
``step`` throughput on a 10-minute 400 Hz record, same output), batch_speedup_vs_reference
(the same against ``reference_step``), max_abs_difference (batch vs streamed ``step``) and
max_abs_difference_reference (compiled vs reference ``step``).
Targets (issue 14): step median ≤ 2 µs, batch ≥ 100× faster than streaming. The same figures
for a model of the ``interaction`` structure (issue 31: order-3 Wiener part, a 2-sample delay,
the same kernel length and input) under ``"interaction"``; its target: step median ≤ 2 µs,
batch ≥ 100× faster per sample than the pure-Python step (``batch_speedup_vs_reference``).
Under ``"interaction_augmented"`` the same interaction model with what the diagnosis adds to it
(``testkit.synthetic.with_effects``: an actuator fade, a sensor resonance and a zero drift after
the sum, a hysteresis factor driven by the lift), compiled since the hysteresis fit on that
structure (issue 31).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, percentiles_us  # noqa: E402
from rtlift.core.rate import FS_HZ  # noqa: E402
from rtlift.model.hybrid import HybridModel  # noqa: E402
from testkit.synthetic import burst_input, interaction_model, make_model, with_effects  # noqa: E402


def _latency(step, cmu: np.ndarray, env: np.ndarray) -> tuple[float, float]:
    """Median and p99 (µs) of single calls, each timed with perf_counter around it."""
    durations = np.empty(cmu.size)
    pc = time.perf_counter
    for i, (c, e) in enumerate(zip(cmu.tolist(), env.tolist(), strict=True)):
        t0 = pc()
        step(c, e)
        durations[i] = pc() - t0
    return percentiles_us(durations)


def _stream(step, cmu: np.ndarray, env: np.ndarray) -> tuple[np.ndarray, float]:
    pc = time.perf_counter
    t0 = pc()
    out = np.fromiter((step(c, e)[0] for c, e in zip(cmu.tolist(), env.tolist(), strict=True)),
                      float, count=cmu.size)
    return out, pc() - t0


def measure(model, cmu: np.ndarray, env: np.ndarray, steps: int) -> dict[str, float]:
    """The figures of the module docstring for one model (compiled step, reference step, batch)."""
    if not model.compiled:
        raise SystemExit("step_latency: the benchmark model does not take the compiled step")
    warm_up_s = model.warm_up()
    step_median, step_p99 = _latency(model.step, cmu[:steps], env[:steps])
    model.reset()
    ref_median, ref_p99 = _latency(model.reference_step, cmu[:steps], env[:steps])

    # throughput: the whole record streamed (compiled, then reference) vs in one batch call
    model.reset()
    streamed, t_stream = _stream(model.step, cmu, env)
    model.reset()
    reference, t_reference = _stream(model.reference_step, cmu, env)
    batch_times = []
    for _ in range(5):
        model.reset()
        t0 = time.perf_counter()
        batch = model.simulate(cmu, env).total
        batch_times.append(time.perf_counter() - t0)
    t_batch = float(np.median(batch_times))
    return {
        "step_median_us": round(step_median, 3),
        "step_p99_us": round(step_p99, 3),
        "reference_step_median_us": round(ref_median, 3),
        "reference_step_p99_us": round(ref_p99, 3),
        "warm_up_seconds": round(warm_up_s, 3),
        "batch_speedup": round(t_stream / t_batch, 1),
        "batch_speedup_vs_reference": round(t_reference / t_batch, 1),
        "stream_seconds": round(t_stream, 3),
        "reference_stream_seconds": round(t_reference, 3),
        "batch_seconds": round(t_batch, 4),
        "max_abs_difference": float(np.max(np.abs(streamed - batch))),
        "max_abs_difference_reference": float(np.max(np.abs(streamed - reference))),
    }


def benchmark_case(minutes: float) -> tuple[np.random.Generator, HybridModel, np.ndarray, np.ndarray]:
    """The benchmark's random stream (seed 0), model (300-sample kernel, order-2 Wiener part and
    high-pass) and ``minutes`` of burst input at 400 Hz (Cμ, Cμ_env), in that order of draws."""
    rng = np.random.default_rng(0)
    model = make_model(rng, kernel_len=300, order=2, hp_order=2)
    cmu, env = burst_input(rng, int(minutes * 60 * FS_HZ))
    return rng, model, cmu, env


def arguments(description: str, minutes: float = 10.0, steps: int = 50_000) -> argparse.Namespace:
    """The command line of a latency benchmark: ``--minutes`` (record length for the throughput
    test) and ``--steps`` (timed single steps, each path), with these defaults."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--minutes", type=float, default=minutes, help="record length for the throughput test")
    ap.add_argument("--steps", type=int, default=steps, help="timed single steps (each path)")
    return ap.parse_args()


def main() -> None:
    args = arguments(__doc__.splitlines()[0])
    rng, model, cmu, env = benchmark_case(args.minutes)
    n = cmu.size
    hybrid = measure(model, cmu, env, args.steps)
    inter = measure(interaction_model(rng, kernel_len=300, order=3, delay=2), cmu, env, args.steps)
    augmented = with_effects(interaction_model(np.random.default_rng(1), kernel_len=300, order=3, delay=2),
                             fade=True, outputs=(1, 2), hysteresis=2)
    emit({**hybrid, "samples": n, "kernel_len": 300, "interaction": inter,
          "interaction_augmented": measure(augmented, cmu, env, args.steps)})


if __name__ == "__main__":
    main()
