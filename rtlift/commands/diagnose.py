"""``rtlift diagnose``: residual tests, candidate effects judged on held-out records, and a
before/after report with the augmented model (INTERFACES.md)."""

from __future__ import annotations

import argparse

from rtlift.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "diagnose", help="find what the model misses, add it, report the error before and after",
        description="Residual = measured - model on the training and validation records; residual "
                    "tests point at candidate effects, each is fitted on --train and accepted only if "
                    "it clearly lowers the error on the --validate records.")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file")
    p.add_argument("--train", required=True, metavar="F", help="record the effects are fitted on")
    p.add_argument("--validate", required=True, nargs="+", metavar="F",
                   help="records the effects are judged on (never fitted on)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import os

    from rtlift.diagnose import DiagnoseOptions, diagnose
    from rtlift.diagnose.report import write
    from rtlift.modelfile import load_model
    from rtlift.records import read_record

    model = load_model(args.model)
    opt = DiagnoseOptions()
    need = int(round(opt.start_s * model.fs_hz)) + int(10 * model.fs_hz)
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
    print(f"diagnose {args.model}: {len(acc)} effect(s) accepted"
          + (": " + ", ".join(e["name"] for e in acc) if acc else " (nothing significant)"))
    for name, b in rep["baseline"]["records"].items():
        a = rep["augmented"]["records"][name]
        print(f"  {name}: RMSE {b['rmse']:.5f} -> {a['rmse']:.5f}, NRMSE {b['nrmse']:.4f} -> "
              f"{a['nrmse']:.4f}, corr {b['corr']:.4f} -> {a['corr']:.4f}")
    print(f"  {len(rep['unexplained'])} unexplained feature(s); report in {args.out}/report.md")
    return 0
