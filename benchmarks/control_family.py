"""The lift loop on plants of the bench's family it was not designed on: per plant draw, the
user's whole path, then the gust and the fade.

For each draw N (``--draws 100-104``: reporting draws; 1–49 are for calibration): record the
clean campaign on plant N (``rtlift bench record --plant-draw N``: static, single_burst,
sine_k0125), identify the model from it (``rtlift identify``, the paper's hybrid), design the loop
(:func:`rtlift.app.control_design.design_loop`: its margins, the targets it misses, the limit any
causal controller reaches), then measure on plant N in process (:func:`benchmarks.gust_rejection.
measure`: gust suppression per frequency beside the prediction at the checked point nearest ΔCL
0.08 — a half-way check with the interpolated gains the controller runs there, or a scheduled
one —, step tracking under a 70 % fade,
the envelope at a constant reference). Whatever the design says, the loop is measured (a design
``rtlift control`` would refuse is marked so). One JSON object per draw is appended to ``--out``
as it finishes (a long run keeps what it did); the last line printed is one JSON line of all.
``--keep DIR`` keeps each draw's model (and reuses it: a re-run after a change of the design skips
the recording and the identification).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, run_cli  # noqa: E402
from benchmarks.gust_rejection import FREQUENCIES, measure  # noqa: E402
from rtlift.app.control_design import DEFAULT_STRUCTURE, STRUCTURES, YOULA_CHANNEL_BOUND  # noqa: E402

CAMPAIGN = ("static", "single_burst", "sine_k0125")
TRAINS = ("sine_k0125", "random")
"""The training records ``--train`` may name: the paper's sine (the default), or the bench's ``random``
envelope, whose content reaches the burst-rate loop's upper band (docs/results/control.md, "Tenth pass")."""


