"""The exported C step (``rtlift export c``) beside the compiled Python step, and its size and load
on a Cortex-M4F.

Model: ``tests/data/bench_model.json`` (identified on the bench, observer tuned on seed-1
records; --model for another). Input: the seed-4 ``random`` bench record (24 000 samples; the
first 1000 warm the caches and are not timed). Prints JSON as its last line, per gain
(``steady``, ``full``) in double precision on this machine:

- ``c_step_median_us``, ``c_step_p99_us``: one ``NAME_step`` call, each timed with
  ``clock_gettime(CLOCK_MONOTONIC)`` around it in a C loop (``cc -std=c99 -O2``);
  ``timer_overhead_us`` the median of the same two clock reads around nothing (included above);
- ``python_step_median_us``, ``python_step_p99_us``: ``Observer.step`` (compiled) timed the same way
  with ``perf_counter`` (full gain only: the Python observer has no steady form);
- ``macs_per_step`` (model, filter): multiply–adds counted from the step's loop trip counts;
- Cortex-M4F, single precision (``arm-none-eabi-gcc -mcpu=cortex-m4 -mfpu=fpv4-sp-d16
  -mfloat-abi=hard -O2``): ``m4_text_bytes`` (code and ``static const`` parameters, flash),
  ``m4_state_bytes`` (``sizeof(NAME_state)``, RAM the caller holds), ``m4_step_stack_bytes``
  (``-fstack-usage`` of ``NAME_step``), and the estimated load at 400 Hz on a 168 MHz part,
  ``m4_load_percent_400hz`` = 400 · macs · CYCLES_PER_MAC / 168e6 (CYCLES_PER_MAC stated in the
  JSON: an estimate, not a measurement on a part). Absent with the reason when the
  cross-compiler is not installed.

Goal (issue 49): C step median ≤ 1 µs for the bench model with the steady gain.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, percentiles_us  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CYCLES_PER_MAC = 5.0
"""Cortex-M4F cycles per single-precision multiply–add of the step, assumed: VMLA.F32 (3
cycles) plus two VLDR (loads, 1–2 cycles each, the parameters from flash behind the STM32F4's
ART accelerator); the loop and call overhead is left out. A stated assumption, not a measurement."""
CLOCK_HZ = 168e6
RATE_HZ = 400.0

TIMER = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "PFX.h"

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

int main(int argc, char **argv)
{
    static PFX_state st;
    PFX_out out;
    FILE *f = fopen(argv[1], "r");
    long n = atol(argv[2]), k;
    double *c = malloc(3 * n * sizeof *c), *d = malloc(2 * n * sizeof *d), sink = 0.0;
    (void)argc;
    for (k = 0; k < 3 * n; k++)
        if (fscanf(f, "%lf", &c[k]) != 1)
            return 2;
    PFX_init(&st);
    for (k = 0; k < n; k++) {
        double t0 = now(), t1;
        PFX_step(&st, c[3 * k], c[3 * k + 1], c[3 * k + 2], &out);
        t1 = now();
        d[k] = t1 - t0;
        sink += out.dcl;
    }
    for (k = 0; k < n; k++) {
        double t0 = now();
        d[n + k] = now() - t0;
    }
    for (k = 0; k < 2 * n; k++)
        printf("%.9e\n", d[k]);
    fprintf(stderr, "%g\n", sink);
    return 0;
}
"""


def c_timing(model, gain: str, c: np.ndarray, e: np.ndarray, z: np.ndarray, work: Path) -> dict:
    """Median and p99 of one double-precision ``NAME_step`` on this machine (module docstring)."""
    from rtlift.export.c_module import export_c

    out = work / f"host_{gain}"
    exp = export_c(model, out, "double", gain, "bench", vector_samples=10)
    (out / "timer.c").write_text(TIMER.replace("PFX", "bench"))
    np.savetxt(out / "input.txt", np.column_stack([c, e, np.nan_to_num(z, nan=np.nan)]), fmt="%.17g")
    subprocess.run(["cc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "bench.c", "timer.c",
                    "-lm", "-o", "timer"], cwd=out, check=True, capture_output=True)
    run = subprocess.run(["./timer", "input.txt", str(c.size)], cwd=out, check=True, capture_output=True, text=True)
    d = np.array(run.stdout.split(), dtype=float)
    steps, empty = d[1000:c.size], d[c.size:]
    median, p99 = percentiles_us(steps)
    return {"c_step_median_us": round(median, 3), "c_step_p99_us": round(p99, 3),
            "timer_overhead_us": round(float(np.median(empty)) * 1e6, 3),
            "macs_per_step": exp.macs, "macs_model": exp.macs_model, "macs_filter": exp.macs_filter}


