"""``rtlift observe``: the Kalman observer live at 400 Hz on a serial or CAN link.

Driven by frame arrival (the device's ``seq`` is the clock; the host clock only measures the
receive → estimate latency). ``--log`` keeps the raw frames (``.bin``/``.raw`` serial
capture, ``.asc``/``.blf`` CAN log) for ``rtlift replay``; ``--out`` the estimates (CSV).
Ctrl-C, SIGTERM and a vanished device end the loop with every file flushed, and
``--json`` is written on every exit path; ``--view`` serves a live plot on loopback (its
last word is the summary's counters, then it stops); with ``--reconnect`` a vanished device is reopened
with backoff instead, and the observer predicts through the gap (rows flagged 16).
"""

from __future__ import annotations

import argparse
import sys
import time

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    from rtlift.app.link_options import add_live_arguments, add_reconnect_argument
    from rtlift.app.view.arguments import add_view_argument
    from rtlift.app.watch import add_arguments as add_watch_arguments

    p = subparsers.add_parser("observe", help="run the Kalman observer live on a serial or CAN link",
                              description="Run the Kalman observer live at the model's rate (400 Hz) on "
                                          "a serial or CAN link: each sample's lift estimate, optionally "
                                          "written to a file, logged raw for a later replay, and shown "
                                          "on a live plot. Ctrl-C stops.")
    add_live_arguments(p)
    p.add_argument("--out", metavar="ESTIMATES.csv", help="estimates, one row per sample")
    p.add_argument("--seconds", type=float, metavar="S", help="stop after S seconds of device time "
                   "(a device that sends nothing for 5 s ends the run: exit 1)")
    p.add_argument("--json", metavar="SUMMARY.json", help="counters and latency percentiles")
    add_watch_arguments(p)
    p.add_argument("--spin", nargs="?", const=True, default=False, type=_spin_window, metavar="WINDOW_MS",
                   help="serial link: busy-poll the port between samples instead of sleeping, keeping the "
                        "observer's working set cached (lower step time and latency; costs that core); with "
                        "WINDOW_MS, sleep until WINDOW_MS before each sample is due and spin only from there "
                        "(most of the gain at a fraction of the core: 0.5 ms took 19 %% of it)")
    add_reconnect_argument(p)
    add_view_argument(p)
    p.set_defaults(func=run)


def _spin_window(text: str) -> float:
    """--spin's WINDOW_MS, checked by the link's own rule (:func:`firmware_io.links.spin_window_s`)."""
    from firmware_io.links import spin_window_s

    try:
        spin_window_s(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected {exc}") from None
    return float(text)


def run(args: argparse.Namespace) -> int:
    from firmware_io.calibration import Calibration
    from firmware_io.convert import Converter
    from firmware_io.links import open_link
    from rtlift.app.link_options import link_config_from_args
    from rtlift.app.live import EstimateWriter, ObserverLoop, run_live, summary, write_summary
    from rtlift.app.view.arguments import start_view
    from rtlift.app.watch import attach
    from rtlift.model.domain import watch_domain
    from rtlift.model.modelfile import load_model
    from rtlift.observer import Observer

    if args.seconds is not None and not args.seconds > 0:
        raise UserError(f"--seconds must be positive, got {args.seconds}")
    model = load_model(args.model)
    observer = Observer.from_model(model)
    compiled = (f"observer step compiled in {observer.warm_up():.2f} s" if observer.compiled
                else "observer step not compiled: the model carries stages the compiled step lacks")
    calibration = Calibration.load(args.calibration)
    if args.spin and not args.serial:
        raise UserError("--spin is for a serial link (--serial); a CAN interface reads in its own driver")
    extra = {"spin": args.spin} if args.spin else {}
    link = open_link(link_config_from_args(args, log=args.log, calibration=calibration, **extra))
    if args.spin:
        link.on_idle = observer.touch    # keep the step's working set cached while waiting
    where = args.serial or args.can
    print(f"rtlift observe: {link.kind} link open on {where} ({compiled}); Ctrl-C stops", file=sys.stderr, flush=True)
    writer = None
    loop = None
    watch = None
    view = None
    t0 = time.perf_counter()
    try:
        writer = EstimateWriter(args.out, {"model": args.model, "fs_hz": f"{model.fs_hz:g}"}) if args.out else None
        watch = attach(args, model, "rtlift observe")
        view = start_view(args, f"rtlift observe {where}", model.fs_hz,
                          lambda: {**link.counters.as_dict(), "estimates": loop.stats.estimates if loop else 0,
                                   **(watch.counts() if watch else {})})
        loop = ObserverLoop(observer, watch_domain(Converter(calibration, model.fs_hz), model, "rtlift observe"),
                            link.seq_modulus, writer=writer,
                            fs_hz=model.fs_hz, step_stats=True, monitor=watch.monitor, adapter=watch.adapter,
                            tap=None if view is None else view.tap,
                            max_samples=None if args.seconds is None else int(round(args.seconds * model.fs_hz)))
        link.on_gap = loop.bridge
        code, message = run_live("rtlift observe", loop.stats, link, loop.feed, lambda: loop.done,
                                 lambda: loop.stats.samples, args.seconds)
    finally:
        link.close()
        if loop is not None:
            loop.stop()             # the listeners' on_stop: the estimates file closed
        elif writer is not None:
            writer.close()
        data = None
        try:
            if loop is not None:
                data = summary(link.counters.as_dict(), loop.stats, loop.observer, model=str(args.model),
                               link=link.kind, host_seconds=time.perf_counter() - t0,
                               device_seconds=(loop.stats.samples + loop.stats.filled + loop.stats.bridged)
                               / model.fs_hz,
                               tare_cl=loop.converter.tare_cl)
                if watch is not None:
                    watch.close()
                    data.update(watch.summary())
                if args.json:
                    write_summary(args.json, data)
                _print(data)
        finally:
            if view is not None:
                view.close(data)
    if message:
        print(message, file=sys.stderr)
    return code



def _print(d: dict) -> None:
    p50, p99 = d["latency_p50_ms"], d["latency_p99_ms"]
    lat = f"latency p50 {p50:.3f} ms p99 {p99:.3f} ms" if p50 is not None else "no samples"
    o = d["observer"]
    nis = f"NIS mean {o['nis_mean']:.3g}, {o['nis_band_fraction']:.1%} in band" if o["nis_mean"] is not None else ""
    gaps = ""
    if d.get("reconnects"):
        gaps = f" reconnects {d['reconnects']} (lost across them {d['gap_lost']}"
        if d["gaps_unknown"]:
            gaps += f"; {d['gaps_unknown']} gap(s) not knowable from seq, about {d['gap_lost_estimated']} samples"
        gaps += ")"
    print(f"rtlift observe: {d['end']}: received {d['received']} lost {d['lost']} crc_errors {d['crc_errors']} "
          f"resyncs {d['resyncs']} duplicates {d['duplicates']} events {d['events']}{gaps}; "
          f"{d['estimates']} estimates; {lat}; {nis}", flush=True)
