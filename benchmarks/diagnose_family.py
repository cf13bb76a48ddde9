"""Diagnosis on the plant family (issue 45): the null rate and the power at the grid's middle size,
on plants nobody chose from.

    python -m benchmarks.diagnose_family [--draws 100-119] [--reps 5] [--out FILE.jsonl]
                                         [--only null|power] [--serial | --scheduler ADDRESS] [--workers 2]

For each plant draw N (default: the first 20 reporting draws): the paper's hybrid is identified
on the draw's clean campaign recorded with seed 0 (static, single burst, sine_k0125: what
``rtlift identify`` gives without trains, as :mod:`benchmarks.null_rate` does on our bench). Then
every diagnosis measures its own three records of the same draw, each at its own noise seed, in
one of two forms:

- ``development``: named records as ``rtlift bench record`` writes them; trained on
  ``sine_k0125`` (its input repeats the identification run's), validated on ``sine_k025`` and
  ``random``;
- ``user``: the records renamed ``run_a``/``run_b``/``run_c`` without experiment metadata, as a
  user's files; trained on ``random`` (no repeat), validated on ``sine_k0125`` and ``sine_k025``.

Tasks:

- **null** (``--reps`` per draw and form): nothing injected; an accepted entry of kind
  ``effect`` is a false alarm. The rate is the share of diagnoses with one, with its two-sided
  95 % Clopper–Pearson interval (:func:`benchmarks.null_rate.clopper_pearson`);
- **power**: every effect of :data:`benchmarks.power.SIZES` injected at the grid's middle size
  (``sizes[len(sizes) // 2]``: delay 0.04 s, damping 0.05, fade to 0.6, drift 8e-4 ΔCL/s,
  pickup 0.01, hysteresis 0.2), the other parameters at their defaults, in all three records;
  named right = accepted under its own name as an ``effect``. Each draw gets every effect once,
  the forms alternating along the draws (effect j of draw N in form (N + j) mod 2), so each
  effect is tried in each form on half the draws.

Tasks are ordered so that a run stopped early is balanced (draws interleaved within each
repetition, null and power alternating); they run on :func:`benchmarks.family.run_tasks`
(Dask ``LocalCluster`` by default, ``--scheduler``, ``--serial``), each result appended to
``--out`` as it arrives and a restarted run resumes. A draw's model is identified by the first
task that needs it and pickled in ``--models`` (default beside ``--out``). No threshold is
read from, or set by, these runs. The last line is one JSON object (the summary).
"""

from __future__ import annotations

import argparse
import os
import pickle
from pathlib import Path

from benchmarks._common import emit
from benchmarks.family import add_run_options, parse_draws, run_tasks

FORMS = ("development", "user")
TRAIN = {"development": ("sine_k0125", "sine_k025", "random"), "user": ("random", "sine_k0125", "sine_k025")}
DEFAULT_DRAWS = 20
FIRST_NOISE_SEED = 7000


def middle_size(effect: str) -> float:
    """The power grid's middle size of ``effect`` (:data:`benchmarks.power.SIZES`)."""
    from benchmarks.power import SIZES

    sizes = SIZES[effect][1]
    return sizes[len(sizes) // 2]


def draw_model(draw: int, models: str):
    """The paper's hybrid identified on plant ``draw``'s clean campaign (seed 0), pickled in ``models``."""
    from benchmarks.null_rate import _identified
    from hil_sim.experiments import run_experiment

    path = Path(models) / f"draw{draw}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    campaign = {n: run_experiment(n, seed=0, plant_draw=draw).to_record(n)
                for n in ("static", "single_burst", "sine_k0125")}
    model = _identified(campaign, False)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_bytes(pickle.dumps(model))
    tmp.replace(path)
    return model


def diagnose_task(kind: str, draw: int, rep: int, form: str, effect: str, seed: int, models: str) -> dict:
    """One diagnosis on plant ``draw`` (module docstring); ``effect`` "" for a null task."""
    from benchmarks.null_rate import _summary, unnamed
    from benchmarks.power import effect_spec
    from hil_sim.experiments import run_experiment
    from rtlift.diagnose import diagnose

    model = draw_model(draw, models)
    effects = [effect_spec(effect, middle_size(effect))] if effect else []
    recs = [run_experiment(n, seed=seed + i, effects=effects, plant_draw=draw).to_record(n)
            for i, n in enumerate(TRAIN[form])]
    if form == "user":
        recs = [unnamed(r, f"run_{c}") for r, c in zip(recs, "abc", strict=True)]
    out = _summary(diagnose(model, recs[0], recs[1:]).report)
    if effect:
        out["detected"] = effect in out["effects"]
    return out


