"""Where the identified model's loop is wrong: its lifted burst-rate plant against the truth's, and
what that does to the predicted gust map.

For each plant draw (``--draws 0-3``: our bench and calibration draws 1–3; never a reporting draw
for a choice) and each operating point the design schedules (:data:`~rtlift.app.control_design.
SCHEDULE_FRACTIONS` of the model's ΔCL range, and half-way between them in Cμ), the lifted plant
of the module docstring of :mod:`rtlift.app.control_design` (P_A: the period's mean, P_X: the
latest value; ΔCL per ΔCL of the controller's output v, through the controller's inverse static
map) is computed twice by the same code (:func:`~rtlift.app.control_design.lifted_plant`): on the
identified model, and on the draw's truth plant (:class:`hil_sim.plant.TruthPlant`, noise-free,
from the same Cμ; ``sensed``: through the draw's balance mode and DAQ filter too, what the
observer sees). The relative error e(f) = P_model/P_true − 1 at the burst rate's frequencies
(0.05–2 Hz) is split into

- the static (DC) gain ratio ΣP_model/ΣP_true − 1 (the static map's slope at the point), and
- the shape: the error left after each plant is scaled to unit DC gain;

and at the half-way points the schedule's own error: the model's internal plant interpolated in
Cμ between its neighbours (as :func:`~rtlift.app.control.youla_at` runs it) against the model at
that point.

``--design`` (with ``--structure``/``--backoff``) then designs the loop on each draw's model (or
reuses ``--keep``'s ``N_design_STRUCTURE.json``: the map is computed again from the model's pulse
response, so a design of version 6, without one, is evaluated too) and,
at the point the loop runs (the checked point nearest ΔCL 0.08), evaluates the gust map three ways
with the design's controller K = (K_A, K_X) and the observer's F_o:

    model:   S_o = 1 − F_o G_y (K_A M + K_X)/(1 + L)   (the design's, :func:`~rtlift.app.control_design.gust_map`)
    lifted:  1 − F_o L/(1 + L)                          (what the design predicted before version 7)
    truth:   the design's map with the truth's pulse response in G_y and L_eff = K·P_eff,
             P_eff = P_model (1 − F_o) + F_o P_sensed   (the estimate of a plant that is not the model)

beside the measured suppression of ``--measured JSONL`` (``benchmarks/control_family.py``'s
output for the same design), so one can see whether the truth's plant explains the measured −
predicted difference. Prints tables, then one JSON line.

The truth is fed the model's Cμ directly (no drive-voltage quantisation: the host's and the
rig's κ are equal, 6.11e-7 V⁻²; the ±2 % pulse would be quantised to 0.01 V otherwise).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402

ROOT = os.path.join(os.path.dirname(__file__), "..")
FREQS = (0.05, 0.1, 0.2, 0.25, 0.35, 0.5, 0.7, 1.0, 1.5, 2.0)
BAND = (0.2, 0.35)


def band_max(values: list[float]) -> float:
    """The largest of ``values`` (one per :data:`FREQS`) over :data:`BAND`."""
    return max(v for f, v in zip(FREQS, values, strict=True) if BAND[0] <= f <= BAND[1])


def truth_simulator(draw: int, sensed: bool = False):
    """``simulate(cmu, cmu_envelope) -> ΔCL`` of plant ``draw``'s truth from rest, noise-free;
    ``sensed``: through the draw's balance mode and anti-alias filter (unit DC gain)."""
    from hil_sim.family import plant_draw
    from hil_sim.plant import TruthPlant
    from hil_sim.sensors import BalanceChain

    pd = plant_draw(draw)

    def simulate(cmu: np.ndarray, env: np.ndarray) -> np.ndarray:
        y = TruthPlant(pd.plant).process(cmu, env)["dcl"]
        if sensed:
            chain = BalanceChain(pd.sensor)
            x = y[:, None]
            for stage in (chain.mode, chain.filter):
                if stage is not None:
                    x = stage.process(x)
            y = x[:, 0]
        return y

    return simulate


def relative_error(pm: np.ndarray, pt: np.ndarray, z: np.ndarray) -> dict:
    """|P_m/P_t − 1|, ∠(P_m/P_t) (deg) on ``z``, the DC ratio − 1 and the shape's |error| (both at unit DC)."""
    from rtlift.app.control_design import plant_response

    rm, rt = plant_response(pm, z), plant_response(pt, z)
    ratio = rm / rt
    dc = float(np.sum(pm) / np.sum(pt))
    return {"mag": np.abs(ratio - 1.0), "phase_deg": np.degrees(np.angle(ratio)), "dc": dc - 1.0,
            "delta": np.abs(1.0 / ratio - 1.0),
            "shape": np.abs(ratio / dc - 1.0), "gain_db": 20 * np.log10(np.abs(ratio))}


