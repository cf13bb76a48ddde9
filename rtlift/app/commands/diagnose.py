"""``rtlift diagnose``: residual tests, candidate effects judged on held-out records, and a
before/after report with the augmented model (INTERFACES.md)."""

from __future__ import annotations

import argparse

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "diagnose", help="find what the model misses, add it, report the error before and after",
        description="Residual = measured - model on the training and validation records, tested "
                    "against the model's own residual at identification (its fingerprint). Candidate "
                    "effects and combinations of up to three are fitted on --train and judged on the "
                    "--validate records; each accepted entry is an 'effect' when its evidence departs "
                    "from the fingerprint, 'structure' when the model already lacked it.")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file")
    p.add_argument("--train", required=True, metavar="F", help="record the effects are fitted on")
    p.add_argument("--validate", required=True, nargs="+", metavar="F",
                   help="records the effects are judged on (never fitted on)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--skip", type=int, default=0, metavar="N",
                   help="generic records: leave each record's first N samples out of the scores")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import os

    from rtlift.model.modelfile import load_any_model
    from rtlift.model.siso import SISO_MODELS

    model = load_any_model(args.model)
    if isinstance(model, SISO_MODELS):
        return run_generic(args, model)

    from rtlift.core.records import read_record
    from rtlift.diagnose import DiagnoseOptions, diagnose
    from rtlift.diagnose.report import write

    opt = DiagnoseOptions()
    need = int(12 * model.fs_hz)          # 2 s from rest left out of the residual tests, 10 s tested
    train = read_record(args.train, min_samples=need)
    validate = [read_record(p, min_samples=need) for p in args.validate]
    names = [r.name for r in (train, *validate)]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise UserError(f"two records share the stem {sorted(dup)[0]!r}; the report is keyed by stem")
    for r in (train, *validate):
        if abs(r.fs_hz - model.fs_hz) > 1e-6 * model.fs_hz:
            raise UserError(f"{r.name}: sampled at {r.fs_hz:g} Hz, the model at {model.fs_hz:g} Hz")
    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{args.out}: cannot create output directory ({exc.strerror})") from None
    diag = diagnose(model, train, validate, opt)
    write(diag, args.out, {"model": str(args.model), "train": str(args.train),
                           "validate": [str(p) for p in args.validate]})
    rep = diag.report
    acc = [e for e in rep["effects"] if e["accepted"]]
    effects = [e["name"] for e in acc if e["kind"] == "effect"]
    structure = [e["name"] for e in acc if e["kind"] == "structure"]
    print(f"diagnose {args.model}: {len(effects)} effect(s) accepted"
          + (": " + ", ".join(effects) if effects else " (nothing departs from the model's own residual)")
          + (f"; structure the model lacked already: {', '.join(structure)}" if structure else ""))
    for name, b in rep["baseline"]["records"].items():
        a = rep["augmented"]["records"][name]
        print(f"  {name}: RMSE {b['rmse']:.5f} -> {a['rmse']:.5f}, NRMSE {b['nrmse']:.4f} -> "
              f"{a['nrmse']:.4f}, corr {b['corr']:.4f} -> {a['corr']:.4f}")
    print(f"  {len(rep['unexplained'])} unexplained feature(s); report in {args.out}/report.md")
    return 0


def run_generic(args: argparse.Namespace, model) -> int:
    """``rtlift diagnose`` of a generic single-input model (:mod:`rtlift.sysid.diagnose`)."""
    import json
    import os

    from rtlift.core.records import read_siso_record, record_kind
    from rtlift.model.siso import save_siso_model
    from rtlift.sysid.diagnose import diagnose_siso

    paths = [args.train, *args.validate]
    for path in paths:
        if record_kind(path) != "siso":
            raise UserError(f"{path}: a lift record, but {args.model} is a generic (t,u,y) model")
    train, *validate = [read_siso_record(p, min_samples=args.skip + 50) for p in paths]
    names = [r.name for r in (train, *validate)]
    if len(set(names)) != len(names):
        raise UserError("two records share a stem; the report is keyed by stem")
    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{args.out}: cannot create output directory ({exc.strerror})") from None
    report, augmented = diagnose_siso(model, train, validate, args.skip)
    with open(os.path.join(args.out, "report.json"), "w", encoding="utf-8") as f:
        json.dump(report, f, indent=1)
        f.write("\n")
    lines = ["# Diagnosis report", "", f"Scores: {report['scoring']}.", "",
             "| record | ρ before | ρ after | RMSE before | RMSE after |", "|---|---|---|---|---|"]
    for name, b in report["baseline"]["records"].items():
        a = report["augmented"]["records"][name]
        lines.append(f"| {name} | {b['corr']:.4f} | {a['corr']:.4f} | {b['rmse']:.5g} | {a['rmse']:.5g} |")
    lines += ["", "## Tried", ""] + [
        f"- **{e['name']}** ({e['kind']}, {'accepted' if e['accepted'] else 'not accepted'}): {e['evidence']}"
        for e in report["effects"]]
    lines += ["", "## Unexplained", ""] + ([f"- {u}" for u in report["unexplained"]] or ["- nothing"])
    with open(os.path.join(args.out, "report.md"), "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    save_siso_model(augmented, os.path.join(args.out, "model_augmented.json"))
    acc = [e["name"] for e in report["effects"] if e["accepted"]]
    print(f"diagnose {args.model}: structure added: {', '.join(acc) if acc else 'nothing'}")
    for name, b in report["baseline"]["records"].items():
        a = report["augmented"]["records"][name]
        print(f"  {name}: RMSE {b['rmse']:.5g} -> {a['rmse']:.5g}, corr {b['corr']:.4f} -> {a['corr']:.4f}")
    return 0
