"""``rtlift identify``: the hybrid model from the static, single-burst and training records."""

from __future__ import annotations

import argparse
import sys
import time

from rtlift.core.errors import UserError, require_finite

LIFT_STRUCTURES = ("paper", "interaction")
GENERIC_STRUCTURES = ("wiener", "wiener_hammerstein", "nonlinear_feedback", "store_chain")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "identify", help="identify the hybrid model from recorded experiments",
        description="Static map -> N(Cmu); single-burst kernel and phi; high-pass filter and "
                    "Wiener LTI (output-error PEM) chosen by held-out error on the training "
                    "record. Writes a model file.")
    p.add_argument("--static", metavar="F", help="slow static sweep record")
    p.add_argument("--single-burst", metavar="F", help="isolated single bursts record")
    p.add_argument("--train", metavar="F", help="training record (the paper: sine_k0125)")
    p.add_argument("--record", metavar="F",
                   help="a generic single-input record (columns t,u,y) instead of the lift campaign")
    p.add_argument("--trains", nargs="+", metavar="F",
                   help="burst-train records (train_T1p75, train_T3p5, train_T7): with them the "
                        "interaction structure is identified (it learns burst-burst interaction from them), "
                        "without them the paper's hybrid")
    p.add_argument("--structure", choices=(*LIFT_STRUCTURES, *GENERIC_STRUCTURES),
                   help="lift campaign: paper (the paper's hybrid) or interaction (slow part driven by the "
                        "delivered momentum, per-burst gain of each burst's slow response); default: "
                        "interaction when --trains are given, else paper. With --record: the "
                        "W block in textbook form (LTI then static map, default), Wiener-Hammerstein (a "
                        "second LTI after the map) or nonlinear feedback (the output fed back through a "
                        "cubic map into the LTI's input)")
    p.add_argument("--order", type=int, metavar="N",
                   help="Wiener LTI order (default: chosen from 1..4 by held-out error)")
    p.add_argument("--form", choices=("auto", "input_gain", "output_map"), default="auto",
                   help="Wiener nonlinearity: N(Cmu)*y as in the paper, f(y) with f the static map "
                        "(textbook Wiener), or whichever has the lower held-out error (default; the "
                        "interaction structure: N(Cmu)*y, the textbook form measured no better there)")
    p.add_argument("--dead-time", type=int, metavar="SAMPLES",
                   help="samples the measured lift lags the actuation record (default: chosen from "
                        "0..8 by held-out error)")
    p.add_argument("--phi", choices=("auto", "single_burst", "train"), default="auto",
                   help="phi from the single burst (paper), re-estimated on the training "
                        "record, or whichever has the lower held-out error (default)")
    p.add_argument("--kernel", choices=("auto", "single_burst"), default="auto",
                   help="the convolution kernel as averaged from the single bursts (paper), or its "
                        "first burst period re-estimated on the training record where that lowers "
                        "the held-out error (default)")
    p.add_argument("-o", "--out", required=True, metavar="MODEL.json", help="model file to write")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.record:
        if args.static or args.single_burst or args.train or args.trains:
            raise UserError("--record identifies a generic record; give it alone, not with --static, "
                            "--single-burst, --train or --trains")
        if args.structure in LIFT_STRUCTURES:
            raise UserError(f"--structure {args.structure} is a lift-campaign structure; with --record use "
                            f"{', '.join(GENERIC_STRUCTURES)}")
        args.structure = args.structure or GENERIC_STRUCTURES[0]
        return run_generic(args)
    if args.structure is not None and args.structure not in LIFT_STRUCTURES:
        raise UserError(f"--structure {args.structure} is for a generic --record; a lift campaign takes "
                        f"{' or '.join(LIFT_STRUCTURES)}")
    missing = [f"--{k.replace('_', '-')}" for k in ("static", "single_burst", "train") if not getattr(args, k)]
    if missing:
        raise UserError(f"{', '.join(missing)} missing: give --static, --single-burst and --train (a lift "
                        "campaign) or --record (a generic t,u,y record)")
    from rtlift.core.records import read_record
    from rtlift.identify.campaign import IdentifyOptions
    from rtlift.identify.choice import choose_structure, identify_lift
    from rtlift.identify.interaction import InteractionOptions
    from rtlift.observer import tune_observer

    if args.order is not None and not 1 <= args.order <= 8:
        raise UserError(f"--order {args.order}: must be between 1 and 8")
    static = read_record(args.static, min_samples=50)
    burst = read_record(args.single_burst, min_samples=50)
    train = read_record(args.train, min_samples=200)
    if args.dead_time is not None and not 0 <= args.dead_time <= 80:
        raise UserError(f"--dead-time {args.dead_time}: must be between 0 and 80 samples")
    trains = [read_record(f, min_samples=200) for f in args.trains or ()]
    names = ", ".join(str(f) for f in (args.static, args.single_burst, *(args.trains or ()), args.train))
    try:
        choice = choose_structure(trains, args.structure)
    except ValueError as exc:
        raise UserError(f"cannot identify from {names}: {exc}") from None
    if choice.name == "interaction" and args.phi != "auto":
        how = "--structure interaction" if args.structure else "the interaction structure (chosen for the --trains)"
        raise UserError(f"--phi: not a choice of {how}: its burst part's gains are fitted instead; "
                        "--structure paper fits the paper's hybrid")
    if choice.name == "paper" and trains:
        print("rtlift identify: note: --trains are not fitted by --structure paper (the paper's hybrid); "
              "leave --structure out to learn from them", file=sys.stderr)
    t0 = time.perf_counter()
    try:
        idf, choice = identify_lift(
            static, burst, trains, train, args.structure,
            hybrid=IdentifyOptions(order=args.order, form=args.form, phi=args.phi, dead_time=args.dead_time,
                                   kernel=args.kernel),
            interaction=InteractionOptions(order=args.order, dead_time=args.dead_time,
                                           form="input_gain" if args.form == "auto" else args.form,
                                           kernel=args.kernel))
    except ValueError as exc:
        raise UserError(f"cannot identify from {names}: {exc}") from None
    seconds = time.perf_counter() - t0
    observer = {**idf.observer, **tune_observer(idf.model, [train])}   # Q, R from the data, for rtlift observe
    require_finite("observer tuning", train.name, observer=observer)
    idf.provenance["files"] = {"static": str(args.static), "single_burst": str(args.single_burst),
                               **({"trains": [str(f) for f in args.trains]} if args.trains else {}),
                               "train": str(args.train)}
    _save(idf, args.out, observer)     # no clock in the file: the same inputs give the same bytes
    print(summary(idf, args.out, seconds) if choice.name == "paper" else interaction_summary(idf, args.out, seconds))
    return 0


