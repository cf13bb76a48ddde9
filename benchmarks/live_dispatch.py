"""The observer loop's per-sample work outside the step: ``ObserverLoop.feed`` timed per call.

Samples are made once, in memory, the way a serial link delivers them: the bench's ``random``
experiment (seed 4) through the serial wire format and :class:`firmware_io.serial_codec.SerialDecoder`,
with every 400th sample dropped (so the loop also fills gaps with predict-only steps). The same
samples then go through a fresh :class:`rtlift.app.live.ObserverLoop` (same model, a fresh observer)
in two set-ups, alternated ``--repeats`` times so both see the same machine load:

- ``bare``: no listener (converter → observer step → latency and counters);
- ``full``: the departure monitor (the model's own), a live view's tap (a ``deque(maxlen=4000)``)
  and an estimates file (``EstimateWriter`` in a temporary folder) — what ``rtlift observe --out
  F --view`` runs per sample.

Prints JSON as its last line: per set-up ``feed_median_us`` and ``feed_p99_us`` (one ``feed``
call: one received sample, with the predict-only steps of a gap before it), ``samples``; and
``full_minus_bare_median_us`` (what the listeners cost per sample). Measured, not asserted.

    python benchmarks/live_dispatch.py [--model tests/data/bench_model.json] [--seconds 60] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import deque

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, percentiles_us  # noqa: E402

DROP_EVERY = 400


def make_samples(seconds: float) -> list:
    """The bench's ``random`` experiment as decoded serial samples (every 400th dropped)."""
    from firmware_io.serial_codec import SerialDecoder, encode_sample
    from hil_sim.devices.source import serial_wire, wire_samples
    from hil_sim.experiments import daq_stream
    from rtlift.core.rate import FS_HZ

    n = int(round(seconds * FS_HZ))
    out: list = []
    decoder = SerialDecoder(out.append)
    decoder.feed(b"\x00")
    period_us = int(round(1e6 / FS_HZ))
    for k, (volt_cv, envelope_cv, status, counts) in enumerate(wire_samples(daq_stream("random", seed=4),
                                                                            serial_wire)):
        if k >= n:
            break
        if k % DROP_EVERY != DROP_EVERY - 1:
            decoder.feed(encode_sample(k, k * period_us, volt_cv, counts, status, envelope_cv, 0))
    return out


def one_run(model, samples: list, full: bool, folder: str) -> np.ndarray:
    """Durations (s) of each ``feed`` call over ``samples``."""
    from firmware_io.convert import Converter
    from rtlift.app.live import EstimateWriter, ObserverLoop
    from rtlift.observer import Observer
    from rtlift.observer.monitor import DepartureMonitor

    observer = Observer.from_model(model)
    observer.warm_up()
    kw = {}
    if full:
        kw = {"monitor": DepartureMonitor.for_model(model), "tap": deque(maxlen=4000),
              "writer": EstimateWriter(os.path.join(folder, "estimates.csv"), {"fs_hz": f"{model.fs_hz:g}"})}
    loop = ObserverLoop(observer, Converter(None, model.fs_hz), 1 << 16, fs_hz=model.fs_hz, **kw)
    feed, pc = loop.feed, time.perf_counter
    durations = np.empty(len(samples))
    for i, s in enumerate(samples):
        t0 = pc()
        feed(s)
        durations[i] = pc() - t0
    if full:
        kw["writer"].close()
    return durations


def main(argv: list[str] | None = None) -> None:
    from rtlift.model.modelfile import load_model

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default=os.path.join(os.path.dirname(__file__), "..", "tests", "data",
                                                   "bench_model.json"))
    p.add_argument("--seconds", type=float, default=60.0, help="device seconds of samples (default 60)")
    p.add_argument("--repeats", type=int, default=3, help="bare/full pairs, alternated (default 3)")
    args = p.parse_args(argv)
    model = load_model(args.model)
    samples = make_samples(args.seconds)
    runs: dict[str, list[np.ndarray]] = {"bare": [], "full": []}
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(args.repeats):
            for setup in ("bare", "full"):
                runs[setup].append(one_run(model, samples, setup == "full", folder))
    out: dict = {"samples": len(samples), "repeats": args.repeats, "model": args.model}
    for setup, parts in runs.items():
        med, p99 = percentiles_us(np.concatenate(parts))
        out[setup] = {"feed_median_us": round(med, 3), "feed_p99_us": round(p99, 3)}
    out["full_minus_bare_median_us"] = round(out["full"]["feed_median_us"] - out["bare"]["feed_median_us"], 3)
    emit(out)


if __name__ == "__main__":
    main()
