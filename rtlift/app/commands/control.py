"""``rtlift control``: closed-loop lift tracking at 400 Hz over protocol version 2.

The observer's estimate in, burst-envelope commands out (:mod:`rtlift.app.closed_loop`,
:mod:`rtlift.app.control`). The host first holds the actuator off for the settle and tare
(3 s on the default calibration); the reference's time starts after them. ``--log`` keeps
the raw frames and, beside them, every command sent (``LOG.commands.csv``, with the reference
and the feedback setting): ``rtlift replay`` reruns the controller on the frames and checks
that it sends the same commands. Ctrl-C, SIGTERM and a vanished device end the loop
with the actuator switched off and ``--json`` written on every exit path. With
``--reconnect`` a vanished device is reopened with backoff instead: while it is gone no command
is sent and the device's watchdog takes its actuator to 0 (the safe state), the observer predicts
through the gap (rows flagged 16) without stepping the controller, and tracking resumes on the
first sample after it. ``--view`` serves the live page of ``rtlift observe``.

The feedback gains are designed from the model with python-control before the link opens
(:mod:`rtlift.app.control_design`: PI with a lead–lag at the burst rate, gain margin ≥ 6 dB,
phase margin ≥ 45°, predicted |S| ≤ +2.85 dB, robust to the model's error, scheduled over Cμ; a minute
on a loaded machine) and cached beside the model (``MODEL.design-<sha12>.json``, keyed by the model
file's bytes): a later start with the same model reads it. A design that misses a target (a
saved one included: its margins are computed again) is refused unless
``--accept-design-warnings``; ``--kp``/``--ti`` set a plain PI by hand instead.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    from rtlift.app.link_options import add_live_arguments, add_reconnect_argument
    from rtlift.app.view.arguments import add_view_argument
    from rtlift.app.watch import add_arguments as add_watch_arguments

    p = subparsers.add_parser("control", help="track a lift reference live over protocol version 2",
                              description="Track a lift reference live: the observer's estimate drives "
                                          "the burst envelope (feedforward from the model, optional PI "
                                          "feedback), sent as commands over protocol version 2 at 400 Hz. "
                                          "The actuator is switched off on the way out.")
    add_live_arguments(p)
    p.add_argument("--reference", required=True, metavar="SPEC",
                   help="steps:V@T,V@T,... | sine:mean=M,amp=A,hz=F | a CSV file with columns t, dcl_ref")
    p.add_argument("--seconds", type=float, metavar="S", help="stop after S seconds of tracking "
                   "(a device that sends nothing for 5 s ends the run: exit 1)")
    p.add_argument("--feedback", choices=("on", "off"), default="on",
                   help="PI feedback on the observer's estimate (off: feedforward only)")
    p.add_argument("--kp", type=float, metavar="K",
                   help="hand-set PI: proportional gain (ΔCL per ΔCL; default: the model-based design)")
    p.add_argument("--ti", type=float, metavar="S", help="hand-set PI: integral time (s)")
    p.add_argument("--design", metavar="REPORT.json",
                   help="the gains of a saved design (rtlift design's report.json) instead of designing at start")
    p.add_argument("--accept-design-warnings", action="store_true",
                   help="run a design that misses one of its targets (refused otherwise)")
    p.add_argument("--json", metavar="SUMMARY.json", help="counters, command latency, tracking RMSE")
    add_reconnect_argument(p)
    add_watch_arguments(p)
    add_view_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from firmware_io.calibration import Calibration
    from firmware_io.convert import Converter
    from firmware_io.links import open_link
    from rtlift.app.applied import commands_not_applied
    from rtlift.app.closed_loop import FIRST_DECISION, ControlLoop
    from rtlift.app.control import LiftController, gains_text
    from rtlift.app.link_options import link_config_from_args
    from rtlift.app.live import ObserverLoop, run_live, summary, write_summary
    from rtlift.app.reference import parse_reference
    from rtlift.app.view.arguments import start_view
    from rtlift.app.watch import attach
    from rtlift.model.domain import watch_domain
    from rtlift.model.modelfile import load_model
    from rtlift.observer import Observer

    if args.seconds is not None and not args.seconds > 0:
        raise UserError(f"--seconds must be positive, got {args.seconds}")
    reference = parse_reference(args.reference)
    model = load_model(args.model)
    config, gains = control_config(model, args.feedback == "on", args.kp, args.ti, args.design,
                                   model_path=args.model, accept_warnings=args.accept_design_warnings)
    if gains.get("observer_q_bias") is not None:   # the observer the design was checked with
        model.observer_config = {**model.observer_config, "q_bias": gains["observer_q_bias"]}
    observer = Observer.from_model(model)
    controller = LiftController(model, config)
    calibration = Calibration.load(args.calibration)
    _warm_up(observer, controller)
    link = open_link(link_config_from_args(args, log=args.log, calibration=calibration))
    link.command_log_meta = {"tool": "rtlift control", "model": args.model, "reference": args.reference,
                             "feedback": args.feedback, "gains": gains_text(config),
                             "seconds": "" if args.seconds is None else repr(args.seconds),
                             FIRST_DECISION[0]: FIRST_DECISION[1]}
    where = args.serial or args.can
    print(f"rtlift control: {link.kind} link open on {where}; Ctrl-C stops", file=sys.stderr, flush=True)
    fs = model.fs_hz
    watch = attach(args, model, "rtlift control")
    loop = None
    view = start_view(args, f"rtlift control {where}", fs,
                      lambda: {**link.counters.as_dict(), "estimates": loop.stats.estimates if loop else 0,
                               **(watch.counts() if watch else {})})
    loop = ObserverLoop(observer, watch_domain(Converter(calibration, fs), model, "rtlift control"), link.seq_modulus,
                        fs_hz=fs, step_stats=True,
                        monitor=watch.monitor, adapter=watch.adapter, tap=None if view is None else view.tap)
    link.on_gap = loop.bridge
    tracking = None if args.seconds is None else int(round(args.seconds * fs))
    closed = ControlLoop(link, loop, controller, reference, calibration, fs, tracking)
    watch.follow(closed)
    data = None
    t0 = time.perf_counter()
    try:
        code, message = run_live("rtlift control", loop.stats, link, closed.feed, lambda: closed.done,
                                 lambda: closed.received, args.seconds)
    finally:
        try:
            closed.switch_off()
            link.close()
            watch.close()
            data = summary(link.counters.as_dict(), loop.stats, loop.observer, model=str(args.model),
                           link=link.kind, host_seconds=time.perf_counter() - t0,
                           device_seconds=(loop.stats.samples + loop.stats.filled + loop.stats.bridged) / fs,
                           tare_cl=loop.converter.tare_cl, reference=args.reference)
            data.update(closed.results())
            data.update(watch.summary())
            data["gains"] = gains
            if args.json:
                write_summary(args.json, data)
            _print(data)
        finally:
            if view is not None:
                view.close(data)
    ignored = commands_not_applied(data["commands_sent"], data["commands_applied"])
    if code == 0 and ignored:       # a run the device did not follow is no success (issue 44)
        code, message = 1, f"rtlift control: {ignored}; the run was not under control (summary written)"
    if message:
        print(message, file=sys.stderr)
    return code


def control_config(model, feedback: bool, kp: float | None, ti: float | None,
                   design_file: str | None = None, *, model_path: str | None = None,
                   accept_warnings: bool = False) -> tuple[object, dict]:
    """The controller's settings and a summary of where its gains came from: the design
    (default; cached beside ``model_path``), a saved design (``--design``) or ``--kp``/``--ti`` by
    hand (the other one at its default). A design that misses a target: UserError unless
    ``accept_warnings``."""
    from rtlift.app.control import ControlConfig

    if design_file is not None and (kp is not None or ti is not None):
        raise UserError("--design and --kp/--ti are alternatives: give one")
    if design_file is not None:
        from rtlift.app.control_design import load_design

        saved = load_design(design_file, accept_warnings=accept_warnings)
        schedule = saved.schedule()
        return (saved.control_config(feedback, model.fs_hz),
                {"source": f"design file {design_file}", "structure": saved.structure,
                 "schedule": [list(r) for r in schedule],
                 "observer_q_bias": (saved.observer or {}).get("q_bias")})
    if kp is not None or ti is not None:
        base = ControlConfig()
        kp = base.kp if kp is None else kp
        ti = base.ti_s if ti is None else ti
        if not (math.isfinite(kp) and kp >= 0):
            raise UserError(f"--kp must be a non-negative number, got {kp}")
        if not (math.isfinite(ti) and ti > 0):
            raise UserError(f"--ti must be a positive number of seconds, got {ti}")
        return ControlConfig(kp=kp, ti_s=ti, feedback=feedback, fs_hz=model.fs_hz), {"source": "hand", "kp": kp,
                                                                                      "ti_s": ti}
    if not feedback:
        return ControlConfig(feedback=False, fs_hz=model.fs_hz), {"source": "none (feedback off)"}
    from rtlift.app.control_design import cached_design

    design, source = cached_design(model, model_path, accept_warnings)
    return (design.control_config(True, model.fs_hz),
            {"source": source, "structure": design.structure, "choice": design.choice, **design.summary(),
             "schedule": [list(r) for r in design.schedule()],
             "observer_q_bias": (design.observer or {}).get("q_bias")})


def _warm_up(observer, controller) -> None:
    """Run the compiled steps once (and reset them) before the link opens: loading the JIT
    cache mid-loop would delay the first commands' echoes by hundreds of milliseconds."""
    observer.warm_up()
    for k in range(100):
        est = observer.step(0.002 if k % 50 < 4 else 0.0, 0.002, 0.01)
        controller.step(est, 0.01)
    observer.reset()
    controller.reset()



def _fmt(v: float | None, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def _print(d: dict) -> None:
    print(f"rtlift control: {d['end']}: received {d['received']} lost {d['lost']} crc_errors {d['crc_errors']}; "
          f"commands sent {d['commands_sent']} applied {d['commands_applied']} watchdog trips "
          f"{d['watchdog_trips']} (link stalls {d.get('link_stalls', 0)}, longest silence "
          f"{d.get('link_silence_max_ms', 0.0):.0f} ms); command latency p50 "
          f"{_fmt(d['command_latency_p50_ms'], '.2f')} ms "
          f"p99 {_fmt(d['command_latency_p99_ms'], '.2f')} ms; tracking RMSE "
          f"{_fmt(d['tracking_rmse'], '.4f')} (feedback {'on' if d['feedback'] else 'off'}), "
          f"saturated {d['saturated_fraction']:.1%}", flush=True)
