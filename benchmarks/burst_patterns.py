"""One model across burst patterns (issues 18, 31): ``rtlift identify``'s default on the full
campaign against the paper's hybrid, ρ and NRMSE per record type beside the ceiling, on our
bench and on the independent plant.

    python -m benchmarks.burst_patterns [--plant DIR] [--seed N]
    python -m benchmarks.burst_patterns --seeds A-B


- bench: the standard campaign recorded from ``hil_sim`` with seed N (default 0) identifies
  both models; every record type recorded with seed N + 1 validates them;
- independent plant (``../shared/data/independent_plant``, skipped when absent): identified
  on its ``campaign/``, validated on the campaign's other records (sine_k025, random) and on
  every record of ``clean/`` (another noise seed, the trains included).

``paper`` is ``rtlift identify`` without trains (static, single burst, sine_k0125: the paper's
hybrid); ``default`` is ``rtlift identify`` with the trains too and no other option (it chooses
the interaction structure, :mod:`rtlift.identify.choice`). Each record is scored from rest over
the whole record (as ``rtlift validate``).

The ceiling is the plant's noise-free lift scored against the same record: no model can do
better. On the bench it is the simulator's own noise-free lift (``truth``). The independent
plant's records carry no noise-free lift: there the ceiling is estimated from the measurement
noise while bursts fire, the scatter of ΔCL across the identical isolated bursts of the
folder's ``single_burst`` record (:func:`rtlift.identify.kernel.burst_scatter_std`), as
ρ = √(1 − σ_n²/σ²), NRMSE = σ_n/σ (:func:`rtlift.core.metrics.noise_ceiling`). The same
estimate is printed on the bench beside the truth, where both are known.

``--seeds A-B`` answers the other question of issue 31 — is the default at least as good as the
paper's hybrid on the sines and ``random``? — where one seed cannot (the two differ by less than
0.001 in ρ there, less than the spread between seeds): on the bench only, each seed N of A … B
identifies both models and seed N + 1's ``sine_k0125``, ``sine_k025`` and ``random`` validate them;
per record type it prints on how many seeds the default is ahead or level in ρ and the medians of
its differences in ρ and NRMSE (paired by seed).

Goal (issue 31), per record: ρ ≥ ceiling ρ − 0.02 and NRMSE ≤ max(0.5, ceiling NRMSE + 0.1).
The last line is one JSON object: per plant and record the models' and the ceiling's scores
and whether the default meets the goal, and ``goal_met`` per plant and model.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from benchmarks._common import emit
from benchmarks.independent_plant import DEFAULT_DATA as DEFAULT_PLANT
from rtlift.core.metrics import noise_ceiling, scores
from rtlift.core.records import Record, read_record
from rtlift.identify.campaign import identify_hybrid
from rtlift.identify.choice import identify_lift
from rtlift.identify.kernel import burst_scatter_std
from rtlift.model.validation import validate_record

RECORDS = ("static", "single_burst", "train_T1p75", "train_T3p5", "train_T7", "sine_k0125", "sine_k025", "random")
TRAINS = ("train_T1p75", "train_T3p5", "train_T7")
MODELS = ("paper", "default")
CORR_MARGIN, NRMSE_MARGIN, NRMSE_FLOOR = 0.02, 0.1, 0.5


def bench_records(seed: int, plant_draw: int = 0) -> tuple[dict[str, Record], dict[str, dict[str, float]]]:
    """The records of every type, and the bench truth's scores against each (the ceiling);
    ``plant_draw``: plant N of the family (hil_sim.family; 0 our bench)."""
    from hil_sim.experiments import run_experiment

    runs = {n: run_experiment(n, seed=seed, plant_draw=plant_draw) for n in RECORDS}
    records = {n: r.to_record(n) for n, r in runs.items()}
    return records, {n: scores(records[n].dcl, runs[n].dcl_true) for n in RECORDS}


def plant_records(folder: str) -> dict[str, Record]:
    return {n: read_record(os.path.join(folder, f"{n}.csv")) for n in RECORDS
            if os.path.exists(os.path.join(folder, f"{n}.csv"))}


def estimated_ceilings(records: dict[str, Record]) -> dict[str, dict[str, float]]:
    """The ceiling of each record from the noise of the same seed's single bursts (module docstring)."""
    burst = records["single_burst"]
    noise = burst_scatter_std(burst.cmu, burst.dcl)
    return {n: noise_ceiling(r.dcl, noise) for n, r in records.items()}


def compare(ident: dict[str, Record], validation: dict[str, Record]) -> dict[str, dict[str, dict[str, float]]]:
    """{label: {"paper": scores, "default": scores}} for every validation record."""
    paper = identify_hybrid(ident["static"], ident["single_burst"], ident["sine_k0125"]).model
    default = identify_lift(ident["static"], ident["single_burst"], [ident[t] for t in TRAINS],
                            ident["sine_k0125"])[0].model
    return {label: {"paper": validate_record(paper, rec).scores, "default": validate_record(default, rec).scores}
            for label, rec in validation.items()}


def meets_goal(model: dict[str, float], ceiling: dict[str, float]) -> bool:
    return (model["corr"] >= ceiling["corr"] - CORR_MARGIN
            and model["nrmse"] <= max(NRMSE_FLOOR, ceiling["nrmse"] + NRMSE_MARGIN))


