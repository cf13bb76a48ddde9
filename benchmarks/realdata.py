"""Real measured data: what a Wiener model lacks on the vendored measured benchmarks, every
choice frozen before the test data are read.

For each benchmark (vendored in ``rtlift/data/benchmarks/``), through the command line as a user
runs it, in two phases:

1. **Choices, on the estimation data alone** (:func:`rtlift.sysid.benchmarks.estimation`; the
   test file is not opened). One estimation run: written as a generic ``t,u,y`` record, its last
   20 % a separate validation record, which starts ``SKIP`` samples earlier (like the test
   split, it is scored after a state-initialisation window of ``SKIP`` samples, here the end of
   the training part, so that all of the last 20 % is scored). Several runs (each its own
   experiment from rest): the first 80 % of the runs (rounded) fit, the rest validate.
   ``rtlift identify --record … --structure wiener`` (every fitting run a ``--record``) and
   ``rtlift diagnose --skip 50 --init-state`` (trained on the first fitting run, judged on the
   validation records) choose the structure, its orders, knots and options. The two model files
   and the commands that made them are hashed (sha256) and the hash printed — the choices are
   frozen.
2. **Test, read now** (:func:`rtlift.sysid.benchmarks.tests`): ``rtlift validate --skip 50
   --init-state`` of both model files on each official test record (free run from the state
   estimated on the first 50 test samples, which are unscored: the rules' state-initialisation
   window; Cascaded Tanks' records start with water in the tanks).

**Simulated cases** (``benchmarks/simulated_systems.py``, issue 48: generators, not data; reporting
seed :data:`SIM_SEED`): ``ced_like`` (two experiments of 500 samples, 400 each for estimation; fewer
than five runs: each run's last 20 % validates; the test record of each is its last 100 samples
behind the 50 estimation samples before them, the unscored state-initialisation window — the
official CED rule gives 4), ``emps_like`` (a positioning system, force in, position out) and
``bouc_wen`` (the hysteretic benchmark from its specification). They go through the same two
phases; the test records are generated only in phase 2. They are not in the default list: run
them with ``--only``.

Prints a markdown table (before, after, what the diagnosis added, published references, seconds)
and, as its last line, one JSON object. ``--only NAME`` runs one benchmark. The last three
benchmarks (``silverbox_schroeder``, ``silverbox_multisine`` — the official multisine test, the one
the published 0.36 mV is on — and ``wh_process_noise``, issue 48) were never looked at while the
structures were grown; their first run is reported as it came out.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rtlift.core.records import write_siso_record
from rtlift.sysid.benchmarks import BENCHMARKS, STATE_INIT_SAMPLES, Benchmark, as_record
from rtlift.sysid.benchmarks import estimation as vendored_estimation
from rtlift.sysid.benchmarks import tests as vendored_tests

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import simulated_systems as sim  # noqa: E402
from benchmarks._common import run_cli  # noqa: E402

SIM_SEED = 101
"""The simulated cases' reporting seed (development and tests used seeds 1-5)."""
SIMULATED = {b.name: b for b in (
    Benchmark("ced_like", "", "coupled-electric-drives kind, simulated: |.| of a resonant drive, 50 Hz, 2 x 500",
              "", 1.0),
    Benchmark("emps_like", "", "positioning-system kind, simulated: force to position with friction, 1 kHz",
              "mm", 1e3),
    Benchmark("bouc_wen", "", "Bouc-Wen hysteretic benchmark simulated from its specification, 750 Hz", "um",
              1e6),
)}


def _simulated(name: str, seed: int = SIM_SEED) -> tuple[float, list, list]:
    """(fs, estimation runs, test records) of a simulated case (module docstring) at ``seed``."""
    if name == "ced_like":
        fs, est, full, _ = sim.ced_like(seed)
        return fs, est, [(f"test_{p}", u[sim.CED_ESTIMATION - SKIP:], y[sim.CED_ESTIMATION - SKIP:])
                         for p, u, y in full]
    fs, est, test = (sim.emps_like if name == "emps_like" else sim.bouc_wen)(seed)
    return fs, est, test


