"""``rtlift data``: the measured benchmarks vendored in ``data/`` — list them, export their
official splits as ``t,u,y`` records (:mod:`rtlift.sysid.benchmarks`)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    from rtlift.sysid.benchmarks import BENCHMARKS

    data = subparsers.add_parser(
        "data", help="the vendored measured benchmarks: list them, export their official splits",
        description="The measured nonlinear system-identification benchmarks vendored in data/ "
                    f"({', '.join(BENCHMARKS)}): list them, or write a benchmark's official estimation and "
                    "test splits as t,u,y record files for rtlift identify --record, diagnose and validate.")
    sub = data.add_subparsers(dest="data_command", metavar="ACTION")
    sub.required = True
    ls = sub.add_parser("list", help="the vendored benchmarks, their rates and split sizes",
                        description="List the vendored benchmarks: sample rate, estimation and test samples, "
                                    "the unit their published RMSEs are quoted in, and the system.")
    ls.add_argument("--data", metavar="DIR", help="folder holding the .npz files (default: the checkout's data/)")
    ls.set_defaults(func=_list)
    ex = sub.add_parser("export", help="write a benchmark's official splits as t,u,y records",
                        description="Write the official estimation and test splits of benchmark NAME as "
                                    "DIR/NAME_estimation.csv and DIR/NAME_test.csv (t,u,y records in V). Score "
                                    "on the test record as the benchmark's rules do: rtlift validate --skip 50 "
                                    "(free run from rest, the first 50 samples unscored).")
    ex.add_argument("name", metavar="NAME", help=f"the benchmark: {', '.join(BENCHMARKS)}")
    ex.add_argument("--out", required=True, metavar="DIR", help="folder for the two records (created)")
    ex.add_argument("--data", metavar="DIR", help="folder holding the .npz files (default: the checkout's data/)")
    ex.set_defaults(func=_export)


def _list(args: argparse.Namespace) -> int:
    from rtlift.sysid.benchmarks import BENCHMARKS, splits

    print(f"{'name':<15} {'fs (Hz)':>9} {'estimation':>10} {'test':>7}  RMSE in  system")
    for b in BENCHMARKS.values():
        fs, ue, _, ut, _, _, unit = splits(b.name, args.data)
        print(f"{b.name:<15} {fs:>9.6g} {ue.size:>10} {ut.size:>7}  {unit:<7}  {b.system}")
    return 0


def _export(args: argparse.Namespace) -> int:
    from rtlift.sysid.benchmarks import export

    for path in export(args.name, args.out, args.data):
        print(f"wrote {path}")
    return 0
