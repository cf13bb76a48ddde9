"""``rtlift record`` against ``rtlift bench record``: the same model quality from a campaign
recorded over a link from ``rtlift bench serve`` (host-commanded, protocol version 2) as from the
bench's own records with the same seed.

Both sets: identify on static + single_burst + sine_k0125 (the paper's protocol, ``rtlift
identify`` defaults), validate on sine_k0125, sine_k025 and random; prints ρ per record and
the difference. Usage: ``python benchmarks/record_vs_bench.py [--seed N] [--link serial|slcan]
[--speed X] [--out DIR]``; the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from rtlift.core.records import read_record
from rtlift.identify.campaign import identify_hybrid
from rtlift.model.validation import validate_record

RECORDS = ("static", "single_burst", "sine_k0125", "sine_k025", "random")
VALIDATE = ("sine_k0125", "sine_k025", "random")


def rtlift(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rtlift", *args], capture_output=True, text=True, **kw)


def record_over_link(out: str, seed: int, link: str, speed: float) -> tuple[float, str]:
    serve = subprocess.Popen([sys.executable, "-m", "rtlift", "bench", "serve", f"--{link}", "--seed", str(seed),
                              "--speed", str(speed)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        path = serve.stdout.readline().strip()
        spec = ["--serial", path] if link == "serial" else ["--can", f"slcan:{path}"]
        t0 = time.perf_counter()
        run = rtlift("record", *spec, *RECORDS, "--out", out, "--seed", str(seed))
        seconds = time.perf_counter() - t0
        if run.returncode != 0:
            raise SystemExit(f"rtlift record failed ({run.returncode}): {run.stderr[-2000:]}")
        return seconds, run.stdout
    finally:
        serve.terminate()
        serve.wait(10)


def scores(recs: dict) -> dict:
    idf = identify_hybrid(recs["static"], recs["single_burst"], recs["sine_k0125"])
    return {n: validate_record(idf.model, recs[n]).scores["corr"] for n in VALIDATE}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--link", choices=("serial", "slcan"), default="serial")
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    out = a.out or tempfile.mkdtemp(prefix="record_vs_bench_")
    bench_dir, link_dir = os.path.join(out, "bench"), os.path.join(out, "record")
    os.makedirs(bench_dir, exist_ok=True)
    for n in RECORDS:
        r = rtlift("bench", "record", n, "--out", os.path.join(bench_dir, f"{n}.csv"), "--seed", str(a.seed))
        assert r.returncode == 0, r.stderr
    seconds, table = record_over_link(link_dir, a.seed, a.link, a.speed)
    print(table)
    bench = scores({n: read_record(os.path.join(bench_dir, f"{n}.csv")) for n in RECORDS})
    recorded = {n: read_record(os.path.join(link_dir, f"{n}.csv")) for n in RECORDS}
    linked = scores(recorded)
    print(f"{'record':<12} {'bench ρ':>8} {'recorded ρ':>11} {'difference':>11}")
    for n in VALIDATE:
        print(f"{n:<12} {bench[n]:8.4f} {linked[n]:11.4f} {linked[n] - bench[n]:+11.4f}")
    meta = {n: {k: recorded[n].meta.get(k) for k in ("received", "lost", "commands_sent", "commands_applied",
                                                        "commands_late", "first_burst_delay_samples")}
            for n in RECORDS}
    print(json.dumps({"seed": a.seed, "link": a.link, "speed": a.speed, "record_seconds": seconds,
                      "bench_corr": bench, "recorded_corr": linked,
                      "max_abs_difference": max(abs(linked[n] - bench[n]) for n in VALIDATE),
                      "records": meta, "out": out}))


if __name__ == "__main__":
    main()