def interaction_summary(idf, out_path: str, seconds: float) -> str:
    """Human summary of an identification of the interaction structure (a few lines)."""
    st, w, dom = idf.provenance["structure"], idf.provenance["wiener"], idf.provenance["domain"]
    lines = [f"identified interaction model in {seconds:.2f} s -> {out_path}",
             f"  structure: {st['choice']['why']}",
             f"  high-pass of the burst part: Butterworth order {st['highpass']['order']}, cutoff "
             f"{st['highpass']['cutoff_hz']:g} Hz; delivered-momentum memory "
             f"tau {st['time_constant_s']:g} s at duty {st['duty']:.4g}",
             "  per-burst gains G_H(m) / G(m) of the fast / slow part: " + ", ".join(
                 f"{gh:.3g}/{g:.3g}@{k:.3g}" for k, gh, g in zip(st["knots"], st["gains_h"], st["gains"], strict=True)),
             f"  Wiener LTI (driven by m, {w['form']} form): order {w['order']}, DC gain {w['dc_gain']:.4g}; "
             f"dead time {st['dead_time_samples']} samples",
             f"  kernel: {_refinement_line(idf.provenance['kernel'].get('refinement', {}))}",
             "  domain: burst periods " + ", ".join(f"{p:.3g}" for p in dom["burst_periods_s"]) + " s"
             + (" and isolated bursts" if dom["isolated_bursts"] else "") + f", Cmu up to {dom['cmu_max']:.4g}"]
    lines += [f"  {name:14s} corr {v['corr']:.4f}  NRMSE {v['nrmse']:.4f}"
              for name, v in idf.metrics["records"].items()]
    return "\n".join(lines)


