"""The loop notices and adapts: ``rtlift control --adapt`` on the simulated bench (issue 29).

Three closed loops side by side over real pseudo-terminals (``rtlift control`` in its own
process each, the bench in this one; :class:`rtlift.app.hil_tracking.BenchTracking`), tracking the
same steps for ``--seconds`` (default 120):

- ``fade_adapt``: an actuator fade to 70 % (on-time constant 2 s) sets in at t = 20 s of
  tracking, ``--adapt``;
- ``fade``: the same fade, monitor on, no ``--adapt``;
- ``clean``: no fade, ``--adapt`` (it must raise nothing and swap nothing).

The observer step's and the receive → estimate latency's percentiles are each run's own
(``rtlift control`` times every step), so ``fade_adapt``'s include the background diagnosis.
Printed per run: departures (time, test, suspect), adaptations (time, accepted, validation RMSE
before/after), tracking RMSE on the bench's truth over the whole run and the last 40 s (both
low-passed at 1 Hz), samples lost. ``--figure`` draws the truth against the reference for the three
runs with the departures and swaps marked. Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from rtlift.app.hil_tracking import BenchTracking, lowpass, reference_values

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "tests" / "data" / "bench_model.json"
REFERENCE = "steps:0.06@0,0.12@12,0.08@24,0.14@36,0.06@48,0.12@60,0.09@72,0.13@84,0.07@96,0.11@108"
ONSET_TRACKING_S = 20.0
TARE_S = 2.0
FIGURE = ROOT / "docs" / "figures" / "adapt.png"


def fade(onset_tracking_s: float = ONSET_TRACKING_S) -> str:
    # the bench's clock starts 3 s before tracking (1 s settle, 2 s tare)
    return f"actuator_fade:final_fraction=0.7,time_constant_s=2,onset_s={onset_tracking_s + 3.0:g}"


def on_draw(run: BenchTracking, draw: int, seed: int, effects: tuple[str, ...]) -> BenchTracking:
    """``run``'s bench made plant ``draw`` of the family (:mod:`hil_sim.family`) before it starts:
    the device keeps its pseudo-terminal, its stream becomes the drawn plant's."""
    from hil_sim.hil import HilStream

    if draw:
        control = run.stream.control
        run.stream.__dict__.update(HilStream("random", seed=seed, effects=list(effects), plant_draw=draw).__dict__)
        run.stream.control = control
    return run


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--model", default=str(MODEL), help="model file (default: the bench's)")
    ap.add_argument("--plant-draw", type=int, default=0,
                    help="plant N of the family (hil_sim.family; give --model, identified on it)")
    ap.add_argument("--reference", default=REFERENCE)
    ap.add_argument("--adapt-structure", action="store_true", help="pass --adapt-structure to the --adapt runs")
    ap.add_argument("--monitor", default=None, metavar="MODE",
                    help="pass --monitor MODE to every run (e.g. 'calibrate OUT.json': a baseline run; or FILE)")
    ap.add_argument("--figure", default=str(FIGURE))
    ap.add_argument("--no-figure", action="store_true")
    ap.add_argument("--runs", default="fade_adapt,fade,clean",
                    help="which of the three runs (default all; `--runs fade_adapt` alone measures the step "
                         "during the background diagnosis without two other loops on the machine)")
    ap.add_argument("--work", default=None, help="keep logs, windows and models here")
    args = ap.parse_args(argv)
    work = Path(args.work or tempfile.mkdtemp(prefix="rtlift-adapt-"))
    work.mkdir(parents=True, exist_ok=True)
    cases = {"fade_adapt": ((fade(),), True), "fade": ((fade(),), False), "clean": ((), True)}
    cases = {k: v for k, v in cases.items() if k in args.runs.split(",")}
    runs = {}
    for name, (effects, adapt) in cases.items():
        extra = ("--log", str(work / f"{name}.bin")) + (("--adapt", str(work / f"{name}_adapt")) if adapt else ())
        extra += ("--adapt-structure",) if adapt and args.adapt_structure else ()
        extra += ("--monitor", *args.monitor.split()) if args.monitor else ()
        extra += ("--accept-design-warnings",) if args.model != str(MODEL) else ()   # a drawn plant's model
        runs[name] = on_draw(BenchTracking(args.model, args.reference, True, args.seconds,
                                           str(work / f"{name}.json"), seed=args.seed, effects=effects, extra=extra),
                             args.plant_draw, args.seed, effects).start()
    out: dict = {"benchmark": "adapt_demo", "seconds": args.seconds, "onset_tracking_s": ONSET_TRACKING_S,
                 "plant_draw": args.plant_draw, "model": args.model, "reference": args.reference,
                 "onset_monitor_s": ONSET_TRACKING_S + TARE_S, "work": str(work), "runs": {}}
    traces = {}
    for name, run in runs.items():
        res = run.finish()
        t, truth, _ = run.traces()
        ref = reference_values(args.reference, len(truth))
        err = lowpass(truth) - lowpass(ref)
        s = run.summary
        row = {"rmse_truth": res["rmse_truth"],
               "rmse_truth_last40": float(np.sqrt(np.mean(err[t >= args.seconds - 40.0] ** 2))),
               "lost": res["lost"], "step_p50_us": s.get("step_p50_us"), "step_p99_us": s.get("step_p99_us"),
               "step_max_us": s.get("step_max_us"), "step_busy_p50_us": s.get("step_busy_p50_us"),
               "step_busy_p99_us": s.get("step_busy_p99_us"), "step_busy_max_us": s.get("step_busy_max_us"),
               "steps_busy": s.get("step_busy_n"),
               "latency_p50_ms": s.get("latency_p50_ms"), "latency_p99_ms": s.get("latency_p99_ms"),
               "departures": [{k: d[k] for k in ("t_s", "test", "statistic", "suspect")}
                                                   for d in s.get("departures", [])],
               "thresholds_from": (s.get("monitor") or {}).get("thresholds_from"),
               "adaptations": [{k: a.get(k) for k in ("t_s", "accepted", "kinds", "swapped", "rmse_before",
                                                      "rmse_after", "reason", "finding", "model_file")}
                               for a in s.get("adaptations", [])]}
        out["runs"][name] = row
        traces[name] = (t, truth, ref)
        print(f"{name}: tracking RMSE {row['rmse_truth']:.4f} (last 40 s {row['rmse_truth_last40']:.4f}); lost "
              f"{row['lost']}; observer step p99 {row['step_p99_us']:.1f} µs (during the background "
              f"diagnosis: {row['step_busy_p99_us'] or float('nan'):.1f} µs over {row['steps_busy'] or 0} steps), "
              f"latency p99 "
              f"{row['latency_p99_ms']:.2f} ms; departures "
              + ", ".join(f"{d['t_s']:.1f} s {d['test']} ({d['suspect']})" for d in row["departures"]) +
              "; adaptations " + ", ".join(f"{a['t_s'] if a['t_s'] is not None else '-'} s "
                                           f"{'+'.join(a['accepted'] or [])} {'swapped' if a['swapped'] else 'no swap'}"
                                           for a in row["adaptations"]), flush=True)
    r = out["runs"]
    if {"fade_adapt", "clean"} <= r.keys():
        out["ratio_last40_vs_clean"] = r["fade_adapt"]["rmse_truth_last40"] / r["clean"]["rmse_truth_last40"]
    if {"fade", "clean"} <= r.keys():
        out["ratio_last40_noadapt_vs_clean"] = r["fade"]["rmse_truth_last40"] / r["clean"]["rmse_truth_last40"]
    if not args.no_figure and len(r) == 3:
        _figure(traces, r, Path(args.figure))
        out["figure"] = str(args.figure)
    print(json.dumps(out))
    return 0


def _figure(traces: dict, rows: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    titles = {"fade_adapt": "fade at 20 s, --adapt", "fade": "fade at 20 s, monitor only", "clean": "no fade, --adapt"}
    for ax, (name, (t, truth, ref)) in zip(axes, traces.items(), strict=True):
        ax.plot(t, ref, color="0.4", lw=1, label="reference")
        ax.plot(t, lowpass(truth), color="C0", lw=1.2, label="true ΔCL (1 Hz low-pass)")
        ax.axvline(ONSET_TRACKING_S, color="C3", ls=":", lw=1)
        for d in rows[name]["departures"]:
            ax.axvline(d["t_s"] - TARE_S, color="C1", ls="--", lw=0.8)
        for a in rows[name]["adaptations"]:
            if a.get("swapped"):
                ax.axvline(a["t_s"] - TARE_S, color="C2", lw=1.5)
        ax.set_title(f"{titles[name]}: RMSE last 40 s {rows[name]['rmse_truth_last40']:.4f}", fontsize=9)
        ax.set_ylabel("ΔCL")
    axes[0].legend(fontsize=7, loc="upper left")
    axes[-1].set_xlabel("tracking time (s); red dotted: fade onset, orange dashed: departures, green: swaps")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    sys.exit(main())
