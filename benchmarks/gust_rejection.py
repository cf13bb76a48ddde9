"""Gust rejection: how much of a lift disturbance the feedback removes, measured on the bench
truth beside the design's prediction.

The closed loop is ``rtlift control``'s, in process (:class:`rtlift.app.hil_tracking.
InProcessTracking`: the bench, the firmware's command side, the serial codec, the converter,
the observer, the controller; no pty, not paced). At a constant reference ``--level`` the bench
adds a gust ``A sin(2π f t)`` to its true ΔCL (``--gust``, :mod:`hil_sim.gust`), one frequency
per run, f from 0.05 to 2 Hz. Per f, the true lift's amplitude at f (least-squares sine fit
after ``SETTLE_S``, over whole periods) with feedback over the same with feedforward only is
the suppression (dB, negative = suppressed), beside the design's predicted gust map
|S_o(f)| = |1 − F_o T| at the operating point (:mod:`rtlift.app.control_design`: the observer's
lag included). ``f6_hz``: the frequency up to which the
suppression is ≥ 6 dB (log-interpolated crossing). Then step tracking under a 70 % actuator
fade (the steps of ``benchmarks/control_loop.py``), feedforward only vs feedback, RMSE on the
truth low-passed at 1 Hz; and the envelope at the constant reference without a gust (no limit
cycle at the burst-period update: its burst-to-burst change beside its spread). ``--pty F,F,...``
repeats those frequencies through the real links as ``rtlift control`` runs (a subprocess on the
serial pseudo-terminal of the bench, real time, feedforward and feedback side by side;
:class:`~rtlift.app.hil_tracking.BenchTracking`). ``--peak-db`` sets the design's bound on
|S|. ``--plant-draw N`` measures on plant N of the bench's family (the model given is still
``--model``: :mod:`benchmarks.control_family` identifies each draw's own). ``--hand``
measures the hand-set PI (K_p 0.5, T_i 0.25 s) instead of the design. ``--figure`` draws the
Bode plot of the design with the measured points, and the envelope traces. Prints a table, then
one JSON line.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402
from benchmarks.control_loop import REFERENCES  # noqa: E402
from rtlift.app.control_design import DEFAULT_STRUCTURE  # noqa: E402

ROOT = os.path.join(os.path.dirname(__file__), "..")
FREQUENCIES = (0.05, 0.1, 0.2, 0.25, 0.35, 0.5, 0.7, 1.0, 1.5, 2.0)
SETTLE_S = 6.0
CLAMP_TOL_V = 0.01
"""An envelope within this of 0 V or 200 V counts as clamped (the wire's resolution is 0.01 V)."""
FADE_70 = "actuator_fade:final_fraction=0.7,time_constant_s=0.4"


def sine_amplitude(t: np.ndarray, y: np.ndarray, f_hz: float, t0: float) -> float:
    """Amplitude of the component of ``y`` at ``f_hz`` over the whole periods after ``t0``."""
    periods = math.floor((t[-1] - t0) * f_hz)
    sel = (t >= t0) & (t < t0 + periods / f_hz)
    w = 2 * math.pi * f_hz * t[sel]
    x = np.c_[np.sin(w), np.cos(w), np.ones(sel.sum())]
    c = np.linalg.lstsq(x, y[sel], rcond=None)[0]
    return float(math.hypot(c[0], c[1]))


def crossing_hz(freqs: list[float], db: list[float], level: float = -6.0) -> float:
    """Highest frequency up to which ``db`` stays ≤ ``level`` from the first (log-interpolated)."""
    for i, v in enumerate(db):
        if v > level:
            if i == 0:
                return 0.0
            f0, f1, d0, d1 = freqs[i - 1], freqs[i], db[i - 1], v
            return float(math.exp(math.log(f0) + (level - d0) / (d1 - d0) * (math.log(f1) - math.log(f0))))
    return freqs[-1]


def clamped(t: np.ndarray, envelope_v: np.ndarray, period: int = 50) -> dict:
    """The burst periods after ``SETTLE_S`` whose envelope (V, one value per period of ``period``
    samples) sits at an actuator limit — 0 V or the firmware's ``ENVELOPE_LIMIT_V`` (200 V), within
    ``CLAMP_TOL_V`` — as a fraction, with the envelope's range over them (V)."""
    from rtlift.core.programs import ENVELOPE_LIMIT_V

    per = envelope_v[t >= SETTLE_S][::period]
    at = (per <= CLAMP_TOL_V) | (per >= ENVELOPE_LIMIT_V - CLAMP_TOL_V)
    return {"clamped_fraction": float(at.mean()), "envelope_min_v": float(per.min()),
            "envelope_max_v": float(per.max())}


def in_process(model, config, spec: str, seconds: float, *, seed: int, plant_draw: int = 0,
               gust: str | None = None, effects: tuple[str, ...] = ()):
    """One in-process closed-loop run on plant ``plant_draw`` of the bench's family (0: our bench)."""
    from hil_sim.gust import parse_gust
    from hil_sim.hil import HilStream
    from rtlift.app.control import LiftController
    from rtlift.app.hil_tracking import InProcessTracking

    run = InProcessTracking(model, LiftController(model, config), spec, seconds, seed=seed, effects=effects,
                            gust=gust)
    if plant_draw:
        run.stream = HilStream("random", seed=seed, effects=list(effects), gust=parse_gust(gust),
                               plant_draw=plant_draw)
    return run.run()


def suppression_rows(model, ff_config, fb_config, point, dt: float, *, level: float = 0.08,
                     amplitude: float = 0.01, seed: int = 11, plant_draw: int = 0,
                     frequencies: tuple[float, ...] = FREQUENCIES, seeds: int = 1) -> list[dict]:
    """Per gust frequency f: the true lift's amplitude at f with feedback (``fb_config``) and with
    feedforward only, their ratio in dB (negative = suppressed), ``point``'s predicted |S_o(f)| and
    the feedback run's clamped burst periods (:func:`clamped`).

    The gust's own part: each run is repeated without the gust on the same noise (the same seed), and
    the sine fitted to the difference of the two lifts, y_gust − y_none (linear in the small). A
    feedback run's lift also carries the sensor noise the loop feeds back; its component near f,
    ``floor_db`` (the no-gust run's amplitude at f over the gust's), moved a single 20-s run's ratio
    (``suppression_single_db``, the first seed's) by up to ±1.5 dB at 0.2 Hz on plant draw 126 over
    five seeds, the difference's by ±0.35 dB (docs/results/control.md, "Eleventh pass"). Over
    ``seeds`` seeds (``seed``, ``seed`` + 1, ...) the parts' amplitudes are averaged
    (``suppression_db``) and their spread given (``suppression_sd_db``, the per-seed ratios' standard
    deviation, 0 for one seed)."""
    ref = f"steps:{level}@0"
    rows = []
    for f in frequencies:
        seconds = SETTLE_S + max(12.0, 4.0 / f)
        gust = f"{f:g}:{amplitude:g}"
        part = {"ff": [], "fb": []}
        whole, floor, env = {}, 0.0, None
        for k in range(seeds):
            for name, cfg in (("ff", ff_config), ("fb", fb_config)):
                runs = [in_process(model, cfg, ref, seconds, seed=seed + k, plant_draw=plant_draw, gust=g).traces()
                        for g in (gust, None)]
                (t, y, e), (_, y0, _) = runs
                part[name].append(sine_amplitude(t, y - y0, f, SETTLE_S))
                if k == 0:
                    whole[name] = sine_amplitude(t, y, f, SETTLE_S)
                    if name == "fb":
                        floor, env = sine_amplitude(t, y0, f, SETTLE_S), e
        ratios = 20 * np.log10(np.array(part["fb"]) / np.array(part["ff"]))
        amp_ff, amp_fb = float(np.mean(part["ff"])), float(np.mean(part["fb"]))
        s_pred = abs(point.sensitivity(np.array([f]), dt)[0])
        rows.append({"f_hz": f, "amp_ff": amp_ff, "amp_fb": amp_fb,
                     "suppression_db": 20 * math.log10(amp_fb / amp_ff),
                     "suppression_sd_db": float(np.std(ratios, ddof=1)) if seeds > 1 else 0.0,
                     "suppression_single_db": 20 * math.log10(whole["fb"] / whole["ff"]),
                     "floor_db": 20 * math.log10(floor / amp_ff),
                     "predicted_s_db": 20 * math.log10(s_pred), **clamped(t, env)})
    return rows


def reach_floor(truth: np.ndarray, envelope_v: np.ndarray, reference: np.ndarray,
                hold_s: float = 1.0, fs_hz: float = 400.0) -> tuple[float, float] | None:
    """(reach, floor) of a faded feedback run: ``reach`` the true ΔCL with the envelope held at the
    actuator's limit (200 V, within ``CLAMP_TOL_V``) for at least ``hold_s`` (the median of the
    low-passed truth there), ``floor`` the RMSE (:func:`~rtlift.app.hil_tracking.truth_rmse`) of the
    best lift the faded actuator can give, min(r, reach), against r: what no controller goes below.
    None if the envelope never stayed at the limit that long."""
    from rtlift.app.hil_tracking import lowpass, truth_rmse
    from rtlift.core.programs import ENVELOPE_LIMIT_V

    held = envelope_v >= ENVELOPE_LIMIT_V - CLAMP_TOL_V
    n = int(hold_s * fs_hz)
    run = np.convolve(held.astype(float), np.ones(n), mode="full")[:held.size]   # samples held in the last n
    settled = run >= n
    if not settled.any():
        return None
    reach = float(np.median(lowpass(truth)[settled]))
    return reach, truth_rmse(np.minimum(reference, reach), reference)


def measure(model, fb_config, point, dt: float, *, level: float = 0.08, amplitude: float = 0.01, seed: int = 11,
            plant_draw: int = 0, frequencies: tuple[float, ...] = FREQUENCIES, seeds: int = 1) -> dict:
    """Suppression per gust frequency (feedback over feedforward only, the gust's own part over
    ``seeds`` seeds, :func:`suppression_rows`, with ``point``'s predicted |S_o| beside it), step tracking
    under a 70 % fade (the RMSEs' means over the same seeds; ``tracking_ratio_single`` the first
    seed's), the envelope at a constant reference."""
    from rtlift.app.control import ControlConfig
    from rtlift.app.hil_tracking import reference_values, truth_rmse

    ff_config = ControlConfig(feedback=False, fs_hz=model.fs_hz)
    ref = f"steps:{level}@0"
    rows = suppression_rows(model, ff_config, fb_config, point, dt, level=level, amplitude=amplitude, seed=seed,
                            plant_draw=plant_draw, frequencies=frequencies, seeds=seeds)
    freqs = [r["f_hz"] for r in rows]
    measured = [r["suppression_db"] for r in rows]
    tracking = {"ff": [], "fb": []}
    spec = REFERENCES["steps"]
    floor = None
    for k in range(seeds):
        for name, cfg in (("ff", ff_config), ("fb", fb_config)):
            t, y, env = in_process(model, cfg, spec, 20.0, seed=seed + k, plant_draw=plant_draw,
                                   effects=(FADE_70,)).traces()
            r = reference_values(spec, len(y))
            tracking[name].append(truth_rmse(y, r))
            if name == "fb" and k == 0:
                floor = reach_floor(y, env, r)
    quiet = in_process(model, fb_config, ref, 20.0, seed=seed, plant_draw=plant_draw)
    tq, _, envq = quiet.traces()
    per_period = envq[(tq >= SETTLE_S)][::50]
    steps = np.diff(per_period)
    envelope = {"mean_v": float(per_period.mean()), "std_v": float(per_period.std()),
                "burst_to_burst_rms_v": float(np.sqrt(np.mean(steps ** 2))),
                "lag1_correlation": float(np.corrcoef(per_period[:-1], per_period[1:])[0, 1])}
    return {"rows": rows, "f6_hz_measured": crossing_hz(freqs, measured), "max_amplification_db": max(measured),
            "max_abs_error_below_1hz_db": max(abs(r["suppression_db"] - r["predicted_s_db"])
                                              for r in rows if r["f_hz"] < 1.0),
            "tracking_rmse_ff": float(np.mean(tracking["ff"])), "tracking_rmse_fb": float(np.mean(tracking["fb"])),
            "tracking_ratio": float(np.mean(tracking["fb"]) / np.mean(tracking["ff"])),
            "tracking_ratio_single": tracking["fb"][0] / tracking["ff"][0], "seeds": seeds,
            "tracking_reach": None if floor is None else floor[0],
            "tracking_floor_ratio": None if floor is None else floor[1] / float(np.mean(tracking["ff"])),
            "envelope": envelope, "quiet": quiet}


def main() -> None:
    from rtlift.app.control import ControlConfig
    from rtlift.app.control_design import Targets, design_loop
    from rtlift.model.modelfile import load_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=os.path.join(ROOT, "tests", "data", "bench_model.json"))
    ap.add_argument("--level", type=float, default=0.08, help="constant ΔCL reference (default 0.08)")
    ap.add_argument("--amplitude", type=float, default=0.01, help="gust amplitude, ΔCL (default 0.01)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--plant-draw", type=int, default=0, help="plant N of the bench's family (default 0: our bench)")
    ap.add_argument("--hand", action="store_true", help="the hand-set PI instead of the design")
    ap.add_argument("--figure", metavar="PNG", help="Bode plot with the measured points, envelope traces")
    ap.add_argument("--peak-db", type=float, help="the design's |S| bound (dB, default: the design's own)")
    ap.add_argument("--pty", metavar="F,F,...", help="also measure these frequencies live over the serial pty")
    ap.add_argument("--design", metavar="REPORT.json", help="a saved design (rtlift design's report.json or the "
                    "cache beside the model) instead of designing")
    ap.add_argument("--structure", default=DEFAULT_STRUCTURE, choices=("auto", "pi", "youla"),
                    help=f"the controller the design builds (default {DEFAULT_STRUCTURE}, as rtlift design)")
    ap.add_argument("--backoff", type=float, help="the internal-model controller's fraction of its band "
                    "(default: the design's own)")
    ap.add_argument("--save-design", metavar="JSON", help="write the design made here (report.json's form)")
    args = ap.parse_args()
    model = load_model(args.model)
    t0 = time.perf_counter()
    if args.design:
        from rtlift.app.control_design import load_design
        design = load_design(args.design, accept_warnings=True)
    else:
        extra = {} if args.backoff is None else {"backoff": args.backoff}
        design = design_loop(model, None if args.peak_db is None else Targets(peak_db=args.peak_db),
                             structure=args.structure, **extra)
        if args.save_design:
            from rtlift.app.control_design import report_doc
            from rtlift.core.jsonfile import write_json_atomic
            write_json_atomic(args.save_design, report_doc(design, args.model), stage="design")
    design_s = time.perf_counter() - t0
    fb_config = (ControlConfig(fs_hz=model.fs_hz) if args.hand else design.control_config(fs_hz=model.fs_hz))
    point = min(design.points, key=lambda pt: abs(pt.dcl - args.level))   # a half-way check: the gains run there
    if args.hand:   # the prediction for the hand-set gains on the same lifted plant
        from rtlift.app.control_design import Gains, check_point
        point = check_point(point.cmu, point.dcl, np.asarray(point.plant), np.asarray(point.plant_point),
                            Gains(0.5, design.dt / 0.25), design.dt, np.asarray(point.observer), point.fs_hz,
                            design.uncertainty, tail=point.observer_tail, period=point.observer_period)
    res = measure(design.control_model(model), fb_config, point, design.dt, level=args.level,
                  amplitude=args.amplitude, seed=args.seed,
                  plant_draw=args.plant_draw)
    rows, quiet, envelope = res["rows"], res.pop("quiet"), res["envelope"]
    print(f"gust {args.amplitude:g} ΔCL at reference {args.level:g}; "
          f"{'hand-set PI' if args.hand else 'designed gains'}; in-process bench, seed {args.seed}, "
          f"plant draw {args.plant_draw}")
    print(f"{'f (Hz)':>7} {'A ff':>8} {'A fb':>8} {'measured dB':>12} {'predicted dB':>13}")
    for r in rows:
        print(f"{r['f_hz']:7.2f} {r['amp_ff']:8.5f} {r['amp_fb']:8.5f} {r['suppression_db']:12.2f} "
              f"{r['predicted_s_db']:13.2f}")
    print(f"suppression >= 6 dB up to {res['f6_hz_measured']:.3f} Hz (predicted {point.f6_hz:.3f} Hz, limit "
          f"{point.limit_f6_hz} Hz); largest amplification {res['max_amplification_db']:+.2f} dB; |measured - "
          f"predicted| below 1 Hz <= {res['max_abs_error_below_1hz_db']:.2f} dB")
    print(f"step tracking under a 70 % fade: RMSE ff {res['tracking_rmse_ff']:.4f}, fb {res['tracking_rmse_fb']:.4f}, "
          f"ratio {res['tracking_ratio']:.2f}")
    print(f"envelope at a constant reference: std {envelope['std_v']:.3f} V, burst-to-burst rms "
          f"{envelope['burst_to_burst_rms_v']:.3f} V, lag-1 correlation {envelope['lag1_correlation']:.2f}")
    live = _live(args, point, design) if args.pty else []
    for r in live:
        print(f"live over the serial pty: {r['f_hz']:g} Hz measured {r['suppression_db']:+.2f} dB "
              f"(predicted {r['predicted_s_db']:+.2f} dB; lost {r['lost']}, commands applied {r['applied']})")
    if args.figure:
        _figure(args.figure, design, point, rows, quiet, args)
    emit({**res, "gains": "hand" if args.hand else "design", "level": args.level, "plant_draw": args.plant_draw,
          "amplitude": args.amplitude, "peak_db_target": design.targets.peak_db, "structure": design.structure,
          "loop": "in-process (InProcessTracking)",
          "f6_hz_predicted": point.f6_hz, "limit_f6_hz": point.limit_f6_hz,
          "design": {"gm_db": point.gm_db, "pm_deg": point.pm_deg, "crossover_hz": point.crossover_hz,
                     "peak_s_db": point.peak_s_db, "seconds": design_s, "violations": design.violations()},
          "live_rows": live})


