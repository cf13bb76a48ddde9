"""``rtlift design --model M --out DIR``: the lift loop's feedback designed from the model with
python-control (:mod:`rtlift.app.control_design`), and its report.

Writes ``DIR/report.json`` (per operating point of the Cμ schedule: the lifted plant, the
gains, gain and phase margins, crossover, peak |S|, f₆, predicted |S| at the gust
frequencies), ``DIR/report.md`` and ``DIR/bode.png`` (|L|, ∠L and |S| of each point). The gains
are the ones ``rtlift control`` uses by default. ``--peak-db`` trades the largest amplification
allowed anywhere against the rejection bandwidth.
"""

from __future__ import annotations

import argparse
import math
import os

from rtlift.core.errors import UserError

REPORT_FREQUENCIES = (0.05, 0.1, 0.2, 0.25, 0.35, 0.5, 0.7, 1.0, 1.5, 2.0)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("design", help="design the lift loop's feedback from a model (python-control)",
                              description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file")
    p.add_argument("--out", required=True, metavar="DIR", help="report directory (created)")
    p.add_argument("--gm-db", type=float, default=6.0, help="gain margin at least (dB, default 6)")
    p.add_argument("--pm-deg", type=float, default=45.0, help="phase margin at least (degrees, default 45)")
    p.add_argument("--peak-db", type=float, default=4.0,
                   help="largest predicted |S| at any frequency (dB, default 4: the model over-predicts "
                        "the bench's loop gain by about 1.5 dB)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rtlift.app.control_design import Targets, design_loop
    from rtlift.model.modelfile import load_model

    for name, lo, hi in (("gm_db", 0.0, 40.0), ("pm_deg", 0.0, 89.0), ("peak_db", 0.5, 20.0)):
        v = getattr(args, name)
        if not (math.isfinite(v) and lo <= v <= hi):
            raise UserError(f"--{name.replace('_', '-')} must be in [{lo:g}, {hi:g}], got {v:g}")
    model = load_model(args.model)
    targets = Targets(args.gm_db, args.pm_deg, args.peak_db)
    design = design_loop(model, targets)
    write_report(design, args.out, str(args.model))
    s = design.summary()
    gm = "inf" if s["gm_db_min"] is None else f"{s['gm_db_min']:.1f}"
    print(f"rtlift design: {len(design.points)} operating points; gain margin >= {gm} dB, "
          f"phase margin >= {s['pm_deg_min']:.1f} deg, |S| <= {s['peak_s_db_max']:+.2f} dB, 6 dB of rejection "
          f"up to >= {s['f6_hz_min']:.3f} Hz -> {args.out}")
    return 0


def write_report(design, out: str, model: str) -> None:
    """``out/report.json``, ``out/report.md`` and ``out/bode.png`` of a design."""
    import numpy as np

    from rtlift.core.jsonfile import write_json_atomic

    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {out}: cannot create the directory ({exc.strerror or exc})") from None
    f = np.array(REPORT_FREQUENCIES)
    doc = {"version": 1, "model": model, **design.to_dict(),
           "predicted_s_db": {"f_hz": list(REPORT_FREQUENCIES),
                              "points": [[20 * math.log10(abs(s)) for s in p.sensitivity(f, design.dt)]
                                         for p in design.points]}}
    doc = _finite(doc)
    write_json_atomic(os.path.join(out, "report.json"), doc, stage="design")
    _bode(design, os.path.join(out, "bode.png"))
    with open(os.path.join(out, "report.md"), "w", encoding="utf-8") as fh:
        fh.write(_markdown(design, doc, model))


def _finite(x):
    """Non-finite numbers (an infinite gain margin: no phase crossover) as ``None``."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def _markdown(design, doc: dict, model: str) -> str:
    t = design.targets
    lines = [f"# Lift-loop design for `{model}`", "",
             f"Burst-rate loop (T = {design.dt:g} s, decisions {design.margin} samples before each onset); "
             f"targets: gain margin >= {t.gm_db:g} dB, phase margin >= {t.pm_deg:g} deg, "
             f"|S| <= {t.peak_db:g} dB. "
             "v - r = C(Z) e_mean + Kx (e_last - e_mean), C(Z) = (Kp + Ki Z/(Z-1)) g (Z-a)/(Z-b), "
             "in ΔCL per ΔCL; margins and crossover from python-control (`stability_margins`).", "",
             "| Cμ | ΔCL | Kp | Ti (s) | a | b | Kx | GM (dB) | PM (deg) | crossover (Hz) | max abs S (dB) "
             "| f6 (Hz) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in design.points:
        gm = "inf" if not math.isfinite(p.gm_db) else f"{p.gm_db:.1f}"
        lines.append(f"| {p.cmu:.4f} | {p.dcl:.3f} | {p.gains.kp:.3f} | {design.dt / p.gains.ki:.3f} | "
                     f"{p.gains.a:.3f} | {p.gains.b:.3f} | {p.gains.kx:.3f} | {gm} | {p.pm_deg:.1f} | "
                     f"{p.crossover_hz:.3f} | "
                     f"{p.peak_s_db:+.2f} | {p.f6_hz:.3f} |")
    ps = doc["predicted_s_db"]
    lines += ["", "Predicted |S| (dB) at the gust frequencies:", "",
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

    f = np.geomspace(0.02, 0.5 / design.dt - 0.01, 500)
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    for p in design.points:
        L = p.loop_response(f, design.dt)
        label = f"ΔCL {p.dcl:.3f}"
        axes[0].semilogx(f, 20 * np.log10(np.abs(L)), label=label)
        axes[1].semilogx(f, np.degrees(np.unwrap(np.angle(L))), label=label)
        axes[2].semilogx(f, 20 * np.log10(np.abs(1 / (1 + L))), label=label)
    axes[0].axhline(0, c="k", lw=0.6)
    axes[1].axhline(-180, c="k", lw=0.6)
    axes[2].axhline(-6, c="k", ls=":")
    axes[2].axhline(design.targets.peak_db, c="r", ls=":")
    axes[0].set_ylabel("|L| (dB)")
    axes[1].set_ylabel("∠L (deg)")
    axes[2].set_ylabel("|S| (dB)")
    axes[2].set_xlabel("frequency (Hz)")
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    fig.suptitle("Lift loop L = C P at the burst rate (design from the model)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
