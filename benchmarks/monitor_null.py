"""The live departure monitor on clean streams: its thresholds, and its false departures per hour.

Clean streams are the simulated bench's experiments (every campaign type but the static
sweep, each repeated with the plant's state running on for ``--seconds``), with no effect,
run through the observer and the monitor sample by sample exactly as the live loop steps them
(:class:`rtlift.app.live.ObserverLoop` calls ``observer.step`` then ``monitor.step``), and with
``--independent`` the independent plant's clean records (``clean/`` and ``campaign/``,
with a model identified on its campaign by ``benchmarks.independent_plant``'s own code).

``--calibrate``: over the *calibration* seeds (``--cal-seeds``), each statistic's largest value
held for ``persist`` consecutive evaluations, times :data:`~rtlift.observer.monitor.MARGIN`, is
printed as the threshold to put into :data:`rtlift.observer.monitor.THRESHOLDS`. Without it, the
*held-out* seeds (``--seeds``, disjoint from the calibration seeds) are run with the thresholds in
force and the departures per hour printed (goal ≤ 1 per hour). Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hil_sim.experiments import BenchRun, daq_stream
from rtlift.core.programs import EXPERIMENTS
from rtlift.core.records import Record, read_record
from rtlift.model.modelfile import load_model
from rtlift.observer import Observer
from rtlift.observer.monitor import MARGIN, TESTS, DepartureMonitor, persistent_max

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "tests" / "data" / "bench_model.json"
IP_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "independent_plant"
TYPES = tuple(t for t in EXPERIMENTS if t != "static")


def bench_stream(name: str, seed: int, seconds: float, plant_draw: int = 0) -> Record:
    """``seconds`` of the bench running experiment ``name`` over and over (one tare at the start),
    on plant ``plant_draw`` of the family (0: the bench's own plant)."""
    chunks = []
    need = int(seconds)
    for chunk in daq_stream(name, seed, plant_draw=plant_draw):
        chunks.append(chunk)
        if len(chunks) >= need:
            break
    first = chunks[0]
    cat = {f: np.concatenate([getattr(c, f) for c in chunks])
           for f in ("t", "volts", "envelope_volts", "cmu", "cmu_envelope", "dcl_true", "counts", "status")}
    run = BenchRun(**cat, meta=dict(first.meta), calibration=first.calibration, fs_hz=first.fs_hz)
    return run.to_record(f"{name}_s{seed}")


def new_monitor(model, thresholds: dict | None = None, history: bool = False,
                baseline: dict | None = None) -> DepartureMonitor:
    """The model's monitor, with thresholds overridden, or a baseline run's (``--monitor FILE``),
    and every evaluation kept if asked."""
    mon = DepartureMonitor.for_model(model)
    if thresholds:
        mon.thresholds.update(thresholds)
    if baseline:
        mon.use_thresholds(baseline, "a baseline run (--monitor calibrate)")
    if history:
        mon.history = []
    return mon


REFERENCE = "steps:0.06@0,0.12@12,0.08@24,0.14@36,0.06@48,0.12@60,0.09@72,0.13@84,0.07@96,0.11@108"


def repeated(reference: str, seconds: float, period_s: float = 120.0) -> str:
    """A ``steps:`` reference repeated every ``period_s`` for ``seconds``."""
    steps = [(float(v), float(t)) for v, t in (p.split("@") for p in reference.removeprefix("steps:").split(","))]
    out = [f"{v:g}@{t + k * period_s:g}" for k in range(int(seconds // period_s) + 1) for v, t in steps]
    return "steps:" + ",".join(out)


_CONFIGS: dict[int, object] = {}


def closed_loop(model, seed: int, seconds: float, effects: tuple[str, ...] = (), reference: str = REFERENCE,
                thresholds: dict | None = None, history: bool = False, plant_draw: int = 0,
                tracking: list | None = None, on_loop=None, model_path: str | None = None) -> DepartureMonitor:
    """``rtlift control``'s closed loop on the bench (plant ``plant_draw`` of the family) in this
    process (:class:`rtlift.app.hil_tracking.InProcessTracking`: the serial wire, the converter, the
    observer loop, the controller with the gains ``rtlift control`` designs by default), the monitor
    stepped by the observer loop and told the reference's steps as ``--monitor`` is; the steps
    repeat every 120 s. ``tracking``, a list, receives the run (its ``traces()``); ``on_loop`` is
    called with the observer loop and the control loop before it runs (an ``--adapt`` adapter);
    with ``model_path`` the controller's design is cached beside the model file, as ``rtlift
    control`` caches it."""
    from firmware_io.calibration import Calibration
    from hil_sim.hil import HilStream
    from rtlift.app.commands.control import control_config
    from rtlift.app.control import LiftController
    from rtlift.app.hil_tracking import InProcessTracking
    from rtlift.app.reference import parse_reference
    from rtlift.app.watch import reference_steps

    if id(model) not in _CONFIGS:
        _CONFIGS[id(model)] = control_config(model, True, None, None, accept_warnings=True,
                                             model_path=None if model_path is None else str(model_path))[0]
    mon = new_monitor(model, thresholds, history)
    spec = repeated(reference, seconds)
    tare = max(1, int(round(Calibration().tare_seconds * model.fs_hz)))     # as ControlLoop counts it
    mon.set_steps(*reference_steps(parse_reference(spec), tare, model.fs_hz))
    ctl = LiftController(model, _CONFIGS[id(model)])
    run = InProcessTracking(model, ctl, spec, seconds, seed=seed, effects=tuple(effects), monitor=mon,
                            on_loop=on_loop)
    if plant_draw:
        run.stream = HilStream("random", seed=seed, effects=list(effects), plant_draw=plant_draw)
    run.run()
    if tracking is not None:
        tracking.append(run)
    return mon


def monitor_record(model, rec: Record, thresholds: dict | None = None, history: bool = False,
                   baseline: dict | None = None) -> DepartureMonitor:
    """The observer and the monitor over one record, as the live loop steps them."""
    obs = Observer.from_model(model)
    mon = new_monitor(model, thresholds, history, baseline)
    step, mstep = obs.step, mon.step
    for c, v, z in zip(rec.cmu.tolist(), rec.cmu_envelope.tolist(), rec.dcl.tolist(), strict=True):
        est = step(c, v, z)
        mstep(z, est.model_dcl, est.innovation, v)
    return mon


LOOP_TYPES = ("sine_k0125", "sine_k025", "random")
"""The independent plant's records with a loop's kind of input (8 Hz bursts, a moving envelope)."""


def independent_model(work: Path):
    """The independent plant's model, identified on its clean campaign as ``benchmarks.independent_plant``
    does (the same command line)."""
    from benchmarks._common import run_cli

    camp = IP_DATA / "campaign"
    path = work / "ip_model.json"
    run_cli("identify", "--static", camp / "static.csv", "--single-burst", camp / "single_burst.csv",
            "--train", camp / "sine_k0125.csv", "-o", path)
    return load_model(path)


def independent_records(work: Path, folders: tuple[str, ...] = ("clean", "campaign")):
    if not (IP_DATA / "clean").is_dir():
        return None
    model = independent_model(work)
    recs = []
    for folder in folders:
        for t in LOOP_TYPES:
            rec = read_record(IP_DATA / folder / f"{t}.csv")
            rec.name = f"ip_{folder}_{t}"
            recs.append(rec)
    return model, recs


IP_CASES = ("clean", "fade", "drift", "mains", "delay_mains", "delay", "hysteresis", "resonance")


def independent_cases(work: Path) -> dict | None:
    """What the monitor raises on each of the independent plant's cases (effects present from the
    start), with the model identified on its campaign: per case and loop-like record, the first
    departure of each test ``{t_s, test, suspect}``."""
    if not (IP_DATA / "clean").is_dir():
        return None
    model = independent_model(work)
    out: dict = {}
    for case in IP_CASES:
        for t in LOOP_TYPES:
            mon = monitor_record(model, read_record(IP_DATA / case / f"{t}.csv"))
            first: dict = {}
            for d in mon.departures:
                first.setdefault(d["test"], {"t_s": d["t_s"], "test": d["test"], "suspect": d["suspect"]})
            out.setdefault(case, {})[t] = sorted(first.values(), key=lambda d: d["t_s"])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ip-cases", action="store_true",
                    help="only: the first departures on each of the independent plant's cases")
    ap.add_argument("--calibrate", action="store_true", help="print thresholds from the calibration seeds")
    ap.add_argument("--cal-seeds", default="100,101,102", help="calibration seeds (default 100,101,102)")
    ap.add_argument("--seeds", default="200,201,202,203,204,205,206,207",
                    help="held-out seeds for the null rate (default 200–207)")
    ap.add_argument("--seconds", type=float, default=120.0, help="seconds per stream (default 120)")
    ap.add_argument("--types", default=",".join(TYPES))
    ap.add_argument("--model", default=str(MODEL))
    ap.add_argument("--closed-loop", type=float, default=0.0, metavar="S",
                    help="also a clean closed loop of S seconds per seed (in process)")
    ap.add_argument("--independent", default=None, metavar="FOLDER[,FOLDER]",
                    help="also the independent plant's clean records of these folders (calibration: campaign; "
                         "null rate: clean)")
    args = ap.parse_args(argv)
    if args.ip_cases:
        cases = independent_cases(Path(tempfile.mkdtemp(prefix="rtlift-monitor-")))
        if cases is None:
            print(f"independent plant data not found at {IP_DATA}", file=sys.stderr)
            return 1
        for case, recs in cases.items():
            print(case, "; ".join(f"{t}: " + (", ".join(f"{d['t_s']:g} s {d['test']} ({d['suspect']})" for d in ds)
                                               or "-") for t, ds in recs.items()), file=sys.stderr)
        print(json.dumps({"benchmark": "monitor_ip_cases", "cases": cases}))
        return 0
    model = load_model(args.model)
    types = args.types.split(",")
    seeds = [int(s) for s in (args.cal_seeds if args.calibrate else args.seeds).split(",")]
    t0 = time.perf_counter()
    runs = []
    streams = [(model, bench_stream(t, s, args.seconds)) for s in seeds for t in types]
    if args.independent:
        ip = independent_records(Path(tempfile.mkdtemp(prefix="rtlift-monitor-")),
                                 tuple(args.independent.split(",")))
        if ip is None:
            print(f"independent plant data not found at {IP_DATA}", file=sys.stderr)
        else:
            streams += [(ip[0], r) for r in ip[1]]
    if args.closed_loop:
        streams += [(model, ("closed_loop", s)) for s in seeds]
    for m, rec in streams:
        if isinstance(rec, tuple):
            mon = closed_loop(m, rec[1], args.closed_loop, history=args.calibrate)
            name, hours = f"closed_loop_s{rec[1]}", args.closed_loop / 3600.0
        else:
            mon = monitor_record(m, rec, history=args.calibrate)
            name, hours = rec.name, len(rec) / rec.fs_hz / 3600.0
        row = {"record": name, "hours": hours, "departures": mon.departures,
               "scale": mon.scale}
        if args.calibrate:
            row["persistent_max"] = {t: persistent_max([h[t] for h in mon.history], mon.config.persist) for t in TESTS}
        runs.append(row)
        print(json.dumps({k: row[k] for k in row if k != "departures"} | {"n_departures": len(mon.departures)}),
              flush=True)
    hours = sum(r["hours"] for r in runs)
    n_dep = sum(len(r["departures"]) for r in runs)
    out = {"benchmark": "monitor_null", "mode": "calibrate" if args.calibrate else "null",
           "seeds": seeds, "types": types, "streams": len(runs), "hours": hours, "departures": n_dep,
           "departures_per_hour": n_dep / hours if hours else math.nan,
           "by_test": {t: sum(1 for r in runs for d in r["departures"] if d["test"] == t) for t in TESTS},
           "seconds": time.perf_counter() - t0}
    if args.calibrate:
        pm = {t: max(r["persistent_max"][t] for r in runs) for t in TESTS}
        out["persistent_max"] = pm
        out["thresholds"] = {t: round(MARGIN * v, 4) for t, v in pm.items()}
        out["worst_record"] = {t: max(runs, key=lambda r: r["persistent_max"][t])["record"] for t in TESTS}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
