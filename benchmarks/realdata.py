"""Real measured data: what a Wiener model lacks on WH2009, Silverbox and Cascaded Tanks.

For each benchmark (vendored in ``data/``), through the command line as a user runs it: the
official estimation data written as a generic ``t,u,y`` record (its last 20 % a separate
validation record, which starts ``SKIP`` samples earlier: like the test split, it is scored
after a state-initialisation window of ``SKIP`` samples, here the end of the training part, so
that all of the last 20 % is scored), ``rtlift identify --record EST --structure wiener``,
``rtlift diagnose --skip 50 --init-state`` with the validation record, and ``rtlift validate --skip 50
--init-state`` of both model files on the official test split (free run from the state estimated on
the first 50 test samples, which are unscored: the rules' state-initialisation window; Cascaded
Tanks' records start with water in the tanks). Prints a markdown
table (before, after, what the diagnosis added, published references, seconds) and, as its
last line, one JSON object. ``--only NAME`` runs one benchmark.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rtlift.core.records import write_siso_record
from rtlift.sysid.benchmarks import STATE_INIT_SAMPLES, as_record, splits

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks._common import run_cli  # noqa: E402

SKIP = STATE_INIT_SAMPLES


PUBLISHED = {"wh2009": "0.241 (SUBNET) – 0.45 (dynoNet) mV",
             "silverbox": "1.4 mV (SUBNET); 0.26 mV (PNLSS, multisine)",
             "cascaded_tanks": "0.191 V (grey box) – 0.306 V (CT SUBNET); PNLSS 0.45 V"}


def record(path: Path, fs: float, u: np.ndarray, y: np.ndarray, name: str) -> Path:
    write_siso_record(path, as_record(fs, u, y, name))
    return path


def run(name: str, work: Path) -> dict:
    fs, ue, ye, ut, yt, scale, unit = splits(name)
    n_fit = int(round(0.8 * ue.size))
    est = record(work / "est.csv", fs, ue[:n_fit], ye[:n_fit], "est")
    val = record(work / "val.csv", fs, ue[n_fit - SKIP:], ye[n_fit - SKIP:], "val")
    test = record(work / "test.csv", fs, ut, yt, "test")
    t0 = time.perf_counter()
    run_cli("identify", "--record", est, "--structure", "wiener", "-o", work / "model.json")
    t1 = time.perf_counter()
    run_cli("diagnose", "--model", work / "model.json", "--train", est, "--validate", val, "--skip", SKIP,
            "--init-state", "--out", work / "diag")
    t2 = time.perf_counter()
    rmse = {}
    for which, model in (("before", work / "model.json"), ("after", work / "diag" / "model_augmented.json")):
        run_cli("validate", "--model", model, test, "--skip", SKIP, "--init-state", "--json", work / f"{which}.json")
        rmse[which] = scale * json.loads((work / f"{which}.json").read_text())["records"]["test"]["rmse"]
    report = json.loads((work / "diag" / "report.json").read_text())
    return {"benchmark": name, "unit": unit, "before": rmse["before"], "after": rmse["after"],
            "accepted": [e["name"] for e in report["effects"] if e["accepted"]],
            "accepted_kinds": {e["name"]: e.get("kind", "structure") for e in report["effects"] if e["accepted"]},
            "accepted_forms": {e["name"]: {"model": e["params"]["model"], "where": e["params"].get("where")}
                               for e in report["effects"] if e["accepted"] and "model" in e.get("params", {})},
            "tried": [e["name"] for e in report["effects"]], "not_built": report.get("not_built", []),
            "identify_seconds": t1 - t0, "diagnose_seconds": t2 - t1, "published": PUBLISHED[name]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("wh2009", "silverbox", "cascaded_tanks"))
    args = ap.parse_args(argv)
    rows = []
    for name in ([args.only] if args.only else ["wh2009", "silverbox", "cascaded_tanks"]):
        with tempfile.TemporaryDirectory() as tmp:
            rows.append(run(name, Path(tmp)))
    print("| benchmark | Wiener (before) | after diagnose | added (structure) | published | identify + diagnose |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['benchmark']} | {r['before']:.3f} {r['unit']} | {r['after']:.3f} {r['unit']} | "
              f"{', '.join(r['accepted']) or '—'} | {r['published']} | "
              f"{r['identify_seconds']:.0f} + {r['diagnose_seconds']:.0f} s |")
    print(json.dumps({"rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
