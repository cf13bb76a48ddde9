"""``rtlift diagnose``: residual tests, candidate effects judged on held-out records, and a
before/after report with the augmented model (INTERFACES.md)."""

from __future__ import annotations

import argparse

from rtlift.core.errors import UserError

SPLIT_DEFAULT = 0.6
"""``--run``: the share of the run the effects are fitted on. The fits carry the diagnosis (a
fade's time constant, a drift's course need the longer part); 40 % left is still ≥ 10 one-second
significance blocks on a run of 25 s, and ≥ 24 on a minute's run."""
MIN_TRAIN_S = 12.0
"""A training record's least length: 2 s from rest left out of the residual tests, 10 s tested."""
MIN_VALIDATE_S = 10.0
"""The validation part's least length: ten 1 s blocks for the significance test."""


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
    p.add_argument("--train", metavar="F", help="record the effects are fitted on")
    p.add_argument("--validate", nargs="+", metavar="F",
                   help="records the effects are judged on (never fitted on)")
    p.add_argument("--run", metavar="F",
                   help="one long record (a closed-loop log as a record, a day's run): fitted on its first "
                        "part, judged on the rest (instead of --train/--validate)")
    p.add_argument("--split", type=float, metavar="FRACTION",
                   help=f"with --run: the share of the run the effects are fitted on (default {SPLIT_DEFAULT:g}); "
                        "the model runs on through it from rest, the rest is scored")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--skip", type=int, default=0, metavar="N",
                   help="generic records: leave each record's first N samples out of the scores")
    p.add_argument("--init-state", action="store_true",
                   help="generic records: every model runs from the state estimated on a record's unscored "
                        "samples (--skip) instead of from rest")
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


def split_index(n: int, fs: float, fraction: float, path: str) -> int:
    """The first validation sample of a run of ``n`` samples; a one-line error where either part
    would be too short (:data:`MIN_TRAIN_S`, :data:`MIN_VALIDATE_S`)."""
    k = int(round(fraction * n))
    need_train, need_val = int(MIN_TRAIN_S * fs), int(MIN_VALIDATE_S * fs)
    if k < need_train or n - k < need_val:
        raise UserError(f"{path}: {n / fs:.1f} s split at {fraction:g} leaves {k / fs:.1f} s to fit and "
                        f"{(n - k) / fs:.1f} s to judge; at least {MIN_TRAIN_S:g} s and {MIN_VALIDATE_S:g} s needed")
    return k


def run(args: argparse.Namespace) -> int:

    from rtlift.model.modelfile import load_any_model
    from rtlift.model.siso import SISO_MODELS

    check_sources(args)
    model = load_any_model(args.model)
    if isinstance(model, SISO_MODELS):
        return run_generic(args, model)

    from rtlift.api import diagnose
    from rtlift.core.records import read_record, record_kind

    need = int(MIN_TRAIN_S * model.fs_hz)
    split = None
    if args.run is not None:
        if record_kind(args.run) != "lift":
            raise UserError(f"{args.run}: a generic (t,u,y) record, but {args.model} is a lift model")
        whole = read_record(args.run, min_samples=need)
        _same_rate(whole, model)
        fraction = SPLIT_DEFAULT if args.split is None else args.split
        k = split_index(len(whole), model.fs_hz, fraction, args.run)
        train = whole.slice(0, k)
        train.name = f"{whole.name}_train"
        validate = [whole.slice(0, len(whole))]
        validate[0].name = f"{whole.name}_validate"
        score_from = [k]
        split = {"record": str(args.run), "fraction": fraction, "samples": len(whole),
                 "train_samples": [0, k], "validate_samples": [k, len(whole)],
                 "train_seconds": k / model.fs_hz, "validate_seconds": (len(whole) - k) / model.fs_hz,
                 "how": f"effects fitted on samples 0..{k - 1} ({whole.name}_train); every model is run over "
                        f"the whole record from rest and scored on samples {k}..{len(whole) - 1} "
                        f"({whole.name}_validate), so its state at the split is the one the run led to"}
        sources = {"model": str(args.model), "run": str(args.run), "split": fraction}
    else:
        train = read_record(args.train, min_samples=need)
        validate = [read_record(p, min_samples=need) for p in args.validate]
        score_from = None
        names = [r.name for r in (train, *validate)]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise UserError(f"two records share the stem {sorted(dup)[0]!r}; the report is keyed by stem")
        for r in (train, *validate):
            _same_rate(r, model)
        sources = {"model": str(args.model), "train": str(args.train),
                   "validate": [str(p) for p in args.validate]}
    rep, _ = diagnose(model, train, validate, out=args.out, score_from=score_from, sources=sources, split=split,
                      init_state=args.init_state)
    acc = [e for e in rep["effects"] if e["accepted"]]
    effects = [e["name"] for e in acc if e["kind"] == "effect"]
    structure = [e["name"] for e in acc if e["kind"] == "structure"]
    print(f"diagnose {args.model}: {len(effects)} effect(s) accepted"
          + (": " + ", ".join(effects) if effects else " (nothing departs from the model's own residual)")
          + (f"; structure the model lacked already: {', '.join(structure)}" if structure else ""))
    if split is not None:
        print(f"  one run: fitted on {split['train_seconds']:.1f} s, judged on the last "
              f"{split['validate_seconds']:.1f} s")
    for name, b in rep["baseline"]["records"].items():
        a = rep["augmented"]["records"][name]
        print(f"  {name}: RMSE {b['rmse']:.5f} -> {a['rmse']:.5f}, NRMSE {b['nrmse']:.4f} -> "
              f"{a['nrmse']:.4f}, corr {b['corr']:.4f} -> {a['corr']:.4f}")
    print(f"  {len(rep['unexplained'])} unexplained feature(s); report in {args.out}/report.md")
    return 0