def _save(idf, out: str, observer: dict) -> None:
    from rtlift.model.modelfile import save_model

    try:
        save_model(idf.model, out, provenance=idf.provenance, metrics=idf.metrics, observer=observer)
    except OSError as exc:
        raise UserError(f"{out}: cannot write model file ({exc.strerror})") from None


def _refinement_line(r: dict) -> str:
    """How the kernel's first burst period was chosen (provenance.kernel.refinement)."""
    if not r or not r.get("taps"):
        return "as averaged from the single bursts"
    ho = r["holdout_rmse"]
    if r["used"] == "single_burst":
        return f"as averaged (refining its first {r['taps']} taps on the training record did not help)"
    chosen = ho[f"{r['ridge']:g}"]
    return (f"first {r['taps']} taps refined on the training record, ridge {r['ridge']:g} "
            f"(held-out RMSE {ho['single_burst']:.4g} -> {chosen:.4g})")


def summary(idf, out_path: str, seconds: float) -> str:
    """Human summary of an identification (a few lines)."""
    p = idf.provenance
    w = p["wiener"]
    hp = p["highpass"]
    h = idf.static.hysteresis
    tr = idf.metrics["train"]
    poles = ", ".join(f"{re:.5f}{im:+.5f}j" if im else f"{re:.5f}" for re, im in w["poles"])
    lines = [
        f"identified hybrid model in {seconds:.2f} s -> {out_path}",
        f"  static map: Cmu 0..{idf.static.cmu_max:.4g} -> dCL 0..{idf.static.dcl[-1]:.4g}, "
        f"N(0) = {idf.static.limit_slope:.4g}; hysteresis: {h.verdict} "
        f"(max gap {h.max_gap:.2g}, loop area {h.loop_area:.2g})",
        f"  kernel: {idf.kernel.n_bursts} bursts averaged, {idf.kernel.kernel.size} taps, "
        f"phi = {p['phi']:.5g} ({p['phi_choice']['used']}; single-burst phi "
        f"{p['phi_choice']['phi_single_burst']:.5g}); " + _refinement_line(p["kernel"].get("refinement", {})),
        f"  high-pass: Butterworth order {hp['order']}, cutoff {hp['cutoff_hz']:g} Hz "
        f"(held-out RMSE {hp['holdout_rmse']:.4g}; zero-phase offline reference "
        f"{hp['zero_phase_holdout_rmse_offline_reference']:.4g})",
        f"  structure by held-out error: {w['form']} form, dead time "
        f"{p['structure']['dead_time_samples']} samples",
        f"  Wiener LTI ({w['form']}): order {w['order']}, poles {poles}, "
        f"DC gain {w['dc_gain']:.4g} +/- {w['uncertainty']['dc_gain_std']:.2g}",
        f"  training record {tr['record']}: corr {tr['corr']:.4f}, NRMSE {tr['nrmse']:.4f}, "
        f"RMSE {tr['rmse']:.4g}",
    ]
    return "\n".join(lines)


def run_generic(args: argparse.Namespace) -> int:
    """``rtlift identify --record F --structure S``: a generic single-input record."""
    from rtlift.core.records import read_siso_record
    from rtlift.model.siso import save_siso_model
    from rtlift.sysid.identify import identify_siso

    if args.order is not None and not 1 <= args.order <= 8:
        raise UserError(f"--order {args.order}: must be between 1 and 8")
    rec = read_siso_record(args.record, min_samples=500)
    t0 = time.perf_counter()
    try:
        model = identify_siso(rec, args.structure, args.order)
    except ValueError as exc:
        raise UserError(f"cannot identify from {args.record}: {exc}") from None
    try:
        save_siso_model(model, args.out)
    except OSError as exc:
        raise UserError(f"{args.out}: cannot write model file ({exc.strerror})") from None
    p = model.provenance
    lines = [f"identified {model.structure} model in {time.perf_counter() - t0:.1f} s -> {args.out}"]
    if "bla_order" in p:
        lines.append(f"  best linear approximation: order {p['bla_order']}, held-out RMSE {p['bla_holdout_rmse']:.5g}")
    lines.append(f"  held-out RMSE {model.metrics['holdout_rmse']:.5g} (last {100 * p['holdout_fraction']:.0f} % "
                 f"of the record), training RMSE {model.metrics['train_rmse']:.5g}")
    print("\n".join(lines))
    return 0
