"""The live monitor on the plant family (issue 46): each draw's own model, its own thresholds.

For every plant draw N given (``--draws``; :mod:`hil_sim.family`: 1–49 calibration, 100–199
reporting): the standard campaign's static sweep, single burst and ``sine_k0125`` are recorded on
plant N (``rtlift bench record --plant-draw N``), a model is identified on them
(``rtlift identify``: its fingerprint carries the monitor's own print,
:mod:`rtlift.observer.monitor_print`), and ``rtlift control``'s closed loop runs in this process
(:func:`benchmarks.monitor_null.closed_loop`: the serial wire, the observer loop stepping the
monitor, the designed controller, the monitor told the reference's steps) tracking steps every
10 s for ``--seconds`` (120): once clean, once with an actuator fade to 70 % (on-time constant
2 s) from t = 20 s of tracking. Not paced: a 120 s loop takes seconds (the design, once per draw,
about a minute).

``--clean-seeds K`` runs K clean loops per draw (seeds 5000 + N, then 15000 + N, 25000 + N, ...;
``--clean-first J`` starts at 5000 + N + 10000 J);
``--adapt`` attaches ``--adapt``'s :class:`~rtlift.app.adapt.Adapter` to every loop (the window
diagnosed by ``rtlift diagnose`` in another process, niced, the augmented model swapped in at a
burst onset; a ``structure`` is reported, not swapped, as by default): while a window is being
diagnosed the loop runs on a clock (:class:`PacedAdapter`, ``--pace``: the host's, or the
diagnosis's CPU seconds), so the diagnosis takes as much of the loop's time as it would live. ``--out FILE``
appends each draw's line to FILE and skips the draws already there (a run stopped and resumed);
the totals are over every line in it. ``--fault SPEC`` adds a closed loop per draw with that bench
effect (a ``zero_drift`` of either sign: what its departures name); ``--open-loop TYPE ...`` adds
clean open-loop streams of those experiments on the draw's plant, stepped as ``rtlift observe``
steps them (no controller), and their false departures per hour (``--open-baseline``: each judged
by thresholds from a clean baseline stream of the same input, the ``--monitor calibrate`` path).

Per draw one JSON line: the model's thresholds and where they came from; per run the departures
(time on the monitor's clock, test, statistic, suspect), every evaluation's statistics (so other
thresholds can be judged on the same runs: :func:`departures_at`), the tracking RMSE on the
bench's truth over the last 40 s (low-passed at 1 Hz). Last line: the totals — false departures
in the clean runs, their hours, the rate and its 95 % Poisson upper bound; for the fades the
delay from the onset to the first departure and its name.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from benchmarks._common import run_cli
from benchmarks.monitor_null import closed_loop
from rtlift.app.adapt import Adapter
from rtlift.model.modelfile import load_model
from rtlift.observer.monitor import TESTS

STEPS = (0.06, 0.12, 0.08, 0.14, 0.06, 0.12, 0.09, 0.13, 0.07, 0.11, 0.08, 0.12)
REFERENCE = "steps:" + ",".join(f"{v:g}@{10 * i}" for i, v in enumerate(STEPS))
"""Steps every 10 s (the issue's run)."""
ONSET_TRACKING_S = 20.0
MONITOR_LEAD_S = 2.0
"""The monitor's clock starts at the end of the 1 s settle, tracking 2 s later (the tare)."""
FADE = f"actuator_fade:final_fraction=0.7,time_constant_s=2,onset_s={ONSET_TRACKING_S + 3.0:g}"
"""The bench's clock starts 3 s before tracking (1 s settle, 2 s tare)."""
CAMPAIGN = ("static", "single_burst", "sine_k0125")


def identify(draw: int, work: Path) -> Path:
    """The campaign recorded on plant ``draw`` and the model identified on it (as a user would)."""
    for name in CAMPAIGN:
        run_cli("bench", "record", name, "--out", work / f"{name}.csv", "--plant-draw", draw)
    path = work / "model.json"
    run_cli("identify", "--static", work / "static.csv", "--single-burst", work / "single_burst.csv",
            "--train", work / "sine_k0125.csv", "-o", path)
    return path


def departures_at(history: list[dict], thresholds: dict, persist: int = 2, t0_s: float = 6.0) -> list[dict]:
    """The departures a monitor with ``thresholds`` raises over an evaluation history
    (:meth:`~rtlift.observer.monitor.DepartureMonitor.judge`; evaluation i at ``t0_s`` + i s)."""
    from rtlift.observer.monitor import DepartureMonitor

    mon = DepartureMonitor(1.0)
    mon.thresholds = {t: float(thresholds.get(t) or math.inf) for t in TESTS}
    out: list[dict] = []
    mon.on_departure = out.append
    for i, stats in enumerate(history):
        mon.judge(stats, t0_s + i)
    return [{"t_s": d["t_s"], "test": d["test"]} for d in out]


class PacedAdapter(Adapter):
    """``--adapt``'s adapter in a loop that is not paced: while a window is being diagnosed
    (``busy``, until the swap or the diagnosis's end) the loop's samples are held to a clock, so
    the diagnosis takes as many of the loop's seconds as it would live. ``pace="wall"``: the
    host's clock (this machine as loaded now: the diagnosis is niced, and at a load average of 16
    it starves); ``pace="cpu"``: the CPU seconds the diagnosis has used — the worker process's and
    the adapter's thread's (``/proc``) — that is, its time on a machine that gives it a core
    (the 2-core rig with nothing but the loop, ~7 % of a core, on the other)."""

    _paced_from: tuple[int, float] | None = None
    pace = "wall"

    def _clock(self) -> float:
        if self.pace == "wall":
            return time.perf_counter()
        ticks = os.sysconf("SC_CLK_TCK")
        total = 0
        worker = getattr(self, "_worker", None)
        paths = [f"/proc/{worker.proc.pid}/stat"] if worker is not None and worker.proc is not None else []
        if self._thread is not None and self._thread.native_id is not None:
            paths.append(f"/proc/self/task/{self._thread.native_id}/stat")
        for path in paths:
            try:
                fields = Path(path).read_text().rsplit(")", 1)[1].split()
            except (OSError, IndexError):
                continue
            total += int(fields[11]) + int(fields[12])      # utime, stime
        return total / ticks

    def diagnosing(self) -> bool:
        """A window is being diagnosed or its swap prepared (not yet ready: a ready swap waits for
        the loop's next burst onset, which only the loop's own samples bring)."""
        thread = self._thread
        return self.busy and self._ready is None and thread is not None and thread.is_alive()

    def after_step(self, index: int, cmu: float, env: float, dcl: float | None) -> None:
        super().after_step(index, cmu, env, dcl)
        if not self.diagnosing():
            self._paced_from = None
            return
        if self._paced_from is None:
            self._paced_from = (index, self._clock())
            return
        due = self._paced_from[1] + (index - self._paced_from[0]) / self.fs_hz
        while self.diagnosing() and self._clock() < due:
            time.sleep(0.0025 if self.pace == "wall" else 0.01)


ADAPT_KEYS = ("event", "n", "t_s", "swapped", "accepted", "kinds", "finding", "reason", "rmse_before", "rmse_after")


def one_run(model, draw: int, seed: int, seconds: float, effects: tuple[str, ...],
            adapt_dir: Path | None = None, model_path: Path | None = None, pace: str = "wall") -> dict:
    from rtlift.app.hil_tracking import lowpass, reference_values

    runs: list = []
    adapters: list[PacedAdapter] = []

    def attach(loop, closed) -> None:
        a = PacedAdapter(loop, str(model_path), adapt_dir, closed=closed, fs_hz=model.fs_hz)
        a.pace = pace
        loop.adapter = a
        loop.monitor.on_departure = a.on_departure
        adapters.append(a)

    t0 = time.perf_counter()
    mon = closed_loop(model, seed, seconds, effects, reference=REFERENCE, history=True, plant_draw=draw,
                      tracking=runs, on_loop=attach if adapt_dir is not None else None, model_path=model_path)
    t, truth, _ = runs[0].traces()
    err = lowpass(truth) - lowpass(reference_values(REFERENCE, len(truth)))
    out = {"seed": seed, "seconds": seconds, "wall_s": time.perf_counter() - t0,
           "departures": [{k: d[k] for k in ("t_s", "test", "statistic", "threshold", "suspect", "evidence")}
                          for d in mon.departures],
           "max": {k: max((h[k] for h in mon.history), default=0.0) for k in TESTS},
           "history": [{k: round(float(h[k]), 5) for k in TESTS} for h in mon.history],
           "rmse_last40": float(np.sqrt(np.mean(err[t >= seconds - 40.0] ** 2))),
           "monitor": mon.summary()}
    if adapters:
        a = adapters[0]
        out["diagnosis_in_flight_at_end"] = a.busy
        a.close(120.0)
        out["adaptations"] = [{k: e[k] for k in ADAPT_KEYS if k in e}
                              | {"departure_t_s": (e.get("departure") or {}).get("t_s")} for e in a.adaptations]
    return out


def parse_draws(spec: str) -> list[int]:
    draws = []
    for part in spec.split(","):
        a, _, b = part.partition("-")
        draws += list(range(int(a), int(b or a) + 1))
    return draws


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", required=True, help="plant draws, e.g. 100-119 or 1,2,3")
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--work", default=None, help="keep each draw's records and model here")
    ap.add_argument("--no-fade", action="store_true")
    ap.add_argument("--clean-seeds", type=int, default=1, help="clean runs per draw (default 1)")
    ap.add_argument("--clean-first", type=int, default=0,
                    help="the first clean seed's index j (seed 5000 + N + 10000 j; default 0): more seeds later")
    ap.add_argument("--adapt", action="store_true", help="--adapt on every run (the swap measured)")
    ap.add_argument("--pace", choices=("wall", "cpu"), default="wall",
                    help="the loop's clock while a window is diagnosed (PacedAdapter; default wall)")
    ap.add_argument("--fault", action="append", default=[],
                    help="one more closed loop per draw with this bench effect (e.g. zero_drift:rate_per_s=4e-4; "
                         "seeds 7000 + N, 17000 + N, ...): what its departures name")
    ap.add_argument("--open-loop", nargs="*", default=[], metavar="TYPE",
                    help="clean open-loop streams per draw (rtlift observe's loop, no controller): random sine_k025")
    ap.add_argument("--open-seconds", type=float, default=600.0, help="each open-loop stream's length (default 600)")
    ap.add_argument("--open-seeds", type=int, default=1, help="open-loop streams of each type per draw (default 1)")
    ap.add_argument("--open-baseline", action="store_true",
                    help="judge each open-loop stream by thresholds from a clean baseline stream of the same input "
                         "(seed 9000 + N + 10000 j), as --monitor calibrate then --monitor FILE would")
    ap.add_argument("--out", default=None, help="append each draw's line here; skip the draws already there")
    args = ap.parse_args(argv)
    work = Path(args.work or tempfile.mkdtemp(prefix="rtlift-family-"))
    rows = []
    if args.out and Path(args.out).exists():
        rows = [json.loads(line) for line in Path(args.out).read_text().splitlines() if line.strip()]
        rows = [r for r in rows if "draw" in r and "error" not in r]
    done = {r["draw"] for r in rows}
    for draw in parse_draws(args.draws):
        if draw in done:
            continue
        d = work / f"draw{draw}"
        d.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        try:
            path = d / "model.json"
            if not path.exists():
                path = identify(draw, d)
            model = load_model(path)

            def run(seed: int, effects: tuple[str, ...], name: str, d=d, model=model, draw=draw,
                    path=path) -> dict:
                adapt = d / f"adapt_{name}_{seed}" if args.adapt else None
                return one_run(model, draw, seed, args.seconds, effects, adapt, path, args.pace)

            row = {"draw": draw, "model": str(path),
                   "print": {k: v for k, v in ((model.fingerprint or {}).get("monitor") or {}).items()
                             if k not in ("operating_point",)},
                   "clean": [run(5000 + draw + 10000 * j, (), "clean")
                             for j in range(args.clean_first, args.clean_first + args.clean_seeds)]}
            if not args.no_fade:
                row["fade"] = run(6000 + draw, (FADE,), "fade")
            row["faults"] = [dict(run(7000 + draw + 10000 * j, (spec,), f"fault{j}"), spec=spec)
                             for j, spec in enumerate(args.fault)]
            row["open_loop"] = [open_loop(model, draw, kind, 8000 + draw + 10000 * j, args.open_seconds,
                                          9000 + draw + 10000 * j if args.open_baseline else None)
                                for j in range(args.open_seeds) for kind in args.open_loop]
        except Exception as exc:  # noqa: BLE001 - a failed draw is listed, the others go on
            row = {"draw": draw, "error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc()[-2000:]}
        row["wall_s"] = time.perf_counter() - t0
        rows.append(row)
        line = json.dumps(row)
        print(line, flush=True)
        if args.out:
            with open(args.out, "a", encoding="utf-8") as f:
                f.write(line + "\n")
    print(json.dumps(totals(rows)), flush=True)
    return 0


def clean_runs(row: dict) -> list[dict]:
    """A draw's clean runs (one dict in lines written before ``--clean-seeds``)."""
    c = row.get("clean") or []
    return [c] if isinstance(c, dict) else list(c)


def totals(rows: list[dict]) -> dict:
    """False departures over the clean runs (rate, 95 % Poisson bound), what their window
    diagnoses accepted and swapped, and the fades' first names and swaps."""
    ok = [r for r in rows if "clean" in r]
    cleans = [c for r in ok for c in clean_runs(r)]
    n = sum(len(c["departures"]) for c in cleans)
    hours = sum(c["seconds"] for c in cleans) / 3600.0
    diag = [a for c in cleans for a in c.get("adaptations", [])]
    onset = ONSET_TRACKING_S + MONITOR_LEAD_S
    fades = []
    for r in ok:
        if "fade" not in r:
            continue
        run = r["fade"]
        deps = run["departures"]
        before = [d for d in deps if d["t_s"] <= onset]
        after = [d for d in deps if d["t_s"] > onset]
        first = after[0] if after else None
        within = [d for d in after if d["t_s"] <= onset + 10.0]
        swaps = [a for a in run.get("adaptations", []) if a.get("swapped")]
        fades.append({"draw": r["draw"], "before_onset": len(before),
                      "delay_s": None if first is None else first["t_s"] - onset,
                      "test": None if first is None else first["test"],
                      "suspect": None if first is None else first["suspect"],
                      "suspects_within_10s": sorted({d["suspect"] for d in within}),
                      "diagnoses": len(run.get("adaptations", [])),
                      "swap_s": swaps[0]["t_s"] - onset if swaps else None,
                      "swap_accepted": swaps[0].get("accepted") if swaps else None,
                      "rmse_last40_ratio": (run["rmse_last40"] / clean_runs(r)[0]["rmse_last40"]
                                            if clean_runs(r) else None)})
    named = [f for f in fades if f["suspect"] == "actuator_fade" and f["delay_s"] is not None
             and f["delay_s"] <= 10.0 and f["before_onset"] == 0]
    alone = [f for f in named if f["suspects_within_10s"] == ["actuator_fade"]]
    swapped60 = [f for f in fades if f["swap_s"] is not None and f["swap_s"] <= 60.0
                 and "actuator_fade" in (f["swap_accepted"] or [])]
    return {"benchmark": "monitor_family", "draws": [r["draw"] for r in ok],
            "failed": [r["draw"] for r in rows if "error" in r], "clean_runs": len(cleans), "clean_hours": hours,
            "false_departures": n, "per_hour": n / hours if hours else None,
            "per_hour_95_upper": poisson_upper(n) / hours if hours else None,
            "clean_diagnoses": len(diag),
            "clean_effects_accepted": sum(1 for a in diag
                                          for k in (a.get("kinds") or {}).values() if k != "structure"),
            "clean_structure_found": sum(1 for a in diag for k in (a.get("kinds") or {}).values() if k == "structure"),
            "clean_swaps": sum(1 for a in diag if a.get("swapped")),
            "fades": fades, "fade_named_within_10s": len(named), "fade_named_alone_within_10s": len(alone),
            "fade_swapped_within_60s": len(swapped60),
            "fade_ratio_le_1p3": sum(1 for f in fades if (f["rmse_last40_ratio"] or math.inf) <= 1.3),
            "fade_runs": len(fades),
            "faults": [{"draw": r["draw"], "spec": f["spec"], "named": [(d["t_s"], d["test"], d["suspect"])
                                                                        for d in f["departures"]]}
                       for r in ok for f in r.get("faults", [])],
            **open_totals([o for r in ok for o in r.get("open_loop", [])])}


def open_loop(model, draw: int, kind: str, seed: int, seconds: float, baseline_seed: int | None = None) -> dict:
    """A clean open-loop stream of plant ``draw`` (the bench running experiment ``kind`` over and
    over, ``seconds`` long, no controller) through the observer and the monitor as ``rtlift
    observe``'s loop steps them (:func:`benchmarks.monitor_null.monitor_record`): its departures.
    With ``baseline_seed``, the user's path for an input the model's print does not cover: a clean
    baseline stream of the same input (that seed) gives thresholds as ``--monitor calibrate`` does
    (:func:`rtlift.app.watch.calibration_doc`), and the measured stream is judged by them."""
    from benchmarks.monitor_null import bench_stream, monitor_record
    from rtlift.app.watch import calibration_doc

    t0 = time.perf_counter()
    baseline = None
    if baseline_seed is not None:
        # as --monitor calibrate records it: every threshold off, so the print's "outside" scaling never
        # enters the baseline's statistics (they are on σ_fp's scale, as the judged stream's)
        base = monitor_record(model, bench_stream(kind, baseline_seed, seconds, plant_draw=draw), history=True,
                              baseline=dict.fromkeys(TESTS, math.inf))
        baseline = {k: v for k, v in calibration_doc(base, "model")["thresholds"].items() if v is not None}
    mon = monitor_record(model, bench_stream(kind, seed, seconds, plant_draw=draw), history=True, baseline=baseline)
    return {"kind": kind, "seed": seed, "seconds": seconds, "wall_s": time.perf_counter() - t0,
            "baseline_seed": baseline_seed, "thresholds": dict(mon.thresholds),
            "departures": [{k: d[k] for k in ("t_s", "test", "statistic", "threshold", "suspect")}
                           for d in mon.departures],
            "max": {k: max((h[k] for h in mon.history), default=0.0) for k in TESTS},
            "input": mon.input_summary(), "input_steps": mon.input_steps}


def open_totals(runs: list[dict]) -> dict:
    """False departures over the clean open-loop streams: count, hours, rate and its 95 % bound."""
    if not runs:
        return {}
    n = sum(len(o["departures"]) for o in runs)
    hours = sum(o["seconds"] for o in runs) / 3600.0
    return {"open_runs": len(runs), "open_hours": hours, "open_false_departures": n,
            "open_per_hour": n / hours, "open_per_hour_95_upper": poisson_upper(n) / hours,
            "open_outside_print": sum(1 for o in runs if (o.get("input") or {}).get("outside_print_s") is not None)}


def poisson_upper(n: int, level: float = 0.95) -> float:
    """The one-sided ``level`` upper bound on a Poisson mean with ``n`` events seen (χ²/2)."""
    from scipy.stats import chi2

    return float(chi2.ppf(level, 2 * (n + 1)) / 2.0)


if __name__ == "__main__":
    sys.exit(main())