def _same_rate(rec, model) -> None:
    if abs(rec.fs_hz - model.fs_hz) > 1e-6 * model.fs_hz:
        raise UserError(f"{rec.name}: sampled at {rec.fs_hz:g} Hz, the model at {model.fs_hz:g} Hz")


def run_generic(args: argparse.Namespace, model) -> int:
    """``rtlift diagnose`` of a generic single-input model (:mod:`rtlift.sysid.diagnose`)."""
    import os

    from rtlift.api import diagnose
    from rtlift.core.records import SisoRecord, read_siso_record, record_kind

    paths = [args.run] if args.run is not None else [args.train, *args.validate]
    for path in paths:
        if os.path.isfile(path) and record_kind(path) != "siso":
            raise UserError(f"{path}: a lift record, but {args.model} is a generic (t,u,y) model")
    split = None
    if args.run is not None:
        whole = read_siso_record(args.run, min_samples=args.skip + 100)
        fraction = SPLIT_DEFAULT if args.split is None else args.split
        k = int(round(fraction * len(whole)))
        if k < args.skip + 50 or len(whole) - k < 50:
            raise UserError(f"{args.run}: {len(whole)} samples split at {fraction:g} leave {k} to fit "
                            f"(--skip {args.skip}) and {len(whole) - k} to judge; at least 50 each needed")
        train = SisoRecord(whole.t[:k], whole.u[:k], whole.y[:k], dict(whole.meta), f"{whole.name}_train")
        validate = [SisoRecord(whole.t, whole.u, whole.y, dict(whole.meta), f"{whole.name}_validate")]
        validate_skip = [k]
        split = {"record": str(args.run), "fraction": fraction, "samples": len(whole),
                 "train_samples": [0, k], "validate_samples": [k, len(whole)],
                 "how": f"structure fitted on samples 0..{k - 1}; every model runs over the whole record "
                        f"from rest and is scored on samples {k}..{len(whole) - 1}"}
    else:
        train, *validate = [read_siso_record(p, min_samples=args.skip + 50) for p in paths]
        validate_skip = None
        names = [r.name for r in (train, *validate)]
        if len(set(names)) != len(names):
            raise UserError("two records share a stem; the report is keyed by stem")
    report, _ = diagnose(model, train, validate, out=args.out, skip=args.skip, score_from=validate_skip,
                         split=split, init_state=args.init_state)
    acc = [e["name"] for e in report["effects"] if e["accepted"]]
    print(f"diagnose {args.model}: structure added: {', '.join(acc) if acc else 'nothing'}")
    for name, b in report["baseline"]["records"].items():
        a = report["augmented"]["records"][name]
        print(f"  {name}: RMSE {b['rmse']:.5g} -> {a['rmse']:.5g}, corr {b['corr']:.4f} -> {a['corr']:.4f}")
    return 0
