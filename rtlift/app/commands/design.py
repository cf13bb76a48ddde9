"""``rtlift design --model M --out DIR``: the lift loop's feedback designed from the model with
python-control (:mod:`rtlift.app.control_design`), and its report.

Writes ``DIR/report.json`` (per operating point of the Cμ schedule and half-way between: the
lifted plant, the observer's response, the gains, every gain and phase crossover up to Nyquist,
peak |S|, max |W T|, f₆ and the limit any causal controller reaches, predicted |S_o| at the gust
frequencies, and the targets missed), ``DIR/report.md`` (the same) and ``DIR/bode.png``. Exit 1
when a target is missed (one line each on stderr: the target, the value, what binds it); the report
is written either way, and ``rtlift control --design`` refuses it unless
``--accept-design-warnings``. ``--peak-db`` trades the largest amplification allowed anywhere
against the rejection bandwidth.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("design", help="design the lift loop's feedback from a model (python-control)",
                              description="Design the lift loop's feedback from the model with python-control: "
                                          "per operating point of a Cμ schedule, a PI with lead-lag for the gain "
                                          "and phase margins asked, the widest disturbance rejection the peak |S| "
                                          "allows; writes report.json, report.md and a Bode figure (bode.png). "
                                          "rtlift control uses the same design by default.")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file")
    p.add_argument("--out", required=True, metavar="DIR", help="report directory (created)")
    p.add_argument("--gm-db", type=float, default=6.0, help="gain margin at least (dB, default 6)")
    p.add_argument("--pm-deg", type=float, default=45.0, help="phase margin at least (degrees, default 45)")
    p.add_argument("--structure", default="auto", choices=("auto", "pi", "pi2", "pi2j", "youla"),
                   help="the controller: auto (default: youla where the model's training record reaches past "
                        "its loop and its design meets every target without a caution, else pi; the report says "
                        "which and why), pi (PI + lead-lag + K_x), pi2 (the same with a second lead-lag), "
                        "pi2j (pi2, then its scheduled points searched together with the half-way checks) or "
                        "youla (the internal-model controller from the Youla parameter)")
    p.add_argument("--peak-db", type=float,
                   help="largest predicted |S| at any frequency (dB; default: the target set on the plant "
                        "family's calibration draws, docs/results/control.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rtlift.app.control_design import Targets, design_loop
    from rtlift.model.modelfile import load_model

    if args.peak_db is None:
        args.peak_db = Targets().peak_db
    for name, lo, hi in (("gm_db", 0.0, 40.0), ("pm_deg", 0.0, 89.0), ("peak_db", 0.5, 20.0)):
        v = getattr(args, name)
        if not (math.isfinite(v) and lo <= v <= hi):
            raise UserError(f"--{name.replace('_', '-')} must be in [{lo:g}, {hi:g}], got {v:g}")
    model = load_model(args.model)
    targets = Targets(args.gm_db, args.pm_deg, args.peak_db)
    design = design_loop(model, targets, structure=args.structure)
    write_report(design, args.out, str(args.model))
    s = design.summary()
    gm = "inf" if s["gm_db_min"] is None else f"{s['gm_db_min']:.1f}"
    limit = "n/a" if s["limit_f6_hz_min"] is None else f"{s['limit_f6_hz_min']:.3f}"
    if s["limit_with_error_hz"] is not None:
        limit += f"; with the model's error spared: {s['limit_with_error_hz']:.3f}"
    if s["limit_with_noise_hz"] is not None:
        limit += f"; with the sensor noise bounded too: {s['limit_with_noise_hz']:.3f}"
    if s["programme_band_hz"] is not None:
        limit += f"; this controller's programme: {s['programme_band_hz']:.3f}"
    print(f"rtlift design: {design.structure} controller, {len(design.scheduled)} scheduled points, "
          f"{len(design.points)} checked; gain margin "
          f">= {gm} dB, phase margin >= {s['pm_deg_min']:.1f} deg (every crossover to Nyquist), |S| <= "
          f"{s['peak_s_db_max']:+.2f} dB, max |W T| {s['robust_max']:.2f}; 6 dB of rejection up to >= "
          f"{s['f6_hz_min']:.3f} Hz (limit for any causal controller: {limit} Hz) -> {args.out}")
    if design.choice:
        print(f"rtlift design: chose the {design.choice}")
    for line in s["violations"]:
        print(f"rtlift design: target missed: {line}", file=sys.stderr)
    for line in s["cautions"]:
        print(f"rtlift design: caution: {line}", file=sys.stderr)
    return 1 if s["violations"] else 0


def write_report(design, out: str, model: str) -> None:
    """``out/report.json``, ``out/report.md`` and ``out/bode.png`` of a design."""
    from rtlift.app.control_design import report_doc
    from rtlift.core.jsonfile import write_json_atomic

    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {out}: cannot create the directory ({exc.strerror or exc})") from None
    doc = report_doc(design, model)
    write_json_atomic(os.path.join(out, "report.json"), doc, stage="design")
    _bode(design, os.path.join(out, "bode.png"))
    with open(os.path.join(out, "report.md"), "w", encoding="utf-8") as fh:
        fh.write(_markdown(design, doc, model))


def _markdown(design, doc: dict, model: str) -> str:
    t, u, s = design.targets, design.uncertainty, doc["summary"]
    lines = [f"# Lift-loop design for `{model}`", "",
             f"Burst-rate loop (T = {design.dt:g} s, decisions {design.margin} samples before each onset); "
             f"targets: gain margin >= {t.gm_db:g} dB (up and down), phase margin >= {t.pm_deg:g} deg, "
             f"|S| <= {t.peak_db:g} dB (the loop's and the gust's with the observer), robust stability "
             f"max |W T| < 1 with W = {u.gain:.2f} + {1 + u.gain:.2f} |1 - exp(-j w {u.delay_s:g} s)| ({u.source}). "
             + ("v - r = C(Z) e_mean + Kx (e_last - e_mean), C(Z) = (Kp + Ki Z/(Z-1)) g (Z-a)/(Z-b)"
                + (" g2 (Z-c)/(Z-d), " if design.structure == "pi2" else ", ")
                if design.structure != "youla" else
                "the internal-model controller v - r = w = Q_A ê_mean + Q_X ê_last, ê = e + P w (Q: FIR taps in "
                "report.json; K = Q/(1 - Q P)); ")
             + "in ΔCL per ΔCL. Margins from every crossover of L up to Nyquist (4 Hz) on a 2000-point grid; "
             "rows marked 'check' are half-way between scheduled points, at the interpolated gains.", "",
             *([f"**Structure:** {design.choice}.", ""] if design.choice else []),
             "**Targets missed:** " + ("none" if not s["violations"] else ""), ""]
    if design.reach:
        r = design.reach
        spared = r.get("s_error")
        lines[-1:-1] = ["**The band's limits:** any causal controller on the model, noise-free: "
                        + ("n/a" if s["limit_f6_hz_min"] is None else f"{s['limit_f6_hz_min']:.3f} Hz")
                        + ("" if r.get("limit_with_error_hz") is None else
                           f"; the same with the model's measured error spared from every bound ({spared}): "
                           f"{r['limit_with_error_hz']:.3f} Hz")
                        + ("" if r.get("limit_with_noise_hz") is None else
                           "; the same with each channel's part of T bounded as this design bounds it (the "
                           f"sensor's noise): {r['limit_with_noise_hz']:.3f} Hz")
                        + "; this controller's programme with every bound exact, each channel's part of T "
                        "bounded (the sensor's noise)" + ("" if spared is None else ", the model's error spared")
                        + f" and a depth margin of {r['depth_db']:g} dB: "
                        f"{r['programme_band_hz']:.3f} Hz; designed for {r['asked_band_hz']:.3f} Hz "
                        f"({r['fraction']:.2f} of it: back-off {r['backoff']:g}"
                        + ("" if r["band_cap_hz"] is None else f", at most {r['band_cap_hz']:g} Hz") + ").", ""]
    lines += [f"- {v}" for v in s["violations"]]
    if s["cautions"]:
        lines += ["", "**Cautions** (targets met on the model, which is extrapolated here):", ""]
        lines += [f"- {c}" for c in s["cautions"]]
    two = design.structure == "pi2"
    head = ("Kp | Ti (s) | a | b | Kx" + (" | c | d" if two else "") if design.structure != "youla" else
            "Q_A(1) | sum abs Q_A | Q_X(-1) | gain at 4 Hz | -")
    lines += ["", f"| Cμ | ΔCL | {head} | GM up/down (dB) | PM (deg) | gain crossovers (Hz) "
              "| max abs S (dB) at (Hz) | max abs W T | f6 (Hz) | limit f6 (Hz) |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|---|" if two else "")]
    for p in design.points:
        m = p.margins
        gm = "/".join("inf" if not math.isfinite(v) else f"{v:.1f}" for v in (m.gm_db, m.gm_low_db))
        xs = ", ".join(f"{fc:.2f}" for fc, _ in m.gain_crossovers)
        lim = "check" if not p.designed else ("n/a" if p.limit_f6_hz is None else f"{p.limit_f6_hz:.3f}")
        g = p.gains
        cols = ((g.kp, design.dt / g.ki, g.a, g.b, g.kx) + ((g.c, g.d) if two else ())
                if design.structure != "youla" else
                (sum(g.qa), sum(map(abs, g.qa)), sum(v * (-1) ** k for k, v in enumerate(g.qx)), g.nyquist_gain(), 0.0))
        lines.append(f"| {p.cmu:.4f} | {p.dcl:.3f} | " + " | ".join(f"{v:.3f}" for v in cols) + f" | {gm} | "
                     f"{p.pm_deg:.1f} | {xs} | "
                     f"{p.peak_s_db:+.2f} at {m.peak_s_hz:.2f} | {m.robust:.2f} | {p.f6_hz:.3f} | {lim} |")
    ps = doc["predicted_s_db"]
    lines += ["", "Predicted gust map |S_o| = |1 - F_o T| (dB) at the gust frequencies:", "",
              "| f (Hz) | " + " | ".join(f"ΔCL {p.dcl:.3f}" for p in design.points) + " |",
              "|---|" + "---|" * len(design.points)]
    for i, f in enumerate(ps["f_hz"]):
        lines.append(f"| {f:g} | " + " | ".join(f"{row[i]:+.2f}" for row in ps["points"]) + " |")
    lines += ["", "![Bode](bode.png)", ""]
    return "\n".join(lines)


def _bode(design, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    f = np.geomspace(0.02, 0.5 / design.dt, 500)
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    for p in design.points:
        L = p.loop_response(f, design.dt)
        label = f"ΔCL {p.dcl:.3f}"
        axes[0].semilogx(f, 20 * np.log10(np.abs(L)), label=label)
        axes[1].semilogx(f, np.degrees(np.unwrap(np.angle(L))), label=label)
        axes[2].semilogx(f, 20 * np.log10(np.abs(p.sensitivity(f, design.dt))), label=label)
    axes[0].axhline(0, c="k", lw=0.6)
    axes[1].axhline(-180, c="k", lw=0.6)
    axes[2].axhline(-6, c="k", ls=":")
    axes[2].axhline(design.targets.peak_db, c="r", ls=":")
    axes[0].set_ylabel("|L| (dB)")
    axes[1].set_ylabel("∠L (deg)")
    axes[2].set_ylabel("|S_o| (dB)")
    axes[2].set_xlabel("frequency (Hz)")
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    fig.suptitle("Lift loop L = C P at the burst rate (design from the model)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