def plan(draws: list[int], reps: int, only: str | None, models: str) -> list[tuple]:
    """Null and power tasks interleaved: repetition by repetition, draw by draw, form by form."""
    from benchmarks.power import SIZES

    effects = list(SIZES)
    tasks: list[tuple] = []
    seed = FIRST_NOISE_SEED
    for rep in range(max(reps, 1)):
        for draw in draws:
            for form in FORMS:
                if only != "power" and rep < reps:
                    tasks.append(("null", draw, rep, form, "", seed, models))
                seed += 3
                if only != "null":      # one effect per (rep, draw, form): the grid fills over repetitions
                    k = (rep * len(FORMS) + FORMS.index(form) + draw) % len(effects)
                    if rep < len(effects) // len(FORMS):
                        tasks.append(("power", draw, rep, form, effects[k], seed, models))
                    seed += 3
    return tasks


def summarise(tasks: list[tuple], results: list[dict | None]) -> dict:
    from benchmarks.null_rate import clopper_pearson

    out: dict = {"null": {}, "power": {}}
    for form in FORMS:
        null = [r for t, r in zip(tasks, results, strict=True) if r is not None and t[0] == "null" and t[3] == form]
        k = sum(bool(r["effects"]) for r in null)
        lo, hi = clopper_pearson(k, len(null)) if null else (0.0, 1.0)
        out["null"][form] = {"diagnoses": len(null), "with_false_effect": k, "rate": k / len(null) if null else None,
                             "upper_95": hi, "with_structure": sum(bool(r["structure"]) for r in null),
                             "false": sorted({e for r in null for e in r["effects"]})}
        per: dict[str, dict] = {}
        for t, r in zip(tasks, results, strict=True):
            if r is None or t[0] != "power" or t[3] != form:
                continue
            p = per.setdefault(t[4], {"n": 0, "named": 0, "instead": []})
            p["n"] += 1
            p["named"] += bool(r["detected"])
            if not r["detected"]:
                p["instead"].append(f"draw {t[1]}: " + (", ".join(r["effects"] + [f"{s} (structure)" for s in
                                                                                   r["structure"]]) or "nothing"))
        n = sum(p["n"] for p in per.values())
        out["power"][form] = {"per_effect": per, "n": n, "named": sum(p["named"] for p in per.values()),
                              "rate": sum(p["named"] for p in per.values()) / n if n else None}
    allnull = [r for t, r in zip(tasks, results, strict=True) if r is not None and t[0] == "null"]
    k = sum(bool(r["effects"]) for r in allnull)
    out["null"]["all"] = {"diagnoses": len(allnull), "with_false_effect": k,
                          "upper_95": clopper_pearson(k, len(allnull))[1] if allnull else 1.0}
    return out


def print_summary(summary: dict) -> None:
    for form in FORMS:
        nl = summary["null"][form]
        print(f"null, {form} form: {nl['with_false_effect']} of {nl['diagnoses']} diagnoses with a false effect "
              f"(95 % upper bound {nl['upper_95']:.1%}; {nl['with_structure']} with a structure entry)"
              + (f"; named: {', '.join(nl['false'])}" if nl["false"] else ""))
    a = summary["null"]["all"]
    print(f"null, both forms: {a['with_false_effect']} of {a['diagnoses']} (95 % upper bound {a['upper_95']:.1%})")
    for form in FORMS:
        pw = summary["power"][form]
        if not pw["n"]:
            continue
        print(f"power at the grid's middle size, {form} form: {pw['named']} of {pw['n']} named right")
        for name, p in pw["per_effect"].items():
            print(f"  {name:22s} {p['named']}/{p['n']}" + (f"   missed: {'; '.join(p['instead'])}" if p["instead"]
                                                            else ""))


def main(argv: list[str] | None = None) -> None:
    from hil_sim.family import REPORTING_DRAWS, draws_line

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", help=f"plant draws (default: the first {DEFAULT_DRAWS} reporting draws)")
    ap.add_argument("--reps", type=int, default=5, help="null diagnoses per draw and form (default 5)")
    ap.add_argument("--only", choices=("null", "power"), help="only one kind of task")
    ap.add_argument("--out", default="family_diagnose.jsonl", help="JSONL of the tasks' results (resumed)")
    ap.add_argument("--models", help="folder of the draws' pickled models (default: beside --out)")
    ap.add_argument("--summarise", action="store_true", help="only the summary of the tasks already in --out")
    add_run_options(ap)
    args = ap.parse_args(argv)
    draws = parse_draws(args.draws) if args.draws else list(REPORTING_DRAWS[:DEFAULT_DRAWS])
    models = args.models or str(Path(args.out).resolve().parent / "family_models")
    print(draws_line(draws) + f"; identification seed 0, noise seeds from {FIRST_NOISE_SEED}", flush=True)
    tasks = plan(draws, args.reps, args.only, models)
    if args.summarise:
        from benchmarks.family import load_done, task_key

        done = load_done(args.out)
        results = [done.get(task_key(t)) for t in tasks]
    else:
        results = run_tasks(diagnose_task, tasks, args.out, serial=args.serial, scheduler=args.scheduler,
                            workers=args.workers)
    summary = summarise(tasks, results)
    print_summary(summary)
    emit({"draws": draws, "reps": args.reps, "tasks": len(tasks),
          "finished": sum(r is not None for r in results), "summary": summary})


if __name__ == "__main__":
    main()