def model_for(draw: int, keep: str | None) -> str:
    """The draw's identified model file (draw 0: ``keep``'s 0_model.json if there, else the bench
    model of tests/data; others as ``benchmarks/control_family.py`` identifies them, kept in ``keep``)."""
    if draw == 0 and not (keep and os.path.exists(os.path.join(keep, "0_model.json"))):
        return os.path.join(ROOT, "tests", "data", "bench_model.json")
    from benchmarks.control_family import identified_model

    return identified_model(draw, tempfile.mkdtemp(), keep)


def plant_errors(model, draw: int, f: np.ndarray) -> list[dict]:
    """Per scheduled and half-way point: the model's and the truth's lifted plants and their errors."""
    from rtlift.app.control import ControlConfig, LiftController
    from rtlift.app.control_design import SCHEDULE_FRACTIONS, lifted_plant, plant_response

    cfg = ControlConfig(fs_hz=model.fs_hz)
    ctl = LiftController(model, cfg)
    z = np.exp(2j * np.pi * f * cfg.period / cfg.fs_hz)
    sims = {"true": truth_simulator(draw), "sensed": truth_simulator(draw, sensed=True)}
    sched = [ctl.dcl_min + fr * (ctl.dcl_max - ctl.dcl_min) for fr in SCHEDULE_FRACTIONS]
    cmus = [ctl.inverse(d) for d in sched]
    half = [0.5 * (a + b) for a, b in zip(cmus, cmus[1:], strict=False)]
    points = [(c, True) for c in cmus] + [(c, False) for c in half]
    model_p = {}
    out = []
    for cmu, designed in sorted(points):
        dcl0 = float(np.interp(cmu, ctl._map_cmu, ctl._map_dcl))
        pm = lifted_plant(model, ctl, dcl0, period=cfg.period)
        model_p[cmu] = pm
        row = {"cmu": cmu, "dcl": dcl0, "scheduled": designed, "p_model": [list(map(float, v)) for v in pm]}
        for name, sim in sims.items():
            pt = lifted_plant(model, ctl, dcl0, period=cfg.period, simulate=sim)
            row[f"p_{name}"] = [list(map(float, v)) for v in pt]
            for ch, k in (("A", 0), ("X", 1)):
                e = relative_error(pm[k], pt[k], z)
                row[f"{name}_{ch}"] = {key: (v.tolist() if isinstance(v, np.ndarray) else v) for key, v in e.items()}
        out.append(row)
    for row in out:                       # the schedule's own error half-way (the model interpolated in Cμ)
        if row["scheduled"]:
            continue
        lo = max(c for c in cmus if c < row["cmu"])
        hi = min(c for c in cmus if c > row["cmu"])
        w = (row["cmu"] - lo) / (hi - lo)
        for ch, k in (("A", 0), ("X", 1)):
            interp = model_p[lo][k] + w * (model_p[hi][k] - model_p[lo][k])
            ratio = plant_response(interp, z) / plant_response(model_p[row["cmu"]][k], z)
            row[f"schedule_{ch}"] = {"mag": np.abs(ratio - 1.0).tolist(),
                                     "phase_deg": np.degrees(np.angle(ratio)).tolist()}
    return out


ENVELOPE_FREQS = tuple(float(v) for v in np.r_[0.05, np.arange(0.125, 4.0001, 0.125)])
"""Where ``--envelope`` evaluates the error (Hz): to the burst rate's Nyquist frequency, 0.125 Hz apart."""


