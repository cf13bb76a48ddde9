"""How long ``rtlift control`` takes to open its link, with and without the design cached beside
the model.

The model file is copied into a fresh directory (so no cached design exists), then ``rtlift
control`` is started twice on the bench's serial pseudo-terminal (:class:`rtlift.app.hil_tracking.
BenchTracking`: a subprocess, real time, the default design, a constant reference, ``--seconds``
of tracking): the first start designs the loop and writes ``MODEL.design-<sha12>.json``; the
second finds it. Measured: wall time from the subprocess's spawn to its "link open" line (what a
user waits for before the loop runs). Prints one line per start, then one JSON line.

``--model MODEL.json`` (default tests/data/bench_model.json).
"""

from __future__ import annotations

import argparse
import glob
import os
import shutil
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402
from rtlift.app.hil_tracking import BenchTracking  # noqa: E402

ROOT = os.path.join(os.path.dirname(__file__), "..")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=os.path.join(ROOT, "tests", "data", "bench_model.json"))
    ap.add_argument("--seconds", type=float, default=2.0, help="tracking time of each run (s)")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        model = os.path.join(tmp, "model.json")
        shutil.copyfile(args.model, model)
        for name in ("no cache (designs)", "cached design"):
            cached_before = bool(glob.glob(os.path.join(tmp, "model.design-*.json")))
            run = BenchTracking(model, "steps:0.08@0", True, args.seconds, os.path.join(tmp, f"{len(rows)}.json"),
                                effects=())
            t0 = time.perf_counter()
            run.start()
            opened = time.perf_counter() - t0
            counts = run.finish()
            rows.append({"start": name, "cache_present": cached_before, "link_open_s": opened,
                         "gains_source": run.summary["gains"]["source"], "lost": counts["lost"],
                         "commands_applied": f"{counts['commands_applied']}/{counts['commands_sent']}"})
            print(f"{name}: link open after {opened:.2f} s (gains: {rows[-1]['gains_source']}; "
                  f"lost {counts['lost']}, commands applied {rows[-1]['commands_applied']})")
    emit({"rows": rows, "model": args.model, "seconds": args.seconds})


if __name__ == "__main__":
    main()