def table(title: str, rows: dict[str, dict]) -> str:
    head = (f"  {'record':24s} {'paper ρ':>8} {'NRMSE':>6}   {'default ρ':>9} {'NRMSE':>6}   "
            f"{'ceiling ρ':>9} {'NRMSE':>6}")
    lines = [title, head]
    for label, r in rows.items():
        p, d, c = r["paper"], r["default"], r["ceiling"]
        line = (f"  {label:24s} {p['corr']:8.3f} {p['nrmse']:6.2f}   {d['corr']:9.3f} {d['nrmse']:6.2f}   "
                f"{c['corr']:9.3f} {c['nrmse']:6.2f}")
        if "estimate" in r:
            line += f"   (estimate {r['estimate']['corr']:.3f} {r['estimate']['nrmse']:.2f})"
        lines.append(line + ("" if r["goal_met"] else "   goal not met"))
    return "\n".join(lines)


def with_ceilings(rows: dict[str, dict], ceilings: dict[str, dict[str, float]],
                  estimates: dict[str, dict[str, float]] | None = None) -> dict[str, dict]:
    for label, r in rows.items():
        r["ceiling"] = ceilings[label]
        if estimates is not None:
            r["estimate"] = estimates[label]
        r["goal_met"] = meets_goal(r["default"], r["ceiling"])
    return rows


PAIRED = ("sine_k0125", "sine_k025", "random")


def paired_seeds(first: int, last: int) -> dict:
    """The default against the paper's hybrid on :data:`PAIRED`, seed by seed (module docstring)."""
    per_seed = {}
    ident = bench_records(first)[0]
    for seed in range(first, last + 1):
        validation = bench_records(seed + 1)[0]          # and the next seed's identification campaign
        per_seed[seed] = compare(ident, {n: validation[n] for n in PAIRED})
        ident = validation
        print(f"  seed {seed}: " + "   ".join(
            f"{n} {r['paper']['corr']:.4f} / {r['default']['corr']:.4f}" for n, r in per_seed[seed].items()),
            flush=True)
    summary = {}
    for n in PAIRED:
        d_corr = np.array([per_seed[s][n]["default"]["corr"] - per_seed[s][n]["paper"]["corr"] for s in per_seed])
        d_nrmse = np.array([per_seed[s][n]["default"]["nrmse"] - per_seed[s][n]["paper"]["nrmse"] for s in per_seed])
        summary[n] = {"seeds": int(d_corr.size), "default_ahead_or_level": int(np.sum(d_corr >= 0.0)),
                      "median_corr_difference": float(np.median(d_corr)), "min_corr_difference": float(d_corr.min()),
                      "max_corr_difference": float(d_corr.max()),
                      "median_nrmse_difference": float(np.median(d_nrmse))}
        s = summary[n]
        print(f"  {n:11s} default ahead or level on {s['default_ahead_or_level']} of {s['seeds']} seeds; "
              f"ρ default − paper median {s['median_corr_difference']:+.4f} "
              f"({s['min_corr_difference']:+.4f} … {s['max_corr_difference']:+.4f}), "
              f"NRMSE median {s['median_nrmse_difference']:+.3f}")
    return {"per_seed": {str(k): v for k, v in per_seed.items()}, "summary": summary}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", default=DEFAULT_PLANT, help="the independent plant's folder")
    ap.add_argument("--seed", type=int, default=0, help="bench seed of the identification campaign")
    ap.add_argument("--seeds", metavar="A-B", help="the bench only, paired over identification seeds A … B")
    args = ap.parse_args(argv)
    if args.seeds:
        first, _, last = args.seeds.partition("-")
        if not (first.isdigit() and (last or first).isdigit()) or int(last or first) < int(first):
            ap.error(f"--seeds wants A-B with 0 <= A <= B, got {args.seeds!r}")
        print("bench (hil_sim): the default against the paper's hybrid, identified on seed N, validated on N + 1")
        emit(paired_seeds(int(first), int(last or first)))
        return
    result: dict = {}
    validation, truth = bench_records(args.seed + 1)
    label = f"seed{args.seed + 1}/{{}}".format
    bench = compare(bench_records(args.seed)[0], {label(n): r for n, r in validation.items()})
    estimates = estimated_ceilings(validation)
    with_ceilings(bench, {label(n): t for n, t in truth.items()}, {label(n): e for n, e in estimates.items()})
    print(table(f"bench (hil_sim): identified on seed {args.seed}, validated on seed {args.seed + 1}; "
                "ceiling: the noise-free lift (and its estimate from the noise)", bench))
    result["bench"] = bench
    camp, clean = os.path.join(args.plant, "campaign"), os.path.join(args.plant, "clean")
    if os.path.isdir(camp) and os.path.isdir(clean):
        ident, later = plant_records(camp), plant_records(clean)
        validation = {f"campaign/{n}": ident[n] for n in ("sine_k025", "random")}
        validation.update({f"clean/{n}": r for n, r in later.items()})
        ceilings = {f"campaign/{n}": c for n, c in estimated_ceilings(ident).items()}
        ceilings.update({f"clean/{n}": c for n, c in estimated_ceilings(later).items()})
        plant = with_ceilings(compare(ident, validation), ceilings)
        print()
        print(table("independent plant: identified on campaign/, validated on campaign/ (held out) and clean/; "
                    "ceiling estimated from the noise", plant))
        result["independent_plant"] = plant
    else:
        print(f"independent plant not found at {args.plant}: skipped")
    result["goal_met"] = {name: {m: all(meets_goal(r[m], r["ceiling"]) for r in rows.values()) for m in MODELS}
                          for name, rows in result.items()}
    emit(result)


if __name__ == "__main__":
    main()
