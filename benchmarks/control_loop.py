"""Closed-loop lift tracking live: ``rtlift control`` against the bench as a HIL plant.

For each reference (steps, a slow sine) and each of feedforward only / feedforward +
feedback, the simulated DAQ (serial, or slcan with ``--can``) runs in this process on a
pseudo-terminal with an undeclared actuator fade to 75 % setting in during the run, and
``rtlift control`` runs in its own process. Scored on the bench truth (the plant's noise-free
ΔCL, which the host never sees), low-passed at 1 Hz like the reference, over the tracking
time; beside it the summary's own ``tracking_rmse`` (against the observer's estimate), the
command counters and latency, and lost samples. Prints the table, then one JSON line:
``rows`` and ``ratio_steps``/``ratio_sine`` (feedback RMSE ÷ feedforward RMSE).

``--model MODEL.json`` (default: tests/data/bench_model.json, identified on the bench, seed 1).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from scipy import signal

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402

ROOT = os.path.join(os.path.dirname(__file__), "..")
FS = 400
TRACKING_STARTS = 3 * FS
FADE = "actuator_fade:final_fraction=0.75,time_constant_s=0.4"
REFERENCES = {"steps": "steps:0.06@0,0.12@5,0.16@10,0.08@15",
              "sine": "sine:mean=0.11,amp=0.04,hz=0.1"}


def reference_values(spec: str, n: int) -> np.ndarray:
    from rtlift.reference import parse_reference

    ref = parse_reference(spec)
    return np.array([ref.at(k / FS) for k in range(n)])


def one_run(model: str, spec: str, feedback: str, seconds: float, can: bool, tmp: str) -> dict:
    from hil_sim.devices import SerialDaq, SlcanAdapter
    from hil_sim.hil import HilStream

    stream = HilStream("random", seed=11, effects=[FADE])
    dev = (SlcanAdapter if can else SerialDaq)(stream)
    stream.control = dev.control
    link = ["--can", f"slcan:{dev.path}"] if can else ["--serial", dev.path]
    out = os.path.join(tmp, f"summary_{feedback}.json")
    cmd = [sys.executable, "-m", "rtlift", "control", *link, "--model", model, "--reference", spec,
           "--seconds", str(seconds), "--feedback", feedback, "--json", out]
    env = {**os.environ, "PYTHONPATH": os.path.abspath(ROOT)}
    with dev:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        proc.stderr.readline()
        dev.start()
        _, err = proc.communicate(timeout=seconds + 60)
    if proc.returncode != 0:
        raise RuntimeError(f"rtlift control exited {proc.returncode}: {err.strip()}")
    s = json.loads(open(out, encoding="utf-8").read())
    idx, truth = stream.truth_array()
    n = int(seconds * FS)
    sel = (idx >= TRACKING_STARTS) & (idx < TRACKING_STARTS + n)
    y = truth[sel]
    r = reference_values(spec, len(y))
    sos = signal.butter(2, 1.0, fs=FS, output="sos")
    rmse = float(np.sqrt(np.mean((signal.sosfiltfilt(sos, y) - signal.sosfiltfilt(sos, r)) ** 2)))
    return {"feedback": feedback, "rmse_truth": rmse, "rmse_estimate": s["tracking_rmse"],
            "lost": s["lost"], "commands_sent": s["commands_sent"], "commands_applied": s["commands_applied"],
            "superseded": dev.stats.commands_superseded, "watchdog_trips": s["watchdog_trips"],
            "command_latency_p50_ms": s["command_latency_p50_ms"],
            "command_latency_p99_ms": s["command_latency_p99_ms"],
            "saturated_fraction": s["saturated_fraction"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=os.path.join(ROOT, "tests", "data", "bench_model.json"))
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--can", action="store_true", help="slcan instead of serial")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, spec in REFERENCES.items():
            for fb in ("off", "on"):
                row = one_run(args.model, spec, fb, args.seconds, args.can, tmp)
                row["reference"] = name
                rows.append(row)
    print(f"{'reference':10} {'feedback':8} {'RMSE truth':>10} {'RMSE est':>9} {'lost':>5} "
          f"{'sent':>5} {'applied':>7} {'lat p50':>8} {'lat p99':>8} {'sat':>6}")
    for r in rows:
        print(f"{r['reference']:10} {r['feedback']:8} {r['rmse_truth']:10.4f} {r['rmse_estimate']:9.4f} "
              f"{r['lost']:5d} {r['commands_sent']:5d} {r['commands_applied']:7d} "
              f"{r['command_latency_p50_ms']:6.2f}ms {r['command_latency_p99_ms']:6.2f}ms "
              f"{r['saturated_fraction']:6.1%}")
    by = {(r["reference"], r["feedback"]): r["rmse_truth"] for r in rows}
    emit({"rows": rows, "link": "slcan" if args.can else "serial", "seconds": args.seconds,
          "ratio_steps": by[("steps", "on")] / by[("steps", "off")],
          "ratio_sine": by[("sine", "on")] / by[("sine", "off")]})


if __name__ == "__main__":
    main()
