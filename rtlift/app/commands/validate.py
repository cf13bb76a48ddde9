"""``rtlift validate``: a model against records — ρ, NRMSE, RMSE per record (INTERFACES.md)."""

from __future__ import annotations

import argparse
import json
import sys

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "validate", help="score a model file on records (corr, NRMSE, RMSE)",
        description="Run the model open loop over each record and compare with the measured "
                    "dCL: the paper's correlation coefficient, NRMSE and RMSE.")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file")
    p.add_argument("records", nargs="+", metavar="RECORD.csv", help="record files")
    p.add_argument("--json", metavar="OUT.json", help="write the scores as JSON")
    p.add_argument("--skip", type=int, default=0, metavar="N",
                   help="leave each record's first N samples out of the scores (a benchmark's "
                        "state-initialisation window); the model runs from rest over them")
    p.add_argument("--init-state", action="store_true",
                   help="generic models: run from the state estimated on the --skip unscored samples "
                        "(a record that does not start at rest) instead of from rest")
    p.add_argument("--figures", metavar="DIR", help="write one figure per record into DIR")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rtlift.api import is_generic, load, read_records
    from rtlift.api import validate as validate_model
    from rtlift.model.validation import validation_json

    model = load(args.model)
    generic = is_generic(model)
    if args.skip < 0:
        raise UserError(f"--skip {args.skip}: must be 0 or more")
    records = read_records(args.records, model, args.skip + 2)
    results = validate_model(model, records, skip=args.skip, figures=args.figures, init_state=args.init_state)
    stems = [r.name for r in results]
    doc = validation_json(args.model, results)
    if args.json:
        try:
            with open(args.json, "w", encoding="utf-8") as f:
                json.dump(doc, f, indent=1, allow_nan=True)
                f.write("\n")
        except OSError as exc:
            raise UserError(f"{args.json}: cannot write ({exc.strerror})") from None
    if not generic:
        from rtlift.model.domain import outside_domain

        for r in records:
            line = outside_domain(model.provenance.get("domain"), r.cmu, r.cmu_envelope, r.fs_hz)
            if line:
                print(f"rtlift validate: warning: {r.name}: {line}", file=sys.stderr)
    width = max(len(s) for s in stems)
    print(f"model {args.model}: {len(results)} record(s)")
    print(f"  {'record':<{width}}  {'corr':>7}  {'NRMSE':>7}  {'RMSE':>9}")
    for res in results:
        s = res.scores
        print(f"  {res.name:<{width}}  {s['corr']:7.4f}  {s['nrmse']:7.4f}  {s['rmse']:9.5f}")
    return 0
