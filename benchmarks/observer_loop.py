"""The observer loop live: bench emulator on a pseudo-terminal → serial link → observer.

The simulated DAQ runs in its own process (``rtlift bench serve --serial``, the ``random``
experiment at 400 Hz); this process opens the pty with firmware_io, converts, and steps the
observer once per received sample, as ``rtlift observe`` does. Prints JSON as its last line:
``observer_step_median_us``, ``observer_step_p99_us`` (one ``Observer.step``),
``loop_latency_p50_ms``, ``loop_latency_p99_ms`` (sample receipt → estimate),
``lost_samples``, ``seconds``; plus the other link counters and a tracemalloc measurement of
one step (bytes retained after 2000 steps, transient peak). Targets: step p99 ≤ 100 µs,
latency p99 ≤ 1 ms. Measured, not asserted.

``--model MODEL.json`` uses a model file with observer settings; by default the model is
identified from the bench (seed 1, 2nd-order Wiener) and the observer tuned on a seed-1
``random`` record first (≈ 15 s, not timed).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
import tracemalloc

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, percentiles_us  # noqa: E402


def default_model():
    from hil_sim.experiments import run_experiment
    from rtlift.identify.campaign import IdentifyOptions, identify_hybrid
    from rtlift.observer import tune_observer

    recs = {n: run_experiment(n, seed=1).to_record() for n in ("static", "single_burst", "sine_k0125", "random")}
    model = identify_hybrid(recs["static"], recs["single_burst"], recs["sine_k0125"], IdentifyOptions(order=2)).model
    model.observer_config = tune_observer(model, [recs["random"]])
    return model


def allocation(model) -> dict:
    """tracemalloc around 2000 steps after a warm-up: retained and transient bytes."""
    from hil_sim.experiments import run_experiment
    from rtlift.observer import Observer

    rec = run_experiment("random", seed=4).to_record()
    obs = Observer.from_model(model)
    c, e, z = rec.cmu.tolist(), rec.cmu_envelope.tolist(), rec.dcl.tolist()
    for k in range(1000):
        obs.step(c[k], e[k], z[k])
    tracemalloc.start()
    for k in range(1000, 3000):
        obs.step(c[k], e[k], z[k])
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {"alloc_retained_bytes_after_2000_steps": current, "alloc_transient_peak_bytes": peak - current}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="device seconds to run (default 20)")
    ap.add_argument("--model", help="model file with observer settings (default: identify and tune)")
    args = ap.parse_args()

    from firmware_io import Converter, open_link
    from rtlift.live import ObserverLoop
    from rtlift.modelfile import load_model
    from rtlift.observer import Observer

    model = load_model(args.model) if args.model else default_model()
    observer = Observer.from_model(model)
    serve = subprocess.Popen([sys.executable, "-m", "rtlift", "bench", "serve", "--serial", "--experiment", "random",
                              "--seed", "3"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        path = serve.stdout.readline().strip()
        with open_link({"kind": "serial", "port": path}) as link:
            loop = ObserverLoop(observer, Converter(), link.seq_modulus, fs_hz=model.fs_hz,
                                max_samples=int(round(args.seconds * model.fs_hz)), time_steps=True)
            t0 = time.perf_counter()
            loop.run(link.samples(0.5), host_timeout_s=args.seconds + 10.0)
            wall = time.perf_counter() - t0
            counters = link.counters.as_dict()
    finally:
        serve.terminate()
        serve.wait(10)
    step_median, step_p99 = percentiles_us(np.frombuffer(loop.stats.step_times, dtype=float))
    lat50, lat99 = loop.stats.latency_ms()
    result = {
        "observer_step_median_us": round(step_median, 2),
        "observer_step_p99_us": round(step_p99, 2),
        "loop_latency_p50_ms": round(lat50, 4),
        "loop_latency_p99_ms": round(lat99, 4),
        "lost_samples": counters["lost"],
        "seconds": round(wall, 2),
        "samples": loop.stats.samples,
        "state_dim": observer.structure.d,
        **{k: v for k, v in counters.items() if k != "lost"},
        **allocation(model),
    }
    emit(result)


if __name__ == "__main__":
    main()
