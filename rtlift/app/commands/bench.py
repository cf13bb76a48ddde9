"""``rtlift bench``: the simulated bench — record one experiment, or serve the DAQ device."""

from __future__ import annotations

import argparse

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    bench = subparsers.add_parser(
        "bench", help="the simulated wind-tunnel bench (hil_sim)",
        description="The simulated wind-tunnel bench: write one experiment as a record file (record), or run "
                    "the simulated DAQ on a pseudo-terminal for rtlift record, observe or control (serve).")
    sub = bench.add_subparsers(dest="bench_command", metavar="ACTION")
    sub.required = True

    rec = sub.add_parser(
        "record", help="write one experiment of the standard campaign as a record CSV",
        description="Run one experiment of the standard campaign on the simulated bench, offline and faster "
                    "than real time, and write it as a record file (t, cmu, cmu_envelope, dcl, with the "
                    "bench's true lift as dcl_true), ready for rtlift identify, validate or diagnose.")
    rec.add_argument("experiment", metavar="EXPERIMENT",
                     help="static, single_burst, train_T1p75, train_T3p5, train_T7, "
                          "sine_k0125, sine_k025 or random")
    rec.add_argument("--out", required=True, metavar="FILE.csv", help="record file to write")
    _common(rec)
    rec.set_defaults(func=_record)

    serve = sub.add_parser(
        "serve", help="run the simulated DAQ device on a new pseudo-terminal",
        description="Run the simulated DAQ (a serial device, or an SLCAN CAN adapter) on a new "
                    "pseudo-terminal and stream the bench at 400 Hz until Ctrl-C; the port is printed, "
                    "to be given to rtlift record, observe or control as --serial PORT or "
                    "--can slcan:PORT.")
    link = serve.add_mutually_exclusive_group(required=True)
    link.add_argument("--serial", action="store_true", help="serial DAQ (COBS packets)")
    link.add_argument("--slcan", action="store_true", help="SLCAN CAN adapter")
    serve.add_argument("--experiment", default="random", metavar="NAME",
                       help="experiment program the DAQ streams, repeated (default random)")
    serve.add_argument("--fault", action="append", default=[], metavar="NAME:k=v",
                       help="link fault: corrupt|drop|duplicate|garbage:rate=R or disconnect:after_s=S; "
                            "command fault: cmd_drop|cmd_corrupt:rate=R or "
                            "cmd_late:rate=R[,delay_ms=MS]")
    serve.add_argument("--protocol", type=int, choices=(1, 2), default=2,
                       help="protocol version of the device (1: it reads no commands; default 2)")
    serve.add_argument("--speed", type=float, default=1.0, metavar="X",
                       help="pace the samples X times faster than real time (default 1)")
    _common(serve)
    serve.set_defaults(func=_serve)


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--effect", action="append", default=[], metavar="NAME[:k=v,...]",
                        help="inject an effect the model is not told about (repeatable)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--gust", metavar="F:A[,F:A...]",
                        help="lift disturbance Σ A sin(2π F t) added to the plant's true ΔCL (Hz:ΔCL)")
    parser.add_argument("--plant-draw", type=int, default=0, metavar="N",
                        help="plant number N of the family (hil_sim.family; 0, the default, is our bench; "
                             "1-49 calibration, 100-199 reporting only)")


def _record(args: argparse.Namespace) -> int:
    from hil_sim.effects import parse_effect
    from hil_sim.experiments import EXPERIMENTS, run_experiment, write_bench_record
    from hil_sim.gust import parse_gust

    if args.experiment not in EXPERIMENTS:
        raise UserError(f"unknown experiment {args.experiment!r} (known: {', '.join(EXPERIMENTS)})")
    effects = [parse_effect(spec) for spec in args.effect]
    gust = parse_gust(args.gust)
    run = run_experiment(args.experiment, seed=args.seed, effects=effects, gust=gust, plant_draw=args.plant_draw)
    write_bench_record(run, args.out)
    names = ", ".join(e.spec() for e in effects) or "none"
    print(f"{args.experiment}: {len(run)} samples ({len(run) / run.fs_hz:.1f} s at "
          f"{run.fs_hz:g} Hz), seed {args.seed}, plant draw {args.plant_draw}, effects {names}, "
          f"gust {gust.spec() or 'none'} -> {args.out}")
    return 0


def _serve(args: argparse.Namespace) -> int:
    from hil_sim.serve import serve_main

    return serve_main(args)
