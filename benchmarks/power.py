"""Power: how large an effect must be for the diagnosis to name it, on a 16 s and a 60 s record.

The hybrid model is identified once on the bench's clean standard campaign (seed 1, as
``benchmarks/effects_table.py``'s ``bench_model``). For every effect of the catalog and each of
a few sizes spanning its documented range (``rtlift.effects.SCHEMAS``; the other parameters
at their defaults), the bench measures, with the effect, a ``random`` record (the training
record: it repeats no identification input, as a user's run would) and a ``sine_k0125`` and a
``sine_k025`` record (the validation records), each at its own noise seed. The training record
is used at two lengths:

- **60 s**: the whole ``random`` experiment (2 s tare + 58 s program; the bench has no duration
  option, and 60 s is what the experiment is);
- **16 s**: its first 16 s (2 s tare + 14 s of program). The bench is causal, so this is the run
  a user stopping after 16 s would have recorded; nothing is concatenated.

Both lengths use the same runs (paired) and the same validation records. An effect is
*detected* when it is accepted with kind ``effect`` under its own name. Per point
(effect, size, length) the detection rate over ``--seeds`` noise seeds is printed, with what was
accepted instead where it was not detected; ``--figure`` (default ``docs/figures/power.png``)
plots detection rate against size, one panel per effect, both lengths.

``--quick``: the smallest and the largest size, one seed. Runs in parallel (``--workers``,
default 2), streams every diagnosis to ``--jsonl``; ``--budget`` seconds stops submitting;
``--replot FILE.jsonl`` only redraws the figure and the table from saved runs.
Prints the table and, as its last line, one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from benchmarks.null_rate import _model

FIGURE = Path(__file__).resolve().parents[1] / "docs" / "figures" / "power.png"
LENGTHS_S = (16.0, 60.0)

# the parameter varied per effect (the others at their defaults), its sizes across the
# documented range (from barely visible to clear), and the axis label
SIZES: dict[str, tuple[str, list[float], str]] = {
    "delay": ("seconds", [0.005, 0.015, 0.04, 0.1], "delay (s)"),
    "sensor_resonance": ("damping_ratio", [0.3, 0.15, 0.05, 0.02], "damping ratio at 30 Hz (smaller = stronger)"),
    "actuator_fade": ("final_fraction", [0.9, 0.8, 0.6, 0.4], "final fraction, τ 3 s (smaller = stronger)"),
    "zero_drift": ("rate_per_s", [2e-4, 4e-4, 8e-4, 1.5e-3], "drift rate (ΔCL/s)"),
    "periodic_disturbance": ("amplitude", [0.002, 0.005, 0.01, 0.02], "amplitude at 20 Hz (ΔCL)"),
    "hysteresis": ("magnitude", [0.05, 0.1, 0.2, 0.3], "magnitude"),
}


def effect_spec(name: str, size: float) -> str:
    from rtlift.effects import SCHEMAS

    params = dict(SCHEMAS[name].defaults)
    params[SIZES[name][0]] = size
    return name + ":" + ",".join(f"{k}={v:g}" for k, v in params.items())


def job_run(job: dict, cache: str | None) -> list[dict]:
    """One run of the bench with the effect, diagnosed at both training lengths."""
    from hil_sim.experiments import run_experiment
    from rtlift.diagnose import diagnose

    try:
        os.nice(5)
    except OSError:
        pass
    model = _model("bench", cache)
    spec = job["spec"]
    s = job["noise_seeds"]
    train = run_experiment("random", seed=s[0], effects=[spec]).to_record(name="train")
    val = [run_experiment(n, seed=k, effects=[spec]).to_record(name=f"val_{n}")
           for n, k in zip(("sine_k0125", "sine_k025"), s[1:], strict=True)]
    out = []
    for length in job["lengths"]:
        t0 = time.perf_counter()
        n = min(len(train), int(round(length * train.fs_hz)))
        rec = train if n == len(train) else train.slice(0, n)
        report = diagnose(model, rec, val).report
        acc = [(e["name"], e["kind"]) for e in report["effects"] if e["accepted"]]
        entry = next((e for e in report["effects"] if e["name"] == job["effect"]), {})
        out.append({**{k: v for k, v in job.items() if k != "lengths"}, "length_s": length,
                    "train_seconds": round(n / train.fs_hz, 2),
                    "detected": (job["effect"], "effect") in acc,
                    "accepted": [f"{a} ({k})" for a, k in acc],
                    "named_unexplained": any(job["effect"] in u for u in report["unexplained"]),
                    "params_estimated": entry.get("params"),
                    "seconds": round(time.perf_counter() - t0, 1)})
    return out


def plan(effects: list[str], size_idx: list[int] | None, seeds: int, first: int, lengths: list[float]) -> list[dict]:
    """Size by size across effects (a budget-stopped run keeps every effect), seeds innermost last."""
    jobs = []
    j = 0
    points = [(rep, name, size) for rep in range(seeds) for name in effects
              for i, size in enumerate(SIZES[name][1]) if size_idx is None or i in size_idx]
    for rep, name, size in points:
        base = first + 3 * j
        jobs.append({"effect": name, "param": SIZES[name][0], "size": size, "spec": effect_spec(name, size),
                     "rep": rep, "noise_seeds": [base, base + 1, base + 2], "lengths": lengths})
        j += 1
    return jobs


def table(rows: list[dict]) -> dict:
    pts: dict[str, dict] = {}
    for r in rows:
        key = f"{r['effect']}|{r['size']:g}|{r['length_s']:g}"
        p = pts.setdefault(key, {"effect": r["effect"], "param": r["param"], "size": r["size"],
                                 "length_s": r["length_s"], "n": 0, "detected": 0, "other": []})
        p["n"] += 1
        p["detected"] += bool(r["detected"])
        if not r["detected"]:
            p["other"].append(", ".join(r["accepted"]) or "nothing")
    for p in pts.values():
        p["rate"] = p["detected"] / p["n"]
    return pts


def figure(pts: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(SIZES)
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.8), constrained_layout=True)
    for ax, name in zip(axes.ravel(), names, strict=True):
        param, sizes, label = SIZES[name]
        for length, style in zip(LENGTHS_S, ("o--", "s-"), strict=True):
            p = sorted((q for q in pts.values() if q["effect"] == name and q["length_s"] == length),
                       key=lambda q: q["size"])
            if not p:
                continue
            ax.plot([q["size"] for q in p], [q["rate"] for q in p], style, label=f"{length:g} s training record")
            for q in p:
                ax.annotate(f"{q['detected']}/{q['n']}", (q["size"], q["rate"]), textcoords="offset points",
                            xytext=(0, 6 if length == LENGTHS_S[1] else -12), ha="center", fontsize=7)
        ax.set_title(name)
        if name in ("delay", "zero_drift", "periodic_disturbance"):
            ax.set_xscale("log")
            ax.minorticks_off()
        ax.set_xlabel(label)
        ax.set_ylim(-0.1, 1.1)
        ax.set_xticks(sizes)
        ax.set_xticklabels([f"{s:g}" for s in sizes], fontsize=7)
        if name in ("sensor_resonance", "actuator_fade"):
            ax.invert_xaxis()
        ax.grid(alpha=0.3)
        ax.set_ylabel("detection rate")
    axes.ravel()[0].legend(fontsize=8, loc="center right")
    fig.suptitle("rtlift diagnose: effect named and accepted vs effect size (simulated bench; training on the "
                 "random experiment, validation on sine_k0125 + sine_k025; n per point annotated)", fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(rows: list[dict], fig_path: Path | None, extra: dict) -> None:
    pts = table(rows)
    print("| effect | parameter | size | 16 s record | 60 s record | accepted instead (misses) |")
    print("|---|---|---|---|---|---|")
    for name in SIZES:
        for size in SIZES[name][1]:
            cells = [pts.get(f"{name}|{size:g}|{length:g}") for length in LENGTHS_S]
            if not any(cells):
                continue
            fmt = ["–" if c is None else f"{c['detected']}/{c['n']}" for c in cells]
            other = "; ".join(f"{length:g} s: " + " / ".join(c["other"]) for length, c in zip(LENGTHS_S, cells,
                              strict=True) if c and c["other"])
            print(f"| {name} | {SIZES[name][0]} | {size:g} | {fmt[0]} | {fmt[1]} | {other or '—'} |")
    if fig_path is not None and pts:
        figure(pts, fig_path)
        print(f"figure: {fig_path}")
    print(json.dumps({"points": list(pts.values()), "runs": rows, **extra}, default=float))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smallest and largest size, one seed")
    ap.add_argument("--seeds", type=int, default=3, help="noise seeds per point (default 3)")
    ap.add_argument("--first-seed", type=int, default=5000)
    ap.add_argument("--effects", default=",".join(SIZES))
    ap.add_argument("--sizes", default=None, help="indices into each effect's sizes, e.g. 0,3")
    ap.add_argument("--lengths", default="16,60", help="training lengths in s (default 16,60)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--budget", type=float, default=None, help="seconds after which no new run starts")
    ap.add_argument("--model-cache", default=None)
    ap.add_argument("--jsonl", default=None)
    ap.add_argument("--figure", default=str(FIGURE))
    ap.add_argument("--no-figure", action="store_true")
    ap.add_argument("--replot", default=None, help="table and figure from a saved --jsonl only")
    args = ap.parse_args(argv)
    fig_path = None if args.no_figure else Path(args.figure)
    if args.replot:
        rows = [json.loads(line) for line in Path(args.replot).read_text().splitlines() if line.strip()]
        report(rows, fig_path, {"replotted_from": args.replot})
        return 0
    effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    if any(e not in SIZES for e in effects):
        print(f"--effects among {', '.join(SIZES)}", file=sys.stderr)
        return 2
    seeds = 1 if args.quick else args.seeds
    idx = [0, 3] if args.quick else ([int(i) for i in args.sizes.split(",")] if args.sizes else None)
    lengths = [float(x) for x in args.lengths.split(",")]
    t0 = time.perf_counter()
    jobs = plan(effects, idx, seeds, args.first_seed, lengths)
    if args.model_cache and not Path(args.model_cache).exists():
        _model("bench", args.model_cache)
    rows: list[dict] = []
    sink = open(args.jsonl, "a") if args.jsonl else None
    started = 0
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        pending: set = set()
        queue = list(jobs)
        while queue or pending:
            while queue and len(pending) < args.workers and \
                    (args.budget is None or time.perf_counter() - t0 < args.budget):
                pending.add(pool.submit(job_run, queue.pop(0), args.model_cache))
                started += 1
            if not pending:
                break
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                for r in f.result():
                    rows.append(r)
                    print(f"{r['effect']:<21} {r['param']}={r['size']:<8g} {r['length_s']:>4g} s seed {r['rep']}: "
                          f"{'DETECTED' if r['detected'] else 'missed  '} accepted: {', '.join(r['accepted']) or '—'}",
                          flush=True)
                    if sink:
                        sink.write(json.dumps(r, default=float) + "\n")
                        sink.flush()
    if sink:
        sink.close()
    report(rows, fig_path, {"planned_runs": len(jobs), "runs_started": started, "seeds_per_point": seeds,
                            "seconds": round(time.perf_counter() - t0, 1)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