def error_envelope(rows_by_draw: dict[int, list[dict]], kinds: tuple[str, ...] = ("true", "sensed")) -> dict:
    """The multiplicative error's envelope δ_ch(f) = max |P_true/P_model − 1| (the Δ of P_true =
    P_model (1 + Δ)) per channel (A: the period's mean, X: the latest value) over every draw, every
    scheduled and half-way point and ``kinds`` ("true": the lift the gust is measured on; "sensed":
    through the balance and the DAQ filter, what the loop feeds back), on :data:`ENVELOPE_FREQS`;
    and each draw's own."""
    out: dict = {"f_hz": list(ENVELOPE_FREQS), "draws": sorted(rows_by_draw), "per_draw": {}, "kinds": list(kinds)}
    for ch in ("A", "X"):
        per = {n: np.max([r[f"{kind}_{ch}"]["delta"] for r in rows for kind in kinds], axis=0)
               for n, rows in rows_by_draw.items()}
        out[f"delta_{ch}"] = np.max(list(per.values()), axis=0).tolist()
        for n, v in per.items():
            out["per_draw"].setdefault(str(n), {})[ch] = v.tolist()
    return out


def gust_maps(design, model, draw: int, f: np.ndarray) -> dict:
    """At the point the loop runs: the gust map predicted on the model (:func:`~rtlift.app.control_design.
    gust_map`), the lifted form 1 − F_o T it replaced, and the same map with the truth's plant (module
    docstring): S_o = 1 − F_o G_y,true (K_A M + K_X)/(1 + L_eff), L_eff = K·P_eff."""
    from rtlift.app.control import ControlConfig, LiftController
    from rtlift.app.control_design import gust_map, lift_pulse, plant_response, pulse_response

    point = min(design.points, key=lambda pt: abs(pt.dcl - 0.08))
    ctl = LiftController(model, ControlConfig(fs_hz=model.fs_hz))
    z = np.exp(2j * np.pi * f * design.dt)
    parts = point.gains.parts(z)
    fo = point.observer_response(f)
    lm = point.loop_response(f, design.dt)
    true_pulse = pulse_response(model, ctl, point.dcl, simulate=truth_simulator(draw))
    sensed = [plant_response(v, z) for v in lift_pulse(pulse_response(model, ctl, point.dcl,
                                                                      simulate=truth_simulator(draw, True)))]
    pm = [plant_response(np.asarray(v), z) for v in (point.plant, point.plant_point)]
    peff = [m * (1.0 - fo) + fo * s for m, s in zip(pm, sensed, strict=True)]
    leff = parts[0] * peff[0] + parts[1] * peff[1]

    def db(s: np.ndarray) -> list[float]:
        return (20 * np.log10(np.abs(s))).tolist()

    return {"dcl": point.dcl, "scheduled": point.designed, "f_hz": f.tolist(),
            "model_db": db(gust_map(f, design.dt, point.fs_hz, lm, parts, fo,
                                    pulse_response(model, ctl, point.dcl))),
            "lifted_db": db(gust_map(f, design.dt, point.fs_hz, lm, parts, fo, [])),
            "truth_db": db(gust_map(f, design.dt, point.fs_hz, leff, parts, fo, true_pulse)),
            "T_abs": np.abs(lm / (1.0 + lm)).tolist(),
            "K_A_abs": np.abs(parts[0]).tolist(), "K_X_abs": np.abs(parts[1]).tolist()}