def draws(text: str) -> list[int]:
    """``A-B`` or ``A,B,C`` as a list of draw numbers."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def identified_model(n: int, tmp: str, keep: str | None = None, train: str = "sine_k0125",
                     envelope: str = "recorded") -> str:
    """Plant ``n``'s model as a new user makes it: its clean campaign recorded (the static sweep, the
    single bursts and the training record ``train``), ``rtlift identify --envelope envelope``; the path (``keep``: kept
    there as ``N_model.json`` and reused when it exists)."""
    path = os.path.join(keep or tmp, f"{n}_model.json")
    if not (keep and os.path.exists(path)):
        files = {}
        for exp in (*CAMPAIGN[:2], train):
            files[exp] = os.path.join(tmp, f"{n}_{exp}.csv")
            run_cli("bench", "record", "--plant-draw", n, "--out", files[exp], exp)
        run_cli("identify", "--static", files["static"], "--single-burst", files["single_burst"], "--train",
                files[train], "--envelope", envelope, "-o", path, "--quiet")
    return path


def one_draw(n: int, tmp: str, frequencies: tuple[float, ...], seed: int, keep: str | None = None,
             targets: object = None, structure: str = DEFAULT_STRUCTURE, backoff: float | None = None,
             channel_bound: bool = YOULA_CHANNEL_BOUND, save_design: bool = False, model_error: str | None = None,
             train: str = "sine_k0125", envelope: str = "recorded", band_hz: float | None = None,
             seeds: int = 1, reuse_design: bool = False, s_error: str | None = None) -> dict:
    from rtlift.app.control_design import design_loop, load_design
    from rtlift.model.modelfile import load_model

    t0 = time.perf_counter()
    path = identified_model(n, tmp, keep, train, envelope)
    t1 = time.perf_counter()
    model = load_model(path)
    def saved(s: str) -> str:        # DIR/N_design_STRUCTURE[_cb][_rob].json
        return os.path.join(keep or "", f"{n}_design_{s}{'_cb' if channel_bound else ''}"
                                        f"{'_rob' if model_error else ''}.json")

    if reuse_design and keep and os.path.exists(saved(structure)):
        design = load_design(saved(structure), accept_warnings=True)
    else:
        design = design_loop(model, targets, structure=structure, channel_bound=channel_bound,
                             model_error=load_model_error(model_error),
                             **({} if backoff is None else {"backoff": backoff}),
                             **({} if band_hz is None else {"band_hz": band_hz}),
                             **({} if s_error is None else {"s_error": load_s_error(s_error)}))
        if save_design and keep:
            from rtlift.app.control_design import report_doc
            from rtlift.core.jsonfile import write_json_atomic

            write_json_atomic(saved(design.structure), report_doc(design, path), stage="design")
    t2 = time.perf_counter()
    point = min(design.points, key=lambda pt: abs(pt.dcl - 0.08))   # a half-way check too: the gains run there
    config = design.control_config(fs_hz=model.fs_hz)
    res = measure(design.control_model(model), config, point, design.dt, seed=seed, plant_draw=n,
                  frequencies=frequencies, seeds=seeds)
    res.pop("quiet")
    s = design.summary()
    return {"draw": n, "identify_s": t1 - t0, "design_s": t2 - t1, "measure_s": time.perf_counter() - t2,
            "violations": s["violations"], "refused_by_control": bool(s["violations"]),
            "pm_deg_min": s["pm_deg_min"], "gm_db_min": s["gm_db_min"], "peak_s_db_max": s["peak_s_db_max"],
            "robust_max": s["robust_max"], "f6_predicted_hz": point.f6_hz,
            "limit_f6_hz": design.nearest(0.08).limit_f6_hz,    # computed at the scheduled points
            "limit_f6_hz_min": s["limit_f6_hz_min"], "predicted_peak_db_at_0p08": point.peak_s_db,
            "predicted_point_dcl": point.dcl, "predicted_point_scheduled": point.designed,
            "limit_f6_hz_scheduled": [pt.limit_f6_hz for pt in design.scheduled],
            "observer": design.observer, "peak_db_target": design.targets.peak_db, "structure": design.structure,
            "backoff": backoff, "channel_bound": channel_bound, "model_error": model_error, "train": train,
            "envelope": envelope, "band_hz": band_hz, "s_error": s_error, "reused_design": reuse_design,
            "reach": design.reach, **res}


def load_model_error(path: str | None) -> object:
    """The :class:`~rtlift.app.control_design.ModelError` of ``benchmarks/model_error.py --envelope
    --out PATH`` ("calibration": :data:`~rtlift.app.control_design.MODEL_ERROR_ENVELOPE`; None: none)."""
    if not path:
        return None
    from rtlift.app.control_design import MODEL_ERROR_ENVELOPE, ModelError

    if path == "calibration":
        return MODEL_ERROR_ENVELOPE

    env = json.load(open(path, encoding="utf-8"))
    return ModelError(tuple(env["f_hz"]), tuple(env["delta_A"]), tuple(env["delta_X"]),
                      f"benchmarks/model_error.py --envelope, draws {env['draws']}")


def load_s_error(name: str) -> object:
    """The :class:`~rtlift.app.control_design.SensitivityError` named: "calibration"
    (:data:`~rtlift.app.control_design.YOULA_S_ERROR`), "none" (None) or the JSON ``--excess`` printed."""
    from rtlift.app.control_design import YOULA_S_ERROR, SensitivityError

    if name in ("calibration", "none"):
        return YOULA_S_ERROR if name == "calibration" else None
    doc = json.load(open(name, encoding="utf-8"))
    return SensitivityError(tuple(doc["f_hz"]), tuple(doc["band"]), tuple(doc["peak"]), doc.get("source", name))


def excess(rows: list[dict]) -> dict:
    """The model's error as the loop sees it, from measured draws: at each gust frequency the largest
    excess of the measured |S_o| (the gust's own part) over the predicted, absolute (≥ 0), over the
    draws, apart where the prediction stood in the band (at most ``BAND_CLASS_DB``) and elsewhere, and
    which draw set each (None: no prediction of that class there; the nearest frequency's value
    stands) — :class:`~rtlift.app.control_design.SensitivityError`'s tables."""
    from rtlift.app.control_design import BAND_CLASS_DB

    freqs = sorted({x["f_hz"] for r in rows for x in r["rows"]})
    out: dict = {"f_hz": freqs, "band": [], "peak": [], "band_draw": [], "peak_draw": [],
                 "draws": sorted(r["draw"] for r in rows)}
    for f in freqs:
        best = {"band": (0.0, None), "peak": (0.0, None)}
        for r in rows:
            for x in r["rows"]:
                if x["f_hz"] == f:
                    e = 10.0 ** (x["suppression_db"] / 20.0) - 10.0 ** (x["predicted_s_db"] / 20.0)
                    which = "band" if x["predicted_s_db"] <= BAND_CLASS_DB else "peak"
                    best[which] = max(best[which], (e, r["draw"]), key=lambda b: b[0])
        for which, (e, draw) in best.items():
            out[which].append(round(e, 4))
            out[which + "_draw"].append(draw)
    for which in ("band", "peak"):      # a frequency no prediction of the class stood at: the nearest one's
        have = [i for i, d in enumerate(out[which + "_draw"]) if d is not None]
        out[which] = [out[which][min(have, key=lambda j: abs(j - i))] for i in range(len(freqs))]
    return out


def table(rows: list[dict]) -> str:
    """The per-draw results as a markdown table, then their distribution (min / median / max)."""
    import numpy as np

    head = ("| draw | design | q_bias factor | PM min (deg) | predicted peak (dB) | 6 dB band measured / predicted / "
            "limit (Hz) | suppression at 0.1 / 0.2 / 0.35 / 0.5 / 1 Hz (dB) | max amplification (dB) | fade ratio |")
    out = [head, "|" + "---|" * 9]
    for r in sorted(rows, key=lambda r: r["draw"]):
        sup = {row["f_hz"]: row["suppression_db"] for row in r["rows"]}
        refused = ("refused: " + r["violations"][0].split(" at ")[0].replace("|", "")   # no | in a table cell
                   if r["refused_by_control"] else "ok")
        out.append(f"| {r['draw']} | {refused} | {(r.get('observer') or {}).get('factor', 1):g} | "
                   f"{r['pm_deg_min']:.1f} | {r['peak_s_db_max']:+.2f} | {r['f6_hz_measured']:.3f} / "
                   f"{r['f6_predicted_hz']:.3f} / {r['limit_f6_hz']:.3f} | "
                   + " / ".join(f"{sup.get(f, float('nan')):+.1f}" for f in (0.1, 0.2, 0.35, 0.5, 1.0))
                   + f" | {r['max_amplification_db']:+.2f} | {r['tracking_ratio']:.2f} |")
    for key, name in (("f6_hz_measured", "6 dB band measured (Hz)"), ("limit_f6_hz", "limit (Hz)"),
                      ("max_amplification_db", "max amplification (dB)"), ("tracking_ratio", "fade ratio")):
        v = np.array([r[key] for r in rows], dtype=float)
        out.append(f"\n{name}: min {v.min():.3f}, median {np.median(v):.3f}, max {v.max():.3f} (n = {v.size})")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", metavar="JSONL", nargs="+", help="print the markdown table of saved results and stop")
    ap.add_argument("--excess", metavar="JSONL", nargs="+", help="print the model's error as the loop sees it "
                    "(the largest excess of measured over predicted |S_o| per frequency over the saved draws; "
                    "SensitivityError's table, JSON) and stop")
    ap.add_argument("--draws", default="100-104", help="draw numbers, A-B or A,B,C (default 100-104)")
    ap.add_argument("--out", default="control_family.jsonl", help="JSON lines, one per draw (appended)")
    ap.add_argument("--seed", type=int, default=11, help="the bench's noise seed of the measuring runs")
    ap.add_argument("--keep", metavar="DIR", help="keep each draw's identified model there (DIR/N_model.json) and "
                    "reuse one found there instead of recording and identifying again")
    ap.add_argument("--peak-db", type=float, help="the design's |S| target (dB; default: the design's own)")
    ap.add_argument("--frequencies", default=",".join(f"{f:g}" for f in FREQUENCIES))
    ap.add_argument("--structure", default=DEFAULT_STRUCTURE, choices=STRUCTURES,
                    help=f"the controller the design builds (default {DEFAULT_STRUCTURE}, as rtlift design: the "
                         "internal-model controller where the model's training record supports it, else pi)")
    ap.add_argument("--backoff", type=float, help="the internal-model controller's fraction of its band "
                    "(default: the design's own)")
    ap.add_argument("--channel-bound", action=argparse.BooleanOptionalAction, default=YOULA_CHANNEL_BOUND,
                    help="the internal-model design bounds each channel's part of T by 1 + M (default: the design's "
                         f"own, control_design.YOULA_CHANNEL_BOUND = {YOULA_CHANNEL_BOUND})")
    ap.add_argument("--model-error", metavar="JSON", help="the internal-model design is robust to this envelope "
                    "of each channel's multiplicative error (benchmarks/model_error.py --envelope --out JSON; "
                    "'calibration': control_design.MODEL_ERROR_ENVELOPE)")
    ap.add_argument("--train", default="sine_k0125", choices=TRAINS, help="the campaign's training record the "
                    "identification fits (default sine_k0125, the paper's; random: a broadband envelope)")
    ap.add_argument("--envelope", default="recorded", choices=("recorded", "delivered", "auto"),
                    help="rtlift identify's --envelope (default recorded, its own default)")
    ap.add_argument("--band-hz", type=float, help="the internal-model design's band at most this (Hz; the "
                    "programme's further reach spent on margin; default: the design's own)")
    ap.add_argument("--s-error", metavar="JSON", help="the internal-model programme spares this error from every "
                    "|S| bound ('calibration': control_design.YOULA_S_ERROR, 'none', or --excess's JSON; default: "
                    "the design's own)")
    ap.add_argument("--seeds", type=int, default=1, help="measure over this many noise seeds from --seed (the "
                    "gust's part and the fade's RMSEs averaged; default 1)")
    ap.add_argument("--reuse-designs", action="store_true", help="with --keep: measure the design saved there "
                    "(--save-designs) instead of designing again")
    ap.add_argument("--save-designs", action="store_true", help="with --keep: write each draw's design there "
                    "(N_design_STRUCTURE.json, report.json's form) for benchmarks/youla_gap.py")
    args = ap.parse_args()
    if args.table or args.excess:
        rows = [json.loads(line) for path in args.table or args.excess for line in open(path, encoding="utf-8")
                if line.strip()]
        print(table(rows) if args.table else json.dumps(excess(rows)))
        return
    from rtlift.app.control_design import Targets

    freqs = tuple(float(f) for f in args.frequencies.split(","))
    results = []
    done = set()
    if os.path.exists(args.out):        # resume: a draw already in --out is not run again
        done = {json.loads(line)["draw"] for line in open(args.out, encoding="utf-8") if line.strip()}
    with tempfile.TemporaryDirectory() as tmp:
        for n in draws(args.draws):
            if n in done:
                continue
            r = one_draw(n, tmp, freqs, args.seed, args.keep,
                         None if args.peak_db is None else Targets(peak_db=args.peak_db), args.structure,
                         args.backoff, args.channel_bound, args.save_designs, args.model_error, args.train,
                         args.envelope, args.band_hz, args.seeds, args.reuse_designs, args.s_error)
            results.append(r)
            with open(args.out, "a", encoding="utf-8") as fh:
                fh.write(json.dumps(r) + "\n")
            sup = {row["f_hz"]: row["suppression_db"] for row in r["rows"]}
            print(f"draw {n}: design {'REFUSED' if r['refused_by_control'] else 'ok'} "
                  f"(PM {r['pm_deg_min']:.1f} deg, peak {r['peak_s_db_max']:+.2f} dB); 6 dB band measured "
                  f"{r['f6_hz_measured']:.3f} Hz, predicted {r['f6_predicted_hz']:.3f}, limit {r['limit_f6_hz']:.3f}; "
                  f"max amplification {r['max_amplification_db']:+.2f} dB; fade tracking ratio "
                  f"{r['tracking_ratio']:.2f}; " + " ".join(f"{f:g}:{v:+.1f}" for f, v in sup.items())
                  + f" ({r['identify_s']:.0f} + {r['design_s']:.0f} + {r['measure_s']:.0f} s)", flush=True)
    emit({"draws": results})


if __name__ == "__main__":
    main()
