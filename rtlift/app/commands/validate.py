"""``rtlift validate``: a model against records — ρ, NRMSE, RMSE per record (INTERFACES.md)."""

from __future__ import annotations

import argparse
import json
import os
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
    p.add_argument("--figures", metavar="DIR", help="write one figure per record into DIR")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rtlift.core.records import read_record, read_siso_record, record_kind
    from rtlift.model.modelfile import load_any_model
    from rtlift.model.siso import SISO_MODELS
    from rtlift.model.validation import (
        RecordValidation,
        plot_generic_validation,
        plot_validation,
        validate_record,
        validation_json,
    )

    model = load_any_model(args.model)
    generic = isinstance(model, SISO_MODELS)
    if args.skip < 0:
        raise UserError(f"--skip {args.skip}: must be 0 or more")
    for path in args.records:
        if (record_kind(path) == "siso") != generic:
            raise UserError(f"{path}: a {'generic t,u,y' if record_kind(path) == 'siso' else 'lift'} record, "
                            f"but {args.model} is a {'generic' if generic else 'lift'} model")
    records = [(read_siso_record if generic else read_record)(path, min_samples=args.skip + 2)
               for path in args.records]
    stems = [r.name for r in records]
    dup = {s for s in stems if stems.count(s) > 1}
    if dup:
        raise UserError(f"two records share the stem {sorted(dup)[0]!r}; the JSON is keyed by stem")
    for r in records:
        if abs(r.fs_hz - model.fs_hz) > 1e-6 * model.fs_hz:
            raise UserError(f"{r.name}: sampled at {r.fs_hz:g} Hz, the model at {model.fs_hz:g} Hz")
    if generic:
        from rtlift.sysid.diagnose import predict, record_scores

        results = [RecordValidation(r.name, record_scores(model, r, args.skip), predict(model, r)) for r in records]
    else:
        results = [validate_record(model, r, args.skip) for r in records]
    if args.figures:
        try:
            os.makedirs(args.figures, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{args.figures}: cannot create figure directory ({exc.strerror})") from None
        for rec, res in zip(records, results, strict=True):
            figure = os.path.join(args.figures, f"{rec.name}.png")
            if generic:
                plot_generic_validation(rec, res, figure, args.skip)
            else:
                plot_validation(rec, res, figure)
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
