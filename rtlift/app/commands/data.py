"""``rtlift data``: the measured benchmarks vendored in ``rtlift/data/benchmarks/`` (installed with
the package) — list them, export their official splits as ``t,u,y`` records
(:mod:`rtlift.sysid.benchmarks`)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    from rtlift.sysid.benchmarks import BENCHMARKS

    data = subparsers.add_parser(
        "data", help="the vendored measured benchmarks: list them, export their official splits",
        description="The measured nonlinear system-identification benchmarks installed with rtlift "
                    f"({', '.join(BENCHMARKS)}): list them, or write a benchmark's official estimation and "
                    "test splits as t,u,y record files for rtlift identify --record, diagnose and validate.")
    sub = data.add_subparsers(dest="data_command", metavar="ACTION")
    sub.required = True
    ls = sub.add_parser("list", help="the vendored benchmarks, their rates and split sizes",
                        description="List the vendored benchmarks: sample rate, estimation and test samples, "
                                    "the unit their published RMSEs are quoted in, and the system.")
    ls.add_argument("--data", metavar="DIR",
                    help="folder holding the .npz files (default: those installed with rtlift)")
    ls.set_defaults(func=_list)
    ex = sub.add_parser("export", help="write a benchmark's official splits as t,u,y records",
                        description="Write the official estimation and test splits of benchmark NAME as "
                                    "DIR/NAME_estimation.csv and DIR/NAME_test.csv (several runs or tests: "
                                    "DIR/NAME_estimation_K.csv, DIR/NAME_test_KIND.csv; t,u,y records in V). Score "
                                    "on the test record as the benchmark's rules do: rtlift validate --skip 50 "
                                    "(free run from rest, the first 50 samples unscored).")
    ex.add_argument("name", metavar="NAME", help=f"the benchmark: {', '.join(BENCHMARKS)}")
    ex.add_argument("--out", required=True, metavar="DIR", help="folder for the two records (created)")
    ex.add_argument("--data", metavar="DIR",
                    help="folder holding the .npz files (default: those installed with rtlift)")
    ex.set_defaults(func=_export)


def _list(args: argparse.Namespace) -> int:
    from rtlift.sysid.benchmarks import BENCHMARKS, estimation, tests

    rows = []                 # every file read before the header: a missing one is the only line
    for b in BENCHMARKS.values():
        fs, est = estimation(b.name, args.data)
        n_est, n_test = (sum(u.size for _, u, _ in parts) for parts in (est, tests(b.name, args.data)))
        rows.append(f"{b.name:<19} {fs:>9.6g} {n_est:>10} {n_test:>7}  {b.unit:<7}  {b.system}")
    print("\n".join([f"{'name':<19} {'fs (Hz)':>9} {'estimation':>10} {'test':>7}  RMSE in  system", *rows]))
    return 0


def _export(args: argparse.Namespace) -> int:
    from rtlift.sysid.benchmarks import export

    for path in export(args.name, args.out, args.data):
        print(f"wrote {path}")
    return 0
