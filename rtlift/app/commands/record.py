"""``rtlift record (--serial PORT | --can INTERFACE:CHANNEL) EXPERIMENT... --out DIR
[--calibration FILE] [--seed N] [--tare-seconds S] [--log]``: record experiments on a rig
whose DAQ speaks protocol version 2, commanding the actuator from the host
(:mod:`rtlift.app.record`).

EXPERIMENT is a standard experiment, ``campaign`` (all eight, in order) or a program file
(CSV ``t, envelope_v, burst_period_ms``; INTERFACES.md). Writes ``DIR/NAME.csv`` per
experiment (with ``--log`` the raw frames beside it: ``NAME.bin`` on serial, ``NAME.asc`` on
CAN, and ``NAME.<ext>.commands.csv``). Exit 0 when every record is complete, 1 when one is
partial (interrupted, device gone, link too bad), 2 on bad input (including a device that does
not echo commands).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from typing import Any

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    from rtlift.app.link_options import add_link_arguments

    p = subparsers.add_parser(
        "record", help="record experiments on a rig over protocol version 2",
        description="Record experiments on a rig whose DAQ speaks protocol version 2: the host commands the "
                    "actuator through each program (after an actuator-off tare) and writes DIR/NAME.csv per "
                    "experiment, ready for rtlift identify. Exit 0 when every record is complete, 1 when one "
                    "is partial (interrupted, device gone, link too bad), 2 on bad input (including a device "
                    "that does not echo commands).")
    add_link_arguments(p)
    p.add_argument("experiments", nargs="+", metavar="EXPERIMENT",
                   help="static, single_burst, train_T1p75, train_T3p5, train_T7, sine_k0125, sine_k025, "
                        "random, campaign (all eight) or a program file (CSV t,envelope_v,burst_period_ms)")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the records (created)")
    p.add_argument("--calibration", metavar="FILE", help="calibration TOML (default: the paper's bench)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random experiment's envelope (default 0)")
    p.add_argument("--tare-seconds", type=float, default=None, metavar="S",
                   help="actuator off before each program, for the tare (default: the calibration's, 2 s)")
    p.add_argument("--log", action="store_true", help="write each experiment's raw frames beside its record")
    p.set_defaults(func=_run)


def programs(names: list[str], volts: Any, seed: int) -> list[Any]:
    """The programs the EXPERIMENT arguments name, in order (``campaign`` expands)."""
    from rtlift.core.programs import CAMPAIGN, EXPERIMENTS, read_program, standard_program

    out = []
    for arg in names:
        if arg == "campaign":
            out += [standard_program(n, volts, seed) for n in CAMPAIGN]
        elif arg in EXPERIMENTS:
            out.append(standard_program(arg, volts, seed))
        elif os.path.exists(arg) or arg.endswith(".csv"):
            out.append(read_program(arg))
        else:
            raise UserError(f"unknown experiment {arg!r} (known: {', '.join(EXPERIMENTS)}, campaign, "
                            "or a program file)")
    seen: set[str] = set()
    for p in out:
        if p.name in seen:
            raise UserError(f"experiment {p.name!r} given twice (each writes DIR/{p.name}.csv)")
        seen.add(p.name)
    return out


class _Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: actuator off, partial record, exit 1."""


def _terminate(signum: int, frame: object) -> None:
    raise _Terminated()


def _bar(total: int, name: str) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=name, unit="sample", unit_scale=True, file=sys.stderr, mininterval=0.5,
                leave=True, bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} "
                                       "[{elapsed}<{remaining}]")


def _run(args: argparse.Namespace) -> int:
    from firmware_io.calibration import Calibration
    from firmware_io.links import open_link
    from rtlift.app.link_options import link_config_from_args
    from rtlift.app.record import OFF_PERIOD_MS, Recorder

    if args.seed < 0:
        raise UserError(f"--seed must be a non-negative integer, got {args.seed}")
    cal = Calibration.load(args.calibration)
    progs = programs(args.experiments, cal.volts_from_cmu, args.seed)
    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{args.out}: cannot create the output directory ({exc.strerror or exc})") from None
    config = link_config_from_args(args)
    where = f"serial:{args.serial}" if args.serial else f"can:{args.can}"
    previous = signal.signal(signal.SIGTERM, _terminate)
    results = []
    interrupted = False
    try:
        with open_link(config) as link:
            print(f"rtlift record: link open on {where}", file=sys.stderr, flush=True)
            rec = Recorder(link, cal, tare_s=args.tare_seconds,
                           meta={"link": where, "calibration": args.calibration or "defaults (the paper's bench)",
                                 "seed": str(args.seed)},
                           progress=_bar)
            rec.check_protocol(OFF_PERIOD_MS)
            ext = ".bin" if link.kind == "serial" else ".asc"
            for program in progs:
                if args.log:
                    link.switch_log(os.path.join(args.out, program.name + ext))
                try:
                    result = rec.run(program, os.path.join(args.out, f"{program.name}.csv"))
                except KeyboardInterrupt:
                    results.append(rec.last_result)
                    interrupted = True
                    break
                results.append(result)
                if not result.complete:
                    break
            link.switch_log(None)
    finally:
        signal.signal(signal.SIGTERM, previous)
    print(summary_table(results))
    complete = not interrupted and len(results) == len(progs) and all(r.complete for r in results)
    if not complete:
        why = "interrupted" if interrupted else next((r.reason for r in results if not r.complete), "stopped")
        print(f"rtlift record: incomplete ({why}); the actuator was commanded off, partial records are "
              "marked 'complete: false'", file=sys.stderr)
        return 1
    return 0


def summary_table(results: list[Any]) -> str:
    """One row per experiment: samples, lost, commands applied of sent, ΔCL range, complete."""
    head = f"{'experiment':<14} {'samples':>8} {'lost':>5} {'commands':>13} {'late':>4} {'ΔCL range':>19}  complete"
    rows = [head, "-" * len(head)]
    for r in results:
        c = r.counters
        cmds = f"{c.get('commands_applied', 0)}/{c.get('commands_sent', 0)}"
        rng = "" if r.dcl_range is None else f"{r.dcl_range[0]:+.4f} … {r.dcl_range[1]:+.4f}"
        done = "yes" if r.complete else f"no ({r.reason})"
        rows.append(f"{r.name:<14} {r.samples:>8} {c.get('lost', 0):>5} {cmds:>13} {r.commands_late:>4} "
                    f"{rng:>19}  {done}")
    return "\n".join(rows)