def _live(args, point, design) -> list[dict]:
    """The ``--pty`` frequencies through ``rtlift control`` on the serial pty, real time."""
    import tempfile

    from rtlift.app.hil_tracking import BenchTracking

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for f in (float(x) for x in args.pty.split(",")):
            seconds = SETTLE_S + max(12.0, 3.0 / f)
            runs = {fb: BenchTracking(args.model, f"steps:{args.level}@0", fb, seconds,
                                      os.path.join(tmp, f"{f}_{fb}.json"), seed=args.seed, effects=(),
                                      gust=f"{f:g}:{args.amplitude:g}").start() for fb in (False, True)}
            amp, counts = {}, {}
            for fb, run in runs.items():
                counts[fb] = run.finish()
                t, y, _ = run.traces()
                amp[fb] = sine_amplitude(t, y, f, SETTLE_S)
            s_pred = abs(point.sensitivity(np.array([f]), design.dt)[0])
            out.append({"f_hz": f, "amp_ff": amp[False], "amp_fb": amp[True],
                        "suppression_db": 20 * math.log10(amp[True] / amp[False]),
                        "predicted_s_db": 20 * math.log10(s_pred), "lost": counts[True]["lost"],
                        "applied": f"{counts[True]['commands_applied']}/{counts[True]['commands_sent']}"})
    return out


def _figure(path: str, design, point, rows: list[dict], quiet, args) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = np.geomspace(0.02, 3.9, 400)
    s = 20 * np.log10(np.abs(point.sensitivity(f, design.dt)))
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 7))
    a1.semilogx(f, s, label="predicted |S_o| = |1 - F_o T| (design, with the observer)")
    a1.semilogx([r["f_hz"] for r in rows], [r["suppression_db"] for r in rows], "o", label="measured on the bench")
    a1.axhline(-6, ls=":", c="k")
    a1.axhline(3, ls=":", c="r")
    a1.set_xlabel("gust frequency (Hz)")
    a1.set_ylabel("lift with feedback / feedforward only (dB)")
    a1.legend()
    a1.grid(True, which="both", alpha=0.3)
    t, y, env = quiet.traces()
    a2.plot(t, env, label="envelope (V)")
    a2.set_xlabel("t (s) at a constant reference, no gust")
    a2.set_ylabel("envelope (V)")
    a2.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
