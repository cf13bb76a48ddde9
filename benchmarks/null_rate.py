"""Null rate: how often the diagnosis names an effect where nothing changed.

The hybrid model is identified once on a clean standard campaign of the bench (seed 1), as in
``benchmarks/effects_table.py`` (``bench_model``). Then, for each of ``--seeds`` seeds and each
training record type (``--types``, default all four):

- ``sine_k0125``: its input repeats the identification's sine bit for bit (the exact repeat:
  the fit target is "what changed" against the identification run itself);
- ``sine_k025`` and ``random``: no repeat (``random`` draws a new envelope with each seed), so
  the reference is the input-matched or predicted print,

one clean training record is measured and diagnosed, validated on the *other two* record types
(fresh noise seeds: every diagnosis has its own three records, no record is shared between
diagnoses). The fourth type, ``closed_loop``, is one long run diagnosed alone: ``rtlift control``
tracks a reference on the simulated bench over a real pseudo-terminal for ``CLOSED_LOOP_S`` (40 s;
no effect; the bench's ``random`` experiment at the run's noise seed until the host takes over,
references alternating between the slow sine of ``tests/test_diagnose_closed_loop.py`` and the
steps of ``benchmarks/control_loop.py``), its log becomes a record through ``rtlift replay LOG
--record`` and ``rtlift diagnose --run`` fits on the first 60 % and judges on the rest — the
same path (:class:`rtlift.app.hil_tracking.BenchTracking`) as that test. Its model is identified
on the same campaign through ``rtlift identify`` (a model file with the observer settings
``rtlift control`` needs; cached at ``--model-cache`` + ``.json``). A
closed-loop run takes its 40 s in real time, and its input never repeats an identification run.

Named vs unnamed alternates over the runs (half and half, balanced per type): an *unnamed*
record is renamed ``run_a``/``run_b``/``run_c`` (a closed-loop run: ``run_a``) and loses its ``# experiment:``,
``seed``, ``effects`` and ``source`` metadata, as a user's files would. With ``--twins N`` the
first N runs are also diagnosed with the other naming on the very same records, and the two
reports' accepted entries and references are compared (the input, not the name, must decide).

With ``--trains``, both models are identified from the full campaign, burst trains included
(``identify_lift``: the interaction structure ``rtlift identify`` then chooses), as a lab that
records its campaign with ``rtlift record … campaign`` gets them (closed-loop runs excluded).

With ``--independent``, the independent plant's clean records (``clean`` and ``campaign`` folders
of ``../shared/data/independent_plant``, when present) are diagnosed too, with a model
identified on its campaign: each record type trains once, the folder's other two validate,
named and unnamed (the unnamed twin is the renaming check there; both are counted as runs).

Nothing was injected, so every accepted entry of kind ``effect`` is a false alarm; entries of
kind ``structure`` (the model's own misfit, named as such) are counted apart. The false-effect
rate is false effects per diagnosis, with a **two-sided 95 % Clopper–Pearson interval** on the
proportion of diagnoses with a false effect (scipy.stats.beta; the upper end is
``beta.ppf(0.975, k + 1, n − k)``, which is 1 − 0.025^(1/n) for k = 0). The bound counts every
diagnosis as independent; the unnamed twins of ``--twins`` re-diagnose the same records and are
left out of the count (they are a check, not more evidence; closed-loop runs have none).

Runs in parallel (``--workers``, default 2) and streams each run to ``--jsonl`` as it finishes;
``--budget`` seconds stops submitting new runs (the result then says how many ran). Prints one
line per run, the totals and, as its last line, one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

IP_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "independent_plant"
TYPES = ("sine_k0125", "sine_k025", "random")
CLOSED_LOOP = "closed_loop"
ALL_TYPES = (*TYPES, CLOSED_LOOP)
CLOSED_LOOP_S = 40
CLOSED_LOOP_REFERENCES = ("sine:mean=0.1,amp=0.05,hz=0.2", "steps:0.06@0,0.12@5,0.16@10,0.08@15")
USER_META = ("experiment", "seed", "effects", "source")

TRAINS = ("train_T1p75", "train_T3p5", "train_T7")

_MODELS: dict[tuple[str, bool], object] = {}


def accepted(report: dict, kind: str) -> list[str]:
    return [e["name"] for e in report["effects"] if e["accepted"] and e["kind"] == kind]


def unnamed(rec, name: str):
    """``rec`` as a user's file would carry it: another name, no experiment metadata."""
    import dataclasses

    return dataclasses.replace(rec, name=name, meta={k: v for k, v in rec.meta.items() if k not in USER_META})


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided exact (Clopper–Pearson) interval for k successes in n trials."""
    from scipy.stats import beta

    a = (1.0 - level) / 2.0
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - a, k + 1, n - k))
    return lo, hi


def _identified(campaign: dict, trains: bool):
    """The model ``rtlift identify`` gives on a campaign ({name: Record}): the paper's hybrid from
    static, single burst and sine k = 0.125, or with ``trains`` the full campaign's (its choice,
    the interaction structure)."""
    from rtlift.identify.choice import identify_lift

    return identify_lift(campaign["static"], campaign["single_burst"],
                         [campaign[t] for t in TRAINS] if trains else [], campaign["sine_k0125"])[0].model


def _model(key: str, cache: str | None, trains: bool = False):
    """The bench's model (``key`` "bench": its clean campaign, seed 1) or the independent plant's
    (``key`` its folder: its ``campaign/``), pickled at ``cache`` (+ ".independent", + ".trains")."""
    if (key, trains) in _MODELS:
        return _MODELS[key, trains]
    suffix = ("" if key == "bench" else ".independent") + (".trains" if trains else "")
    path = Path(cache + suffix) if cache else None
    if path is not None and path.exists():
        model = pickle.loads(path.read_bytes())
    else:
        if key == "bench" and not trains:
            from benchmarks.effects_table import bench_model

            model = bench_model()
        elif key == "bench":
            from hil_sim.experiments import run_experiment

            names = ("static", "single_burst", "sine_k0125", *(TRAINS if trains else ()))
            model = _identified({n: run_experiment(n, seed=1).to_record(n) for n in names}, trains)
        else:
            from rtlift.core.records import read_record

            camp = Path(key) / "campaign"
            model = _identified({p.stem: read_record(p) for p in camp.glob("*.csv")}, trains)
        if path is not None:
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_bytes(pickle.dumps(model))
            tmp.replace(path)
    _MODELS[key, trains] = model
    return model


def _summary(report: dict) -> dict:
    refs = {name: {k: v for k, v in ref.items() if k in ("source", "key", "nearest", "distance")}
            for name, ref in report["references"].items()}
    return {"effects": accepted(report, "effect"), "structure": accepted(report, "structure"),
            "references": refs, "fit_target": report["fit_target"]}


def bench_job(job: dict, cache: str | None) -> dict:
    """One clean bench diagnosis (and its twin with the other naming, if asked)."""
    from hil_sim.experiments import run_experiment
    from rtlift.diagnose import diagnose

    t0 = time.perf_counter()
    model = _model("bench", cache, job.get("trains", False))
    ttype, seeds = job["train"], job["noise_seeds"]
    others = [t for t in TYPES if t != ttype]
    recs = [run_experiment(n, seed=s).to_record() for n, s in zip([ttype, *others], seeds, strict=True)]

    def named_as(naming: str):
        if naming == "named":
            return recs
        return [unnamed(r, f"run_{c}") for r, c in zip(recs, "abc", strict=True)]

    out = dict(job)
    rs = named_as(job["naming"])
    out.update(_summary(diagnose(model, rs[0], rs[1:]).report))
    if job.get("twin"):
        other = "unnamed" if job["naming"] == "named" else "named"
        rs = named_as(other)
        tw = _summary(diagnose(model, rs[0], rs[1:]).report)
        same_refs = [(v["source"], v.get("key")) for v in out["references"].values()] == \
                    [(v["source"], v.get("key")) for v in tw["references"].values()]
        out["twin"] = {"naming": other, "effects": tw["effects"], "structure": tw["structure"],
                       "same": tw["effects"] == out["effects"] and tw["structure"] == out["structure"]
                       and same_refs}
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def model_file(cache: str | None, workdir: Path) -> str:
    """The bench model as a model file with its observer settings (``rtlift control`` needs
    them): ``rtlift identify`` on the same clean campaign as :func:`_model` (seed 1), as a user
    would make it; at ``--model-cache`` + ``.json``, written once (without a cache, in ``workdir``)."""
    import contextlib
    import io
    import tempfile

    from hil_sim.experiments import run_experiment
    from rtlift.app.cli import main
    from rtlift.core.records import write_record

    path = Path(cache + ".json") if cache else workdir / "bench_model.json"
    if path.exists():
        return str(path)
    with tempfile.TemporaryDirectory(prefix="null_rate_id_") as tmp:
        files = {}
        for n in ("static", "single_burst", "sine_k0125"):
            files[n] = str(Path(tmp) / f"{n}.csv")
            write_record(files[n], run_experiment(n, seed=1).to_record())
        out = Path(tmp) / "model.json"
        said = io.StringIO()
        with contextlib.redirect_stdout(said):
            code = main(["identify", "--static", files["static"], "--single-burst", files["single_burst"],
                         "--train", files["sine_k0125"], "--out", str(out)])
        if code != 0:
            raise RuntimeError(f"rtlift identify exited {code}: {said.getvalue()[-300:]}")
        tmp_path = path.with_suffix(f".{os.getpid()}.tmp")
        tmp_path.write_bytes(out.read_bytes())
        tmp_path.replace(path)
    return str(path)


def closed_loop_job(job: dict, cache: str | None) -> dict:
    """One clean closed-loop run on the bench, its log as a record, diagnosed as one run (``--run``)."""
    import contextlib
    import io
    import tempfile

    from rtlift.app.cli import main
    from rtlift.app.hil_tracking import BenchTracking
    from rtlift.core.records import read_record, write_record

    t0 = time.perf_counter()
    out = dict(job)
    with tempfile.TemporaryDirectory(prefix="null_rate_cl_") as tmp:
        d = Path(tmp)
        model = model_file(cache, d)
        run = BenchTracking(model, job["reference"], True, CLOSED_LOOP_S, str(d / "loop.json"),
                            seed=job["noise_seeds"][0], effects=(), log=str(d / "loop.bin"))
        run.start()
        loop = run.finish()
        said = io.StringIO()
        with contextlib.redirect_stdout(said):
            run.record(str(d / "closed_loop.csv"))
            path = d / "closed_loop.csv"
            if job["naming"] == "unnamed":
                path = d / "run_a.csv"
                write_record(path, unnamed(read_record(d / "closed_loop.csv"), "run_a"))
            code = main(["diagnose", "--model", model, "--run", str(path), "--out", str(d / "diag")])
        if code != 0:
            raise RuntimeError(f"rtlift diagnose --run exited {code}: {said.getvalue()[-300:]}")
        out.update(_summary(json.loads((d / "diag" / "report.json").read_text())))
        out["loop"] = {k: loop[k] for k in ("rmse_truth", "lost", "received", "saturated_fraction")}
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def independent_job(job: dict, cache: str | None) -> dict:
    from rtlift.core.records import read_record
    from rtlift.diagnose import diagnose

    t0 = time.perf_counter()
    data = Path(job["data"])
    model = _model(str(data), cache, job.get("trains", False))
    folder = data / job["folder"]
    others = [t for t in TYPES if t != job["train"]]
    recs = [read_record(folder / f"{n}.csv") for n in (job["train"], *others)]
    if job["naming"] == "unnamed":
        recs = [unnamed(r, f"run_{c}") for r, c in zip(recs, "abc", strict=True)]
    out = dict(job)
    out.update(_summary(diagnose(model, recs[0], recs[1:]).report))
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def _run(job: dict, cache: str | None) -> dict:
    try:
        os.nice(5)
    except OSError:
        pass
    if job["plant"] == "independent":
        return independent_job(job, cache)
    return (closed_loop_job if job["train"] == CLOSED_LOOP else bench_job)(job, cache)


def plan(seeds: int, first: int, types: list[str], twins: int, independent: Path | None) -> list[dict]:
    """The runs, seed by seed (a run stopped early leaves a balanced sample)."""
    jobs: list[dict] = []
    j = 0
    for s in range(first, first + seeds):
        for ti, ttype in enumerate(types):
            base = 3 * first + 3 * j          # every diagnosis its own three noise seeds
            job = {"plant": "bench", "seed": s, "train": ttype, "naming": "named" if (s + ti) % 2 == 0 else "unnamed",
                   "noise_seeds": [base, base + 1, base + 2], "twin": j < twins and ttype != CLOSED_LOOP}
            if ttype == CLOSED_LOOP:       # one run, one seed; references alternate by seed pairs (not with naming)
                job["noise_seeds"] = [base]
                job["reference"] = CLOSED_LOOP_REFERENCES[(s // 2) % len(CLOSED_LOOP_REFERENCES)]
            jobs.append(job)
            j += 1
    if independent is not None:
        ip = [{"plant": "independent", "data": str(independent), "seed": f"{folder}/{ttype}", "folder": folder,
               "train": ttype, "naming": naming}
              for folder in ("clean", "campaign") if (independent / folder / "random.csv").exists()
              for ttype in TYPES for naming in ("named", "unnamed")]
        # interleaved early, so that a budget-stopped run still has them
        for k, job in enumerate(ip):
            jobs.insert(min(len(jobs), 2 + 4 * k), job)
    return jobs


def summarize(runs: list[dict], planned: int | None, seconds: float, failed: list[dict] | None = None) -> None:
    """The totals, per-group counts with each group's own upper bound, and the last-line JSON
    (``planned`` None: runs pooled from several plans' files). ``failed``: runs that raised
    (a bench that could not be run, not a diagnosis): listed, not counted among the diagnoses."""
    failed = failed or []
    n = len(runs)
    false = sum(len(r["effects"]) for r in runs)
    hit = sum(bool(r["effects"]) for r in runs)
    structure = sum(len(r["structure"]) for r in runs)
    lo, hi = clopper_pearson(hit, n) if n else (0.0, 1.0)
    twins = [r["twin"] for r in runs if r.get("twin")]
    by: dict[str, dict] = {}
    for r in runs:
        for key in (f"{r['plant']}:{r['train']}", f"{r['plant']}:{r['naming']}"):
            b = by.setdefault(key, {"runs": 0, "false_effects": 0, "runs_with_false_effect": 0, "structure": 0})
            b["runs"] += 1
            b["false_effects"] += len(r["effects"])
            b["runs_with_false_effect"] += bool(r["effects"])
            b["structure"] += len(r["structure"])
    for b in by.values():
        b["upper_95"] = clopper_pearson(b["runs_with_false_effect"], b["runs"])[1]
    how = ("pooled from several files" if planned is None
           else f"{planned - n - len(failed)} planned runs not run, {len(failed)} failed")
    print(f"\n{n} clean diagnoses ({how}): {hit} with an accepted effect "
          f"({false} false effects in all, {false / max(n, 1):.2%} per diagnosis; two-sided 95 % Clopper-Pearson "
          f"interval on the share of diagnoses with one: {lo:.2%} to {hi:.2%}); "
          f"{sum(bool(r['structure']) for r in runs)} with a structure entry ({structure} in all)")
    if twins:
        print(f"renaming check: {sum(t['same'] for t in twins)} of {len(twins)} twin diagnoses on the same records "
              f"accept the same entries from the same references")
    for key, b in sorted(by.items()):
        print(f"  {key:<28} {b['runs']:>4} runs  {b['false_effects']:>3} false effects "
              f"({b['false_effects'] / b['runs']:.2%} per diagnosis, 95 % upper bound {b['upper_95']:.1%})  "
              f"{b['structure']:>3} structure")
    print(json.dumps({"runs": runs, "clean_runs": n, "runs_with_false_effect": hit, "false_effects": false,
                      "structure_entries": structure, "runs_with_structure": sum(bool(r["structure"]) for r in runs),
                      "false_effect_rate": false / n if n else None, "upper_95": hi, "lower_95": lo,
                      "interval": "two-sided 95 % Clopper-Pearson on runs_with_false_effect / clean_runs",
                      "planned_runs": planned, "twins_same": sum(t["same"] for t in twins), "twins": len(twins),
                      "by": by, "failed_runs": failed, "seconds": round(seconds, 1)}))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50, help="seeds; one diagnosis per seed and training type "
                    "(default 50: 200 bench diagnoses, 50 of them closed-loop runs)")
    ap.add_argument("--first-seed", type=int, default=200)
    ap.add_argument("--types", default=",".join(ALL_TYPES),
                    help=f"training record types (default {','.join(ALL_TYPES)})")
    ap.add_argument("--twins", type=int, default=6, help="first N runs also diagnosed with the other naming "
                    "on the same records (default 6)")
    ap.add_argument("--independent", action="store_true", help="also the independent plant's clean records")
    ap.add_argument("--trains", action="store_true", help="models identified from the full campaign, burst trains "
                    "included (the interaction structure rtlift identify then chooses)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--budget", type=float, default=None, help="seconds after which no new run starts")
    ap.add_argument("--model-cache", default=None, help="pickle of the bench model (written if absent)")
    ap.add_argument("--jsonl", default=None, help="append each finished run to this file")
    ap.add_argument("--skip", type=int, default=0, help="start at the plan's run N (continue a budget-stopped run "
                    "with the same options and --jsonl)")
    ap.add_argument("--summarize", nargs="+", default=None, help="only the totals of the runs saved in these --jsonl "
                    "files (pooled; with one file, the plan given by the other options sets planned_runs)")
    args = ap.parse_args(argv)
    types = [t.strip() for t in args.types.split(",") if t.strip()]
    if args.seeds < 0 or args.workers < 1 or not types or any(t not in ALL_TYPES for t in types):
        print("--seeds must be >= 0, --workers >= 1, --types among " + ", ".join(ALL_TYPES), file=sys.stderr)
        return 2
    if args.trains and CLOSED_LOOP in types:
        print("--trains: the closed-loop runs identify through rtlift identify without trains; "
              "leave closed_loop out of --types", file=sys.stderr)
        return 2
    if args.independent and not (IP_DATA / "campaign" / "static.csv").exists():
        print(f"no independent plant data at {IP_DATA}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    jobs = plan(args.seeds, args.first_seed, types, args.twins, IP_DATA if args.independent else None)
    for job in jobs:
        job["trains"] = args.trains
    if args.summarize:
        runs = [json.loads(line) for f in args.summarize for line in Path(f).read_text().splitlines() if line.strip()]
        summarize(runs, len(jobs) if len(args.summarize) == 1 else None,
                  sum(r.get("seconds", 0.0) for r in runs) / max(args.workers, 1))
        return 0
    jobs = jobs[args.skip:]
    if args.model_cache and any(j["plant"] == "bench" for j in jobs):
        _model("bench", args.model_cache, args.trains)          # once, before the workers start
    if args.model_cache and any(j.get("train") == CLOSED_LOOP for j in jobs):
        model_file(args.model_cache, Path("."))   # once, before the workers start
    if args.model_cache and args.independent:
        _model(str(IP_DATA), args.model_cache, args.trains)
    runs: list[dict] = []
    failed: list[dict] = []
    sink = open(args.jsonl, "a") if args.jsonl else None
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        pending: dict = {}
        queue = list(jobs)
        while queue or pending:
            while queue and len(pending) < args.workers and \
                    (args.budget is None or time.perf_counter() - t0 < args.budget):
                job = queue.pop(0)
                pending[pool.submit(_run, job, args.model_cache)] = job
            if not pending:
                break
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                job = pending.pop(f)
                try:
                    r = f.result()
                except Exception as exc:  # noqa: BLE001 - one failed run is reported, the others go on
                    failed.append({**job, "error": f"{type(exc).__name__}: {exc}"[-400:]})
                    print(f"{job['plant']:<11} {str(job['seed']):<22} {job['train']:<10} {job['naming']:<7} "
                          f"FAILED: {failed[-1]['error']}", flush=True)
                    continue
                runs.append(r)
                tw = r.get("twin")
                print(f"{r['plant']:<11} {str(r['seed']):<22} {r['train']:<10} {r['naming']:<7} "
                      f"effects: {', '.join(r['effects']) or '—':<24} structure: {', '.join(r['structure']) or '—'}"
                      + (f"  [twin {tw['naming']}: {'same' if tw['same'] else 'DIFFERENT'}]" if tw else ""),
                      flush=True)
                if sink:
                    sink.write(json.dumps(r) + "\n")
                    sink.flush()
    if sink:
        sink.close()
    summarize(runs, len(jobs), time.perf_counter() - t0, failed)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
