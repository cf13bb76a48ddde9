"""The internal-model design's programme solved two ways: every disc bound a second-order cone
(Clarabel, exact, what the design uses) against the same discs as polygons in a linear programme
(HiGHS, the fallback: inner polygons of 12 and 24 sides, as the controller's programme was until the
fourteenth pass).

For the model ``--model`` (default: the bench model of tests/data, or a plant draw's identified model
``DIR/N_model.json``), :func:`rtlift.app.control_design.design_loop` builds the joint programme of its
scheduled points (``structure="youla"``, the channel bound, the model's error spared, as ``rtlift
design --structure youla`` does; the programmes are taken from its own :func:`joint_band` call), then
the joint band's binary search is timed with each solver ``--repeat`` times: the band each finds and
the median time. The polygon band is never above the cone's (an inner polygon is a narrower set).
One JSON line: per solver the band (Hz) and the median seconds, and the ratio of the times measured in
the same run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402

DEFAULT_MODEL = os.path.join(os.path.dirname(__file__), "..", "tests", "data", "bench_model.json")


def programmes(model_path: str) -> list:
    """The scheduled points' :class:`~rtlift.app.control_design.YoulaProgram` of the model's youla design."""
    from rtlift.app import control_design as cd
    from rtlift.model.modelfile import load_model

    seen: list = []
    real = cd.joint_band

    def keep(progs):
        seen.append(progs)
        return real(progs)

    cd.joint_band = keep
    try:
        cd.design_loop(load_model(model_path), structure="youla", limit=False)
    finally:
        cd.joint_band = real
    return seen[0]


def timed(progs: list, repeat: int, sides: int | None) -> tuple[float, float]:
    """(band Hz, median seconds) of :func:`joint_band` with the cone, or with ``sides``-sided polygons."""
    from rtlift.app import control_design as cd

    real_cone, real_sides = cd.settled_cone, cd.CONTROLLER_SIDES
    if sides is not None:
        cd.settled_cone = lambda *a, **k: ("unsettled", None)
        cd.CONTROLLER_SIDES = sides
    try:
        times, band = [], 0.0
        for _ in range(repeat):
            t = time.perf_counter()
            band = cd.joint_band(progs)
            times.append(time.perf_counter() - t)
    finally:
        cd.settled_cone, cd.CONTROLLER_SIDES = real_cone, real_sides
    return band, statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=DEFAULT_MODEL, help="an identified model file (default: the bench model)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per solver (median)")
    ap.add_argument("--sides", default="12,24", help="polygon sides to time beside the cone")
    args = ap.parse_args()
    progs = programmes(args.model)
    out = {"model": os.path.basename(args.model), "points": len(progs), "repeat": args.repeat}
    band, sec = timed(progs, args.repeat, None)
    out["cone"] = {"band_hz": band, "median_s": sec}
    for n in (int(s) for s in args.sides.split(",") if s):
        b, s = timed(progs, args.repeat, n)
        out[f"polygon_{n}"] = {"band_hz": b, "median_s": s, "time_over_cone": s / sec}
        print(f"polygon {n}: {b:.3f} Hz in {s:.1f} s (cone {band:.3f} Hz in {sec:.1f} s)", flush=True)
    emit(out)


if __name__ == "__main__":
    main()