def python_timing(model, c: list, e: list, z: list) -> dict:
    from rtlift.observer import Observer

    obs = Observer.from_model(model)
    obs.warm_up()
    pc = time.perf_counter
    d = np.empty(len(c))
    for k in range(len(c)):
        t0 = pc()
        obs.step(c[k], e[k], z[k])
        d[k] = pc() - t0
    median, p99 = percentiles_us(d[1000:])
    return {"python_step_median_us": round(median, 3), "python_step_p99_us": round(p99, 3)}


def cortex_m4(model, gain: str, work: Path) -> dict:
    """Size and estimated load of the single-precision module built for a Cortex-M4F."""
    from rtlift.export.c_module import export_c

    if shutil.which("arm-none-eabi-gcc") is None:
        return {"m4_skipped": "arm-none-eabi-gcc not installed (Debian: apt-get install gcc-arm-none-eabi)"}
    out = work / f"m4_{gain}"
    exp = export_c(model, out, "single", gain, "bench", vector_samples=10)
    (out / "probe.c").write_text('#include "bench.h"\nbench_state bench_probe;\n')
    flags = ["-std=c99", "-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-O2", "-Wall", "-Wextra",
             "-Werror", "-pedantic"]
    for name in ("bench", "probe"):
        subprocess.run(["arm-none-eabi-gcc", *flags, "-fstack-usage", "-c", f"{name}.c", "-o", f"{name}.o"],
                       cwd=out, check=True, capture_output=True)
    sizes = {}
    for name in ("bench", "probe"):
        line = subprocess.run(["arm-none-eabi-size", f"{name}.o"], cwd=out, check=True, capture_output=True,
                              text=True).stdout.splitlines()[1].split()
        sizes[name] = [int(v) for v in line[:3]]
    stack = re.search(r"bench_step\s+(\d+)", (out / "bench.su").read_text())
    cycles = exp.macs * CYCLES_PER_MAC
    return {"m4_text_bytes": sizes["bench"][0], "m4_data_bytes": sizes["bench"][1],
            "m4_state_bytes": sizes["probe"][2] + sizes["probe"][1],
            "m4_step_stack_bytes": int(stack.group(1)) if stack else None,
            "m4_macs_per_step": exp.macs, "m4_cycles_per_step_estimate": int(cycles),
            "m4_step_us_estimate": round(cycles / CLOCK_HZ * 1e6, 1),
            "m4_load_percent_400hz": round(100.0 * RATE_HZ * cycles / CLOCK_HZ, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=str(ROOT / "tests" / "data" / "bench_model.json"))
    args = ap.parse_args()
    from hil_sim.experiments import run_experiment
    from rtlift.api import load

    model = load(args.model)
    rec = run_experiment("random", seed=4).to_record()
    c, e, z = rec.cmu, rec.cmu_envelope, rec.dcl
    result: dict = {"model": os.path.relpath(args.model, ROOT), "samples_timed": int(c.size - 1000),
                    "cycles_per_mac_assumed": CYCLES_PER_MAC, "clock_hz": CLOCK_HZ}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for gain in ("steady", "full"):
            part = c_timing(model, gain, c, e, z, work)
            part.update(cortex_m4(model, gain, work))
            if gain == "full":
                part.update(python_timing(model, c.tolist(), e.tolist(), z.tolist()))
            result[gain] = part
    result["goal_c_step_median_le_1us_steady"] = result["steady"]["c_step_median_us"] <= 1.0
    emit(result)


if __name__ == "__main__":
    main()
