"""``rtlift diagnose``: residual tests, candidate effects judged on held-out records, and a
before/after report with the augmented model (INTERFACES.md)."""

from __future__ import annotations

import argparse

from rtlift.core.errors import UserError
from rtlift.core.split import MIN_TRAIN_S, MIN_VALIDATE_S, SPLIT_DEFAULT


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "diagnose", help="find what the model misses, add it, report the error before and after",
        description="Residual = measured - model on the training and validation records, tested "
                    "against the model's own residual at identification (its fingerprint). Candidate "
                    "effects and combinations of up to three are fitted on --train and judged on the "
                    "--validate records; each accepted entry is an 'effect' when its evidence departs "
                    "from the fingerprint, 'structure' when the model already lacked it. --run F: one "
                    "long record, fitted on its first part and judged on the rest.")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file")
    p.add_argument("--train", metavar="F", action="append",
                   help="record the effects are fitted on; a generic model's may be repeated (several "
                        "experiments of one system, each its own run from rest, one cost)")
    p.add_argument("--validate", nargs="+", metavar="F",
                   help="records the effects are judged on (never fitted on)")
    p.add_argument("--run", metavar="F",
                   help="one long record (a closed-loop log as a record, a day's run): fitted on its first "
                        "part, judged on the rest (instead of --train/--validate). A lift run needs at least "
                        f"{MIN_TRAIN_S:g} s to fit and {MIN_VALIDATE_S:g} s to judge: "
                        f"{max(MIN_TRAIN_S / SPLIT_DEFAULT, MIN_VALIDATE_S / (1 - SPLIT_DEFAULT)):g} s at the "
                        f"default split; a run of T s from {MIN_TRAIN_S + MIN_VALIDATE_S:g} s on with --split "
                        f"between {MIN_TRAIN_S:g}/T and 1 - {MIN_VALIDATE_S:g}/T. A generic t,u,y run: 50 samples "
                        "in each part (past --skip)")
    p.add_argument("--split", type=float, metavar="FRACTION",
                   help=f"with --run: the share of the run the effects are fitted on (default {SPLIT_DEFAULT:g}); "
                        "the model runs on through it from rest, the rest is scored")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--skip", type=int, default=0, metavar="N",
                   help="generic records: leave each record's first N samples out of the scores")
    p.add_argument("--init-state", action="store_true",
                   help="generic records: every model runs from the state estimated on a record's unscored "
                        "samples (--skip) instead of from rest")
    p.add_argument("--suspect", metavar="EFFECT",
                   help="a lift model's effect another source of evidence names (rtlift --adapt passes the live "
                        "monitor's suspect): among explanations that fit alike it ranks first")
    p.add_argument("--quiet", action="store_true", help="no progress line on stderr")
    p.set_defaults(func=run)


def check_sources(args: argparse.Namespace) -> None:
    """``--run`` [``--split``] or ``--train`` and ``--validate``, never both (one-line errors)."""
    if args.run is not None:
        if args.train is not None or args.validate is not None:
            raise UserError("--run and --train/--validate are exclusive: one long record, or a training "
                            "record and validation records")
        if args.split is not None and not 0.0 < args.split < 1.0:
            raise UserError(f"--split {args.split:g}: a fraction of the run between 0 and 1")
        return
    if args.split is not None:
        raise UserError("--split needs --run (it splits one long record)")
    if args.train is None or args.validate is None:
        raise UserError("give --train F and --validate F..., or --run F for one long record")


def run(args: argparse.Namespace) -> int:
    """Parse, call :func:`rtlift.api.diagnose` (or :func:`~rtlift.api.diagnose_run`), print the summary."""
    from rtlift import api
    from rtlift.app.progress import working

    check_sources(args)
    with working("rtlift diagnose", "fitting candidate effects, judging them, writing the report", args.quiet):
        if args.run is not None:
            rep, augmented = api.diagnose_run(args.model, args.run, split=args.split, out=args.out,
                                              skip=args.skip, init_state=args.init_state, suspect=args.suspect)
        else:
            train = args.train[0] if len(args.train) == 1 else args.train
            rep, augmented = api.diagnose(args.model, train, args.validate, out=args.out, skip=args.skip,
                                          init_state=args.init_state, suspect=args.suspect)
    print("\n".join(summary(rep, args.model, args.out, api.is_generic(augmented))))
    return 0


def summary(rep: dict, model: str, out: str, generic: bool) -> list[str]:
    """The lines ``rtlift diagnose`` prints: what was accepted, the split, the error per record."""
    acc = [e for e in rep["effects"] if e["accepted"]]
    effects = [e["name"] for e in acc if e["kind"] == "effect"]
    structure = [e["name"] for e in acc if e["kind"] == "structure"]
    if generic:
        lines = [f"diagnose {model}: structure added: {', '.join(structure) if structure else 'nothing'}"]
    else:
        lines = [f"diagnose {model}: {len(effects)} effect(s) accepted"
                 + (": " + ", ".join(effects) if effects else " (nothing departs from the model's own residual)")
                 + (f"; structure the model lacked already: {', '.join(structure)}" if structure else "")]
    split = rep.get("split")
    if split is not None:
        lines.append(f"  one run: fitted on {split['train_seconds']:.1f} s, judged on the last "
                     f"{split['validate_seconds']:.1f} s")
    num = ".5g" if generic else ".5f"       # a generic record's output has any scale
    for name, b in rep["baseline"]["records"].items():
        a = rep["augmented"]["records"][name]
        lines.append(f"  {name}: RMSE {b['rmse']:{num}} -> {a['rmse']:{num}}, NRMSE {b['nrmse']:.4f} -> "
                     f"{a['nrmse']:.4f}, corr {b['corr']:.4f} -> {a['corr']:.4f}")
    lines.append(f"  {len(rep['unexplained'])} unexplained feature(s); report in {out}/report.md")
    return lines
