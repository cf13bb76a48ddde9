"""``rtlift demo``: the main job on the simulated bench, end to end (see :mod:`rtlift.app.demo`)."""

from __future__ import annotations

import argparse

from rtlift.core.errors import UserError

LIVE_MIN_S = 5.0
"""The live stage's shortest run (s): settle and tare (3 s, actuator off), then 2 s of the program."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("demo", help="the whole product on the simulated bench, end to end",
                              description="Serve the simulated bench on a pseudo-terminal, record the "
                                          "standard campaign through firmware_io, identify, validate, run "
                                          "the observer live, diagnose an undeclared effect, track a lift reference "
                                          "in closed loop under an undeclared actuator fade, write a report.")
    p.add_argument("--out", default="rtlift-demo", metavar="DIR", help="output directory (default: rtlift-demo)")
    p.add_argument("--seed", type=int, default=0, help="bench seed (default 0)")
    p.add_argument("--live-seconds", type=float, default=20.0, metavar="S",
                   help=f"how long the observer runs live at 400 Hz, at least {LIVE_MIN_S:g} (default 20)")
    p.add_argument("--effect", metavar="SPEC", help="the undeclared effect to diagnose, NAME[:k=v,...] "
                   "(default: a 24 Hz sensor resonance)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import os

    from hil_sim.effects import parse_effect
    from rtlift.app.demo import DEMO_EFFECT, DemoOptions, run_demo
    from rtlift.app.demo_report import results_table

    if not args.live_seconds >= LIVE_MIN_S:
        raise UserError(f"--live-seconds must be at least {LIVE_MIN_S:g} (3 s of settle and tare with the actuator "
                        f"off come first), got {args.live_seconds}")
    effect = args.effect or DEMO_EFFECT
    parse_effect(effect)                                  # a bad spec is a one-line error now, not later
    try:
        os.makedirs(args.out, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{args.out}: cannot create output directory ({exc.strerror})") from None
    summary = run_demo(DemoOptions(out_dir=args.out, seed=args.seed, live_seconds=args.live_seconds,
                                   effect=effect, progress=not args.quiet))
    print(f"rtlift demo: finished in {summary['elapsed_s']:.0f} s; report {os.path.join(args.out, 'report.md')}")
    print()
    print(results_table(summary))
    return 0
