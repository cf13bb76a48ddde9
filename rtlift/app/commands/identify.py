"""``rtlift identify``: the hybrid model from the static, single-burst and training records."""

from __future__ import annotations

import argparse
import sys
import time

from rtlift.api import GENERIC_STRUCTURES, LIFT_STRUCTURES
from rtlift.core.errors import UserError
from rtlift.core.registry import MODEL_STRUCTURES


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "identify", help="identify the hybrid model from recorded experiments",
        description="Identify a model from recorded experiments and write it as a model file: the paper's "
                    "hybrid lift model from the lift campaign (--static, --single-burst, --train; the static "
                    "map, the single-burst kernel, the high-pass filter and the Wiener LTI), or a "
                    "single-input model of a generic t,u,y record (--record). What is not given is chosen "
                    "by the held-out error on the training record.")
    p.add_argument("--static", metavar="F", help="slow static sweep record")
    p.add_argument("--single-burst", metavar="F", help="isolated single bursts record")
    p.add_argument("--train", metavar="F", help="training record (the paper: sine_k0125)")
    p.add_argument("--record", metavar="F", action="append",
                   help="a generic single-input record (columns t,u,y) instead of the lift campaign; repeat it "
                        "for several experiments of one system (each its own run from rest, one cost)")
    p.add_argument("--trains", nargs="+", metavar="F",
                   help="burst-train records (train_T1p75, train_T3p5, train_T7): with them the "
                        "interaction structure is identified (it learns burst-burst interaction from them), "
                        "without them the paper's hybrid")
    p.add_argument("--structure", choices=(*LIFT_STRUCTURES, *GENERIC_STRUCTURES),
                   help="lift campaign: paper (the paper's hybrid) or interaction (the slow part driven by "
                        "the delivered momentum, a gain per burst); default: interaction when --trains are "
                        "given, else paper. With --record: " + _generic_help())
    p.add_argument("--order", type=int, metavar="N",
                   help="Wiener LTI order (default: chosen from 1..4 by held-out error)")
    p.add_argument("--form", choices=("auto", "input_gain", "output_map"), default="auto",
                   help="Wiener nonlinearity: input_gain, N(Cmu)*y as in the paper; output_map, f(y) with f "
                        "the static map (textbook Wiener); auto, whichever has the lower held-out error "
                        "(default; the interaction structure: input_gain, the textbook form measured no "
                        "better there)")
    p.add_argument("--dead-time", type=int, metavar="SAMPLES",
                   help="samples the measured lift lags the actuation record (default: chosen from "
                        "0..8 by held-out error)")
    p.add_argument("--phi", choices=("auto", "single_burst", "train"), default="auto",
                   help="phi: single_burst, from the single bursts (paper); train, re-estimated on the "
                        "training record; auto, whichever has the lower held-out error (default)")
    p.add_argument("--kernel", choices=("auto", "single_burst"), default="auto",
                   help="the convolution kernel: single_burst, as averaged from the single bursts (paper); "
                        "auto, its first burst period re-estimated on the training record where that "
                        "lowers the held-out error (default)")
    p.add_argument("--envelope", choices=("recorded", "delivered", "auto"), default="recorded",
                   help="the Wiener part's input (the paper's hybrid): recorded, the envelope as recorded "
                        "(default); delivered, what each burst delivered (the envelope at its onset, held to "
                        "the next: the convention of a loop that holds the envelope per burst period, as "
                        "rtlift control does); auto, delivered unless the recorded one's held-out error is "
                        "lower by more than 1 %%")
    p.add_argument("-o", "--out", required=True, metavar="MODEL.json", help="model file to write")
    p.add_argument("--quiet", action="store_true", help="no progress line on stderr")
    p.set_defaults(func=run)


def _generic_help() -> str:
    """``wiener (an LTI then a static map, default), …`` from the registry's model structures."""
    parts = [f"{s.name} ({s.doc}{', default' if i == 0 else ''})" for i, s in enumerate(MODEL_STRUCTURES)]
    return ", ".join(parts[:-1]) + " or " + parts[-1]


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
    from rtlift.api import identify

    if args.trains and args.structure == "paper":
        print("rtlift identify: note: --trains are not fitted by --structure paper (the paper's hybrid); "
              "leave --structure out to learn from them", file=sys.stderr)
    from rtlift.app.progress import working

    t0 = time.perf_counter()
    with working("rtlift identify", "identifying the model and tuning the observer", args.quiet):
        idf = identify(args.static, args.single_burst, args.train,
                       trains=args.trains or (), structure=args.structure,
                       order=args.order, form=args.form, phi=args.phi, dead_time=args.dead_time,
                       kernel=args.kernel, envelope=args.envelope, out=args.out)
    seconds = time.perf_counter() - t0
    if idf.provenance["structure"]["name"] == "interaction":
        print(interaction_summary(idf, args.out, seconds))
    else:
        print(summary(idf, args.out, seconds))
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
        f"{p['structure']['dead_time_samples']} samples; Wiener input: {_envelope_line(p['structure'])}",
        f"  Wiener LTI ({w['form']}): order {w['order']}, poles {poles}, "
        f"DC gain {w['dc_gain']:.4g} +/- {w['uncertainty']['dc_gain_std']:.2g}",
        f"  training record {tr['record']}: corr {tr['corr']:.4f}, NRMSE {tr['nrmse']:.4f}, "
        f"RMSE {tr['rmse']:.4g}",
    ]
    reach = p["domain"].get("train_envelope")
    if reach:
        lines.append(f"  training envelope: 95 % of its variance below {reach['f95_hz']:.2f} Hz "
                     f"({100 * reach['share_above_1hz']:.1f} % above 1 Hz): the model's dynamics are "
                     f"extrapolated above that")
    return "\n".join(lines)


def _envelope_line(st: dict) -> str:
    """The Wiener part's input and, under ``--envelope auto``, why (provenance.structure)."""
    used = st.get("envelope", "recorded")
    c = st.get("envelope_choice")
    if not c:
        return f"the envelope {used}"
    ho = c["holdout_rmse"]
    return (f"the envelope {used} (held-out RMSE delivered {ho['delivered']:.4g}, "
            f"recorded {ho['recorded']:.4g})")


def run_generic(args: argparse.Namespace) -> int:
    """``rtlift identify --record F --structure S``: a generic single-input record."""
    from rtlift.api import identify_record
    from rtlift.app.progress import working

    t0 = time.perf_counter()
    with working("rtlift identify", f"identifying a {args.structure} model", args.quiet):
        model = identify_record(args.record, structure=args.structure, order=args.order, out=args.out)
    p = model.provenance
    lines = [f"identified {model.structure} model in {time.perf_counter() - t0:.1f} s -> {args.out}"]
    if "bla_order" in p:
        lines.append(f"  best linear approximation: order {p['bla_order']}, held-out RMSE {p['bla_holdout_rmse']:.5g}")
    if "integrating" in p:
        lines.append(f"  integrating: {p['integrating']}")
    lines.append(f"  held-out RMSE {model.metrics['holdout_rmse']:.5g} (last {100 * p['holdout_fraction']:.0f} % "
                 f"of {'each' if len(args.record) > 1 else 'the'} record), training RMSE "
                 f"{model.metrics['train_rmse']:.5g}")
    print("\n".join(lines))
    for note in p.get("notes", []):
        print(f"rtlift identify: note: {note}", file=sys.stderr)
    if p.get("skipped"):
        print("rtlift identify: note: skipped, fit failed numerically: "
              + "; ".join(f"{k} ({v})" for k, v in p["skipped"].items()), file=sys.stderr)
    return 0