def estimation(name: str, seed: int = SIM_SEED) -> tuple[float, list]:
    """The estimation runs of a vendored benchmark or a simulated case."""
    if name in SIMULATED:
        fs, est, _ = _simulated(name, seed)
        return fs, est
    return vendored_estimation(name)


def tests(name: str, seed: int = SIM_SEED) -> list:
    """The test records (phase 2 only)."""
    return _simulated(name, seed)[2] if name in SIMULATED else vendored_tests(name)

SKIP = STATE_INIT_SAMPLES
VALIDATE_FRACTION = 0.2
"""The share of the estimation data (of one run, or of the runs) the diagnosis judges on."""

PUBLISHED = {"wh2009": "0.241 (SUBNET) – 0.45 (dynoNet) mV",
             "silverbox": "1.4 mV (SUBNET); 0.26 mV (PNLSS, multisine)",
             "cascaded_tanks": "0.191 V (grey box) – 0.306 V (CT SUBNET); PNLSS 0.45 V",
             "silverbox_schroeder": "none found for the Schroeder period (multisine test: 0.36 mV, SUBNET)",
             "silverbox_multisine": "0.36 mV (DT SUBNET)",
             "wh_process_noise": "none found (data README: not tabulated; unpublished OE(6): 38.1 / 23.2 mV)",
             "ced_like": "simulated: none (noise floor 0.03)",
             "emps_like": "simulated: none (measured EMPS: none found by the searches of issue 48's fifth pass)",
             "bouc_wen": "12.1 um multisine (PNLSS 3-5-7, -98.32 dB: Noel et al., arXiv 1610.09138, as tabulated in "
                         "pyvib's Bouc-Wen PNLSS example); sweep: none found"}
"""Published free-run RMSE beside each benchmark, each with its source (none where none was found)."""


def record(path: Path, fs: float, u: np.ndarray, y: np.ndarray, name: str) -> Path:
    write_siso_record(path, as_record(fs, u, y, name))
    return path


def choose(name: str, work: Path, seed: int = SIM_SEED) -> tuple[dict, dict]:
    """Phase 1 (module docstring): the model files from the estimation data alone; (files and
    commands, timings)."""
    fs, runs = estimation(name, seed)
    if len(runs) == 1:
        _, ue, ye = runs[0]
        n_fit = int(round((1 - VALIDATE_FRACTION) * ue.size))
        fit = [record(work / "est.csv", fs, ue[:n_fit], ye[:n_fit], "est")]
        val = [record(work / "val.csv", fs, ue[n_fit - SKIP:], ye[n_fit - SKIP:], "val")]
    elif len(runs) < 5:         # a few short experiments: each one's last 20 % validates
        fit, val = [], []
        for p, u, y in runs:
            n_fit = int(round((1 - VALIDATE_FRACTION) * u.size))
            fit.append(record(work / f"{p}_est.csv", fs, u[:n_fit], y[:n_fit], f"{p}_est"))
            val.append(record(work / f"{p}_val.csv", fs, u[n_fit - SKIP:], y[n_fit - SKIP:], f"{p}_val"))
    else:
        n_fit = int(round((1 - VALIDATE_FRACTION) * len(runs)))
        fit = [record(work / f"{p}.csv", fs, u, y, p) for p, u, y in runs[:n_fit]]
        val = [record(work / f"{p}.csv", fs, u, y, p) for p, u, y in runs[n_fit:]]
    identify = ["identify", *(a for f in fit for a in ("--record", f)), "--structure", "wiener",
                "-o", work / "model.json"]
    diagnose = ["diagnose", "--model", work / "model.json", "--train", fit[0], "--validate", *val, "--skip", SKIP,
                "--init-state", "--out", work / "diag"]
    t0, c0 = time.perf_counter(), _cpu()
    run_cli(*identify)
    t1, c1 = time.perf_counter(), _cpu()
    run_cli(*diagnose)
    t2, c2 = time.perf_counter(), _cpu()
    files = {"before": work / "model.json", "after": work / "diag" / "model_augmented.json"}
    return ({"files": files, "commands": [identify, diagnose]},
            {"identify_seconds": t1 - t0, "diagnose_seconds": t2 - t1,
             "identify_cpu_seconds": c1 - c0, "diagnose_cpu_seconds": c2 - c1})


