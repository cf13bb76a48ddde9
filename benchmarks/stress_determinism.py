"""Same inputs, same answer: N runs of ``rtlift identify`` (and of ``rtlift diagnose``) on
one campaign, P at a time, all starting from one empty numba cache (issue 26).

Each run is a separate ``rtlift`` process, as a user's or a lab's scripts would start them;
the P concurrent runs share the cold ``NUMBA_CACHE_DIR``, so they compile and write the
cache at the same time (the case where numba's on-disk cache has known races). The script
prints how many runs succeeded, the first line of every failure, and how many distinct
output files the successful runs wrote (1 = bit for bit the same). The last line is one JSON
object.

    python -m benchmarks.stress_determinism --runs 40 --parallel 3 --diagnoses 20

The campaign is the independent plant's (``../shared/data/independent_plant``) where it
is present, else the simulated bench's standard campaign recorded with ``--seed``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from benchmarks._common import emit

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "independent_plant"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _json_difference(a: object, b: object, where: str = "") -> str | None:
    """The path of the first value that differs between two JSON documents."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                return f"{where}.{k}"
            d = _json_difference(a[k], b[k], f"{where}.{k}")
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            d = _json_difference(x, y, f"{where}[{i}]")
            if d:
                return d
        return None
    return None if a == b else f"{where or '.'}: {a!r} vs {b!r}"[:200]


def _rtlift(argv: list[str], env: dict) -> tuple[int, str, float]:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "rtlift", *argv], env=env, capture_output=True, text=True)
    lines = [ln for ln in (proc.stderr + proc.stdout).splitlines() if ln.strip()]
    first_error = next((ln for ln in lines if "error" in ln.lower()), lines[-1] if lines else "")
    return proc.returncode, first_error, time.perf_counter() - t0


def _campaign(work: Path, seed: int) -> tuple[Path, Path, str]:
    """(campaign dir, diagnosis case dir, source): the independent plant's where present."""
    if (SHARED / "campaign" / "static.csv").exists():
        return SHARED / "campaign", SHARED / "fade", "independent_plant"
    from hil_sim.experiments import run_experiment
    from rtlift.core.records import write_record

    camp, case = work / "campaign", work / "case"
    camp.mkdir()
    case.mkdir()
    for name in ("static", "single_burst", "sine_k0125"):
        write_record(camp / f"{name}.csv", run_experiment(name, seed=seed).to_record())
    for name in ("sine_k0125", "sine_k025", "random"):
        write_record(case / f"{name}.csv", run_experiment(name, seed=seed + 1,
                                                             effects=["actuator_fade:final_fraction=0.7"]).to_record())
    return camp, case, f"bench seed {seed}"


def _batch(label: str, argvs: list[list[str]], outputs: list[list[Path]], parallel: int,
           env: dict) -> dict:
    with ThreadPoolExecutor(parallel) as pool:
        results = list(pool.map(lambda a: _rtlift(a, env), argvs))
    failures = [f"run {i}: exit {code}: {err}" for i, (code, err, _) in enumerate(results) if code != 0]
    ok = [i for i, (code, _, _) in enumerate(results) if code == 0]
    by_digest: dict = {}
    for i in ok:
        by_digest.setdefault(tuple(_digest(p) for p in outputs[i]), i)
    digests = set(by_digest)
    differences = []
    if len(by_digest) > 1:
        first, *others = by_digest.values()
        for i in others:
            for pa, pb in zip(outputs[first], outputs[i], strict=True):
                d = _json_difference(json.loads(pa.read_text()), json.loads(pb.read_text()))
                if d:
                    differences.append(f"{pb.name} of run {i} vs run {first}: {d}")
    seconds = sorted(s for _, _, s in results)
    for line in failures + differences:
        print(f"{label}: {line}", file=sys.stderr)
    print(f"{label}: {len(ok)} of {len(argvs)} succeeded, {len(digests)} distinct output(s), "
          f"median {seconds[len(seconds) // 2]:.1f} s", file=sys.stderr)
    return {"runs": len(argvs), "succeeded": len(ok), "failures": failures, "differences": differences,
            "distinct_outputs": len(digests), "identical": len(ok) == len(argvs) and len(digests) == 1,
            "median_seconds": round(seconds[len(seconds) // 2], 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=40, help="identifications (default 40)")
    ap.add_argument("--diagnoses", type=int, default=20, help="diagnoses (default 20; 0 to skip)")
    ap.add_argument("--parallel", type=int, default=3, help="runs at a time (default 3)")
    ap.add_argument("--seed", type=int, default=0, help="bench seed where the independent plant is absent")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        camp, case, source = _campaign(work, args.seed)
        env = dict(os.environ, NUMBA_CACHE_DIR=str(work / "numba-cache"))   # empty: a cold cache
        result: dict = {"campaign": source, "parallel": args.parallel}

        models = [work / f"model{i}.json" for i in range(args.runs)]
        argvs = [["identify", "--static", str(camp / "static.csv"), "--single-burst", str(camp / "single_burst.csv"),
                  "--train", str(camp / "sine_k0125.csv"), "-o", str(m)] for m in models]
        result["identify"] = _batch("identify", argvs, [[m] for m in models], args.parallel, env)

        if args.diagnoses:
            model = next((m for m in models if m.exists()), None)
            if model is None:
                result["diagnose"] = {"runs": 0, "note": "no identification succeeded"}
            else:
                env["NUMBA_CACHE_DIR"] = str(work / "numba-cache-diagnose")
                outs = [work / f"diag{i}" for i in range(args.diagnoses)]
                argvs = [["diagnose", "--model", str(model), "--train", str(case / "sine_k0125.csv"),
                          "--validate", str(case / "sine_k025.csv"), str(case / "random.csv"), "--out", str(o)]
                         for o in outs]
                files = [[o / "report.json", o / "model_augmented.json"] for o in outs]
                result["diagnose"] = _batch("diagnose", argvs, files, args.parallel, env)
    emit(result)
    ok = result["identify"]["identical"] and result.get("diagnose", {}).get("identical", True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
