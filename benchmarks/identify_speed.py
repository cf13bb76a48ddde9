"""Speed of ``rtlift identify`` on the standard campaign of the simulated bench.

Records the whole standard campaign (8 experiments, ≈ 5 min of 400 Hz data), writes them as
CSV, and times the identification exactly as ``rtlift identify`` runs it: reading the static,
single-burst and k = 0.125 records, static map, kernel and φ, the HPF search (2 φ modes ×
the admitted filters), the order choice n = 1 … 4 and the final PEM. The validation of the
other records is timed separately. Prints one JSON object as its last line.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

from hil_sim.experiments import EXPERIMENTS, run_experiment
from rtlift.core.rate import FS_HZ
from rtlift.core.records import read_record, write_record
from rtlift.identify.campaign import identify_hybrid
from rtlift.model.validation import validate_record


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        samples = 0
        for name in EXPERIMENTS:
            rec = run_experiment(name, seed=0).to_record()
            samples += len(rec)
            write_record(d / f"{name}.csv", rec)
        t0 = time.perf_counter()
        static = read_record(d / "static.csv")
        burst = read_record(d / "single_burst.csv")
        train = read_record(d / "sine_k0125.csv")
        t1 = time.perf_counter()
        idf = identify_hybrid(static, burst, train)
        t2 = time.perf_counter()
        others = [read_record(d / f"{n}.csv") for n in EXPERIMENTS]
        scores = {r.name: validate_record(idf.model, r).scores["corr"] for r in others}
        t3 = time.perf_counter()
    result = {
        "campaign_seconds_of_data": samples / FS_HZ,
        "campaign_samples": samples,
        "read_seconds": round(t1 - t0, 3),
        "identify_seconds": round(t2 - t0, 3),
        "identify_compute_seconds": round(t2 - t1, 3),
        "validate_all_seconds": round(t3 - t2, 3),
        "corr": {k: round(v, 4) for k, v in scores.items()},
        "highpass": {"order": idf.highpass.order, "cutoff_hz": idf.highpass.cutoff_hz},
        "wiener_order": idf.order.order,
    }
    print(f"standard campaign: {result['campaign_seconds_of_data']:.0f} s of data; "
          f"identify {result['identify_seconds']:.2f} s (of which reading "
          f"{result['read_seconds']:.2f} s); validating all 8 records "
          f"{result['validate_all_seconds']:.2f} s")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
