"""Why a design's measured gust band falls short of its prediction: per draw, saved designs measured
at several gust amplitudes, with the fraction of burst periods whose envelope sits at an actuator
limit (0 V or 200 V) in each feedback run.

For each draw N of ``--draws`` and each structure S of ``--structures``, ``DIR/N_model.json`` and
the design ``DIR/N_design_S.json`` (``rtlift design``'s report.json form; ``benchmarks/
control_family.py`` and ``benchmarks/model_error.py --design`` make them) are loaded, and
:func:`benchmarks.gust_rejection.suppression_rows` measures the loop on plant N in process (the
bench's truth, a constant reference ``--level``, a gust ``A sin(2π f t)`` on the true ΔCL) at every
amplitude A of ``--amplitudes`` beside the design's predicted |S_o| at the checked point nearest
the reference. A suppression that changes with A, or clamped periods, is a nonlinearity the linear
prediction leaves out; one that does neither is linear. Each feedback run is repeated without
the gust at the same seed (:func:`~benchmarks.gust_rejection.suppression_rows`): the lift the loop
makes of the sensor noise alone at f (the floor) and the gust's own part (the two runs' difference),
printed as measured (the whole lift) / gust's part / predicted dB [clamped %, floor dB]. One JSON
object per (draw, structure, amplitude) is appended to ``--out``; the last line printed is one JSON line of all.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402
from benchmarks.control_family import draws  # noqa: E402
from benchmarks.gust_rejection import crossing_hz, suppression_rows  # noqa: E402


def one(directory: str, n: int, structure: str, amplitude: float, frequencies: tuple[float, ...], *,
        level: float, seed: int) -> dict:
    """Draw ``n``'s saved ``structure`` design measured at gust ``amplitude`` (ΔCL)."""
    from rtlift.app.control import ControlConfig
    from rtlift.app.control_design import load_design
    from rtlift.model.modelfile import load_model

    model = load_model(os.path.join(directory, f"{n}_model.json"))
    design = load_design(os.path.join(directory, f"{n}_design_{structure}.json"), accept_warnings=True)
    point = min(design.points, key=lambda pt: abs(pt.dcl - level))
    t0 = time.perf_counter()
    rows = suppression_rows(design.control_model(model), ControlConfig(feedback=False, fs_hz=model.fs_hz),
                            design.control_config(fs_hz=model.fs_hz), point, design.dt, level=level,
                            amplitude=amplitude, seed=seed, plant_draw=n, frequencies=frequencies)
    freqs = [r["f_hz"] for r in rows]
    return {"draw": n, "structure": structure, "amplitude": amplitude, "level": level, "seed": seed,
            "f6_hz_measured": crossing_hz(freqs, [r["suppression_db"] for r in rows]),
            "f6_hz_predicted": point.f6_hz, "point_dcl": point.dcl, "rows": rows,
            "measure_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", required=True, help="N_model.json and N_design_S.json per draw")
    ap.add_argument("--draws", default="1-3", help="draw numbers, A-B or A,B,C (default 1-3: calibration)")
    ap.add_argument("--structures", default="pi,youla", help="the designs' suffixes (default pi,youla)")
    ap.add_argument("--amplitudes", default="0.01,0.0025", help="gust amplitudes, ΔCL (default 0.01,0.0025)")
    ap.add_argument("--frequencies", default="0.1,0.2,0.25,0.35,0.5,2")
    ap.add_argument("--level", type=float, default=0.08, help="constant ΔCL reference (default 0.08)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--out", default="youla_gap.jsonl", help="JSON lines (appended)")
    args = ap.parse_args()
    freqs = tuple(float(f) for f in args.frequencies.split(","))
    results = []
    for n in draws(args.draws):
        for s in args.structures.split(","):
            for a in (float(x) for x in args.amplitudes.split(",")):
                r = one(args.dir, n, s, a, freqs, level=args.level, seed=args.seed)
                results.append(r)
                with open(args.out, "a", encoding="utf-8") as fh:
                    fh.write(json.dumps(r) + "\n")
                print(f"draw {n} {s} gust {a:g}: band {r['f6_hz_measured']:.3f} Hz (predicted "
                      f"{r['f6_hz_predicted']:.3f}); " + " ".join(
                          f"{row['f_hz']:g}:{row['suppression_single_db']:+.1f}/{row['suppression_db']:+.1f}/"
                          f"{row['predicted_s_db']:+.1f}[{100 * row['clamped_fraction']:.0f}%, floor "
                          f"{row['floor_db']:+.1f}]" for row in r["rows"])
                      + f" ({r['measure_s']:.0f} s)", flush=True)
    emit({"runs": results})


if __name__ == "__main__":
    main()
