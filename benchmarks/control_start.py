"""How long ``rtlift control`` takes to open its link, with and without the design cached beside
the model.

The model file is copied into a fresh directory (so no cached design exists), then ``rtlift
control`` is started twice on the bench's serial pseudo-terminal (:class:`rtlift.app.hil_tracking.
BenchTracking`: a subprocess, real time, the default design, a constant reference, ``--seconds``
of tracking): the first start designs the loop and writes ``MODEL.design-<sha12>.json``; the
second finds it. Measured: wall time from the subprocess's spawn to its "link open" line (what a
user waits for before the loop runs), and the CPU time the process had used by then (the wall time
on an idle machine). Prints one line per start, then one JSON line.

``--model MODEL.json`` (default tests/data/bench_model.json). ``--cached-only``: the design cached
beside MODEL (``MODEL.design-<sha12>.json``, made by ``rtlift design`` or an earlier start) is copied
beside the copy, and only the cached start is measured (the designing start takes minutes here).
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


def child_cpu_s(pid: int) -> float:
    """CPU time (user + system, s) the process ``pid`` has used so far (/proc/PID/stat fields 14–15):
    on a loaded machine the wall time to the link is this stretched by the other processes."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=os.path.join(ROOT, "tests", "data", "bench_model.json"))
    ap.add_argument("--seconds", type=float, default=2.0, help="tracking time of each run (s)")
    ap.add_argument("--cached-only", action="store_true", help="copy MODEL's cached design; measure that start only")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        model = os.path.join(tmp, "model.json")
        shutil.copyfile(args.model, model)
        starts = ("no cache (designs)", "cached design")
        if args.cached_only:
            from rtlift.app.control_design import design_cache_path

            cache = design_cache_path(args.model)
            if not os.path.exists(cache):
                sys.exit(f"control_start: no cached design {cache} (rtlift control or rtlift design makes it)")
            shutil.copyfile(cache, design_cache_path(model))
            starts = starts[1:]
        for name in starts:
            cached_before = bool(glob.glob(os.path.join(tmp, "model.design-*.json")))
            run = BenchTracking(model, "steps:0.08@0", True, args.seconds, os.path.join(tmp, f"{len(rows)}.json"),
                                effects=())
            t0 = time.perf_counter()
            run.start()
            opened = time.perf_counter() - t0
            cpu = child_cpu_s(run.proc.pid)
            counts = run.finish()
            rows.append({"start": name, "cache_present": cached_before, "link_open_s": opened,
                         "cpu_to_link_open_s": cpu,
                         "gains_source": run.summary["gains"]["source"], "lost": counts["lost"],
                         "commands_applied": f"{counts['commands_applied']}/{counts['commands_sent']}"})
            print(f"{name}: link open after {opened:.2f} s, {cpu:.2f} s of CPU (gains: {rows[-1]['gains_source']}; "
                  f"lost {counts['lost']}, commands applied {rows[-1]['commands_applied']})")
    emit({"rows": rows, "model": args.model, "seconds": args.seconds})


if __name__ == "__main__":
    main()
