"""Null rate: how often the diagnosis names an effect where nothing changed.

The hybrid model is identified once on a clean standard campaign of the bench (seed 1), as in
``benchmarks/effects_table.py``. Then, for each of ``--seeds`` noise seeds, clean records are
measured again — the training record (sine k = 0.125, the identification's experiment repeated)
and two validation records (sine k = 0.125 and random) — and diagnosed. Nothing was injected, so
every accepted entry of kind ``effect`` is a false alarm; entries of kind ``structure`` are
counted apart (the model's own misfit, which the diagnosis may name as such).

With ``--independent``, the same is done on the independent plant's development set (when
``../shared`` is beside the project): its ``clean`` case as the README's protocol runs it, and
once more with the campaign's own ``sine_k025`` and ``random`` (another noise seed) as the
validation records.

Prints one line per run, the totals, and, as its last line, one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from benchmarks.effects_table import bench_model, records
from rtlift.diagnose import diagnose
from rtlift.identify import identify_hybrid

IP_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "independent_plant"


def accepted(report: dict, kind: str) -> list[str]:
    return [e["name"] for e in report["effects"] if e["accepted"] and e["kind"] == kind]


def bench_runs(seeds: int, first: int) -> list[dict]:
    model = bench_model()
    runs = []
    for s in range(first, first + seeds):
        train, val = records([], (3 * s, 3 * s + 1, 3 * s + 2))
        report = diagnose(model, train, val).report
        runs.append({"plant": "bench", "seed": s, "effects": accepted(report, "effect"),
                     "structure": accepted(report, "structure"), "fit_target": report["fit_target"]})
    return runs


def independent_runs(data: Path) -> list[dict]:
    from rtlift.core.records import read_record

    camp = data / "campaign"
    model = identify_hybrid(read_record(camp / "static.csv"), read_record(camp / "single_burst.csv"),
                            read_record(camp / "sine_k0125.csv")).model
    train = read_record(data / "clean" / "sine_k0125.csv")
    runs = []
    for label, folder in (("clean case", data / "clean"), ("campaign's validation records", camp)):
        val = [read_record(folder / f"{r}.csv") for r in ("sine_k025", "random")]
        report = diagnose(model, train, val).report
        runs.append({"plant": "independent", "seed": label, "effects": accepted(report, "effect"),
                     "structure": accepted(report, "structure"), "fit_target": report["fit_target"]})
    return runs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=12, help="clean bench runs (default 12)")
    ap.add_argument("--first-seed", type=int, default=200)
    ap.add_argument("--independent", action="store_true", help="also the independent plant's clean records")
    args = ap.parse_args(argv)
    if args.seeds < 0:
        print("--seeds must be >= 0", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    runs = bench_runs(args.seeds, args.first_seed)
    if args.independent:
        if not (IP_DATA / "campaign" / "static.csv").exists():
            print(f"no independent plant data at {IP_DATA}", file=sys.stderr)
            return 2
        runs += independent_runs(IP_DATA)
    for r in runs:
        print(f"{r['plant']:<12} {str(r['seed']):<30} effects: {', '.join(r['effects']) or '—':<30} "
              f"structure: {', '.join(r['structure']) or '—'}")
    false = sum(len(r["effects"]) for r in runs)
    hit = sum(bool(r["effects"]) for r in runs)
    print(f"\n{len(runs)} clean runs: {hit} with an accepted effect ({false} false effects in all); "
          f"{sum(bool(r['structure']) for r in runs)} with a structure entry")
    print(json.dumps({"runs": runs, "clean_runs": len(runs), "runs_with_false_effect": hit,
                      "false_effects": false, "seconds": round(time.perf_counter() - t0, 1)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