def main() -> None:
    from benchmarks.control_family import draws as parse_draws
    from rtlift.model.modelfile import load_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", default="0-3", help="plant draws, A-B or A,B (default 0-3: the bench, calibration 1-3)")
    ap.add_argument("--keep", metavar="DIR", help="the draws' identified models (DIR/N_model.json; made if missing)")
    ap.add_argument("--design", action="store_true", help="also design each draw's loop and compare the gust maps")
    ap.add_argument("--structure", default="youla", choices=("pi", "youla"))
    ap.add_argument("--backoff", type=float, help="the Youla controller's back-off (default: the design's)")
    ap.add_argument("--measured", metavar="JSONL", nargs="*", default=[],
                    help="control_family.py results of the same designs: measured suppression beside the maps")
    ap.add_argument("--out", metavar="JSON", help="write every number here too")
    ap.add_argument("--envelope", action="store_true", help="only the multiplicative error's envelope over the "
                    "draws (control_design.MODEL_ERROR_ENVELOPE's source; calibration draws only)")
    args = ap.parse_args()
    if args.envelope:
        t0 = time.process_time()
        rows = {n: plant_errors(load_model(model_for(n, args.keep)), n, np.array(ENVELOPE_FREQS))
                for n in parse_draws(args.draws)}
        for kinds in (("true",), ("sensed",), ("true", "sensed")):
            env = error_envelope(rows, kinds)
            print(f"{'+'.join(kinds)}: f (Hz) / delta_A / delta_X (envelope) / per draw A,X")
            for i, fv in enumerate(ENVELOPE_FREQS):
                print(f"  {fv:5.3f}  {env['delta_A'][i]:6.3f}  {env['delta_X'][i]:6.3f}   " + "  ".join(
                    f"{n}:{d['A'][i]:.3f},{d['X'][i]:.3f}" for n, d in env["per_draw"].items()))
        env["cpu_s"] = time.process_time() - t0
        if args.out:
            with open(args.out, "w", encoding="utf-8") as fh:
                json.dump(env, fh)
        emit({k: env[k] for k in ("f_hz", "delta_A", "delta_X", "draws", "cpu_s")})
        return
    f = np.array(FREQS)
    measured = {}
    for path in args.measured:
        for line in open(path, encoding="utf-8"):
            if line.strip():
                r = json.loads(line)
                measured[r["draw"]] = {row["f_hz"]: row["suppression_db"] for row in r["rows"]}
    results = []
    for n in parse_draws(args.draws):
        t0 = time.process_time()
        path = model_for(n, args.keep)
        model = load_model(path)
        rows = plant_errors(model, n, f)
        res = {"draw": n, "model": path, "points": rows}
        print(f"\ndraw {n} ({path}): P_model/P_true - 1 (true lift) per point; |e| in %, phase in deg, at "
              + ", ".join(f"{v:g}" for v in FREQS) + " Hz")
        for r in rows:
            for ch in ("A", "X"):
                e, es = r[f"true_{ch}"], r[f"sensed_{ch}"]
                print(f"  dCL {r['dcl']:.3f} {'sched' if r['scheduled'] else 'half '} {ch}: DC {100 * e['dc']:+.1f} %; "
                      "|e| " + " ".join(f"{100 * v:5.1f}" for v in e["mag"]) + " | phase "
                      + " ".join(f"{v:+5.1f}" for v in e["phase_deg"])
                      + f" | shape |e| at 0.2-0.35 Hz max {100 * band_max(e['shape']):.1f} %"
                      + f" | sensed phase at 0.35 Hz {es['phase_deg'][FREQS.index(0.35)]:+.1f}")
                if not r["scheduled"]:
                    s = r[f"schedule_{ch}"]
                    print("      schedule (model interpolated / model): |e| "
                          + " ".join(f"{100 * v:5.1f}" for v in s["mag"])
                          + " | phase " + " ".join(f"{v:+5.1f}" for v in s["phase_deg"]))
        if args.design:
            from rtlift.app.control_design import design_loop, load_design

            extra = {} if args.backoff is None else {"backoff": args.backoff}
            saved = os.path.join(args.keep or "", f"{n}_design_{args.structure}.json")
            if args.keep and os.path.exists(saved):      # a design kept by an earlier run: reused
                design = load_design(saved, accept_warnings=True)
            else:
                design = design_loop(model, structure=args.structure, **extra)
            if args.keep and not os.path.exists(saved):  # kept in report.json's form (gust_rejection.py --design)
                from rtlift.app.control_design import report_doc
                from rtlift.core.jsonfile import write_json_atomic

                write_json_atomic(saved, report_doc(design, path), stage="design")
            maps = gust_maps(design, model, n, f)
            res["gust"] = maps
            meas = measured.get(n, {})
            print(f"  gust map at dCL {maps['dcl']:.3f} ({args.structure}): f / measured / predicted (the design's "
                  "map) / the lifted 1 - F_o T / the map with the truth's plant (dB)")
            for i, fv in enumerate(FREQS):
                mv = meas.get(fv, math.nan)
                print(f"    {fv:5.2f}  {mv:+6.2f}  {maps['model_db'][i]:+6.2f}  {maps['lifted_db'][i]:+6.2f}  "
                      f"{maps['truth_db'][i]:+6.2f}   |T| {maps['T_abs'][i]:.2f} |K_A| {maps['K_A_abs'][i]:.1f} "
                      f"|K_X| {maps['K_X_abs'][i]:.1f}")
            res["measured"] = meas
        res["cpu_s"] = time.process_time() - t0
        results.append(res)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            json.dump(results, fh)
    emit({"draws": [{"draw": r["draw"], "cpu_s": r["cpu_s"],
                     "max_err_0p2_0p35": max(max(v for fv, v in zip(FREQS, p["true_A"]["mag"], strict=True)
                                                 if BAND[0] <= fv <= BAND[1]) for p in r["points"])}
                    for r in results]})


if __name__ == "__main__":
    main()