def _cpu() -> float:
    """CPU seconds (user + system) of this process and of its reaped children (the forked halves)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def freeze(choices: dict, work: Path) -> str:
    """sha256 of the commands (paths relative to the work folder) and of the two model files' bytes."""
    h = hashlib.sha256()
    for cmd in choices["commands"]:
        h.update(" ".join(str(a).replace(str(work), ".") for a in cmd).encode() + b"\n")
    for which in ("before", "after"):
        h.update(choices["files"][which].read_bytes())
    return h.hexdigest()


def run(name: str, work: Path, seed: int = SIM_SEED) -> dict:
    b = SIMULATED.get(name) or BENCHMARKS[name]
    choices, seconds = choose(name, work, seed)
    frozen = freeze(choices, work)
    print(f"{name}: choices frozen before the test data are read: sha256 {frozen}", flush=True)
    rmse: dict[str, dict[str, float]] = {}
    fs, _ = estimation(name, seed)
    for label, u, y in tests(name, seed):                       # read only now
        test = record(work / f"{label}.csv", fs, u, y, label)
        for which, model in choices["files"].items():
            out = work / f"{which}_{label}.json"
            run_cli("validate", "--model", model, test, "--skip", SKIP, "--init-state", "--json", out)
            rmse.setdefault(label, {})[which] = b.scale * json.loads(out.read_text())["records"][label]["rmse"]
    report = json.loads((work / "diag" / "report.json").read_text())
    first = next(iter(rmse.values()))
    model = json.loads(choices["files"]["before"].read_text())
    return {"benchmark": name, **({"seed": seed} if name in SIMULATED else {}), "unit": b.unit,
            "before": first["before"], "after": first["after"],
            "tests": rmse, "frozen_sha256": frozen,
            "wiener": {k: model["provenance"].get(k) for k in ("bla_order", "knots", "integrating")},
            "accepted": [e["name"] for e in report["effects"] if e["accepted"]],
            "accepted_kinds": {e["name"]: e.get("kind", "structure") for e in report["effects"] if e["accepted"]},
            "accepted_forms": {e["name"]: {"model": e["params"]["model"], "where": e["params"].get("where")}
                               for e in report["effects"] if e["accepted"] and "model" in e.get("params", {})},
            "tried": [e["name"] for e in report["effects"]], "not_built": report.get("not_built", []),
            **seconds, "published": PUBLISHED[name]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=(*BENCHMARKS, *SIMULATED), action="append",
                    help="run only this benchmark (repeatable)")
    ap.add_argument("--seed", type=int, default=SIM_SEED,
                    help=f"the simulated cases' seed (default {SIM_SEED}, the reporting seed; development used "
                         "1, 4 and 5)")
    ap.add_argument("--choices-only", action="store_true",
                    help="phase 1 alone (identify + diagnose on the estimation data): the frozen hash and the "
                         "wall and CPU seconds, as one JSON line per benchmark; the test data are not read")
    args = ap.parse_args(argv)
    if args.choices_only:
        for name in (args.only or list(BENCHMARKS)):
            with tempfile.TemporaryDirectory() as tmp:
                choices, seconds = choose(name, Path(tmp), args.seed)
                print(json.dumps({"benchmark": name, "frozen_sha256": freeze(choices, Path(tmp)),
                                  "load_average": os.getloadavg(),
                                  **{k: round(v, 2) for k, v in seconds.items()}}), flush=True)
        return 0
    rows = []
    for name in (args.only or list(BENCHMARKS)):
        with tempfile.TemporaryDirectory() as tmp:
            rows.append(run(name, Path(tmp), args.seed))
    print("| benchmark | test | Wiener (before) | after diagnose | added (structure) | published | "
          "identify + diagnose | frozen (sha256) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        for label, v in r["tests"].items():
            print(f"| {r['benchmark']} | {label} | {v['before']:.3f} {r['unit']} | {v['after']:.3f} {r['unit']} | "
                  f"{', '.join(r['accepted']) or '—'} | {r['published']} | "
                  f"{r['identify_seconds']:.0f} + {r['diagnose_seconds']:.0f} s | {r['frozen_sha256'][:12]} |")
    print(json.dumps({"rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
