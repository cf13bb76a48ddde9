"""``rtlift replay``: hardware-in-the-loop replay of a recorded serial or CAN log through the
same observer loop as ``rtlift observe`` — the same frames in give the same estimates out,
bit for bit. As fast as possible by default; ``--realtime`` paces a CAN log with python-can's
``MessageSync`` (its recorded timestamps) and a raw serial capture on the device clock
(one sample per 1/fs on absolute deadlines). ``--view`` serves the live plot of ``rtlift
observe`` (most useful with ``--realtime``).

A log written by ``rtlift control`` has its commands beside it (``LOG.commands.csv``): replay
then reruns the controller too — the same settle and tare, the same reference and feedback
setting, the observer fed exactly the samples the live loop fed it — and checks that it sends
the same commands after the same samples (``cmd_seq``, envelope, flags); the summary says how
many were logged and replayed and where they first differ (exit 1 if they do). ``--no-control``
replays the observer alone over every sample.

``--record F.csv`` writes what the loop converted as a record file (Cμ and envelope as the
device applied them, ΔCL as measured, time from the device's sample counter; short gaps
filled and marked, long ones refused: :mod:`rtlift.app.log_record`), which ``rtlift diagnose``
reads (``--run F.csv`` for one long run).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    from rtlift.app.view.arguments import add_view_argument

    p = subparsers.add_parser("replay", help="replay a recorded serial or CAN log through the observer",
                              description="Replay a recorded serial or CAN log through the same observer "
                                          "loop as rtlift observe: the same frames give the same estimates, "
                                          "bit for bit. As fast as possible, or paced in real time. A log "
                                          "written by rtlift control is replayed with its controller, which "
                                          "must send the same commands (exit 1 where they differ).")
    p.add_argument("log", metavar="LOG", help="raw serial capture (.bin/.raw) or CAN log (.asc/.blf/...)")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file with observer settings")
    p.add_argument("--realtime", action="store_true", help="pace the replay in real time")
    p.add_argument("--out", metavar="ESTIMATES.csv", help="estimates, one row per sample")
    p.add_argument("--calibration", metavar="FILE", help="calibration TOML (default: the bench's)")
    p.add_argument("--json", metavar="SUMMARY.json", help="counters and observer monitors")
    from rtlift.app.watch import add_arguments as add_watch_arguments

    add_watch_arguments(p, adapt=False)
    p.add_argument("--no-control", action="store_true",
                   help="do not rerun the controller of a log written by rtlift control")
    p.add_argument("--record", metavar="F.csv",
                   help="write the log as a record file (t, cmu, cmu_envelope, dcl) for rtlift diagnose")
    add_view_argument(p)
    p.set_defaults(func=run)


class _SyncedCanLog:
    """Samples of a CAN log replayed in real time by ``can.MessageSync``, decoded by the same
    assembler (and counters) as a live CAN link."""

    seq_modulus = 256
    kind = "can"

    def __init__(self, path: str) -> None:
        from firmware_io.can_codec import SEQ_MODULUS, CanAssembler
        from firmware_io.logs import LogSamples

        LogSamples(path)  # validates the path and the extension, one-line errors
        self.path = path
        self.seq_modulus = SEQ_MODULUS
        self._assembler = CanAssembler()
        self.counters = self._assembler.counters

    def __iter__(self) -> Iterator:
        import can

        from firmware_io.errors import LogError

        try:
            reader = can.LogReader(self.path)
        except (OSError, ValueError) as exc:
            raise LogError(f"{self.path}: cannot read CAN log ({' '.join(str(exc).split())})") from None
        try:
            for msg in can.MessageSync(reader, timestamps=True):
                sample = self._assembler.feed_message(msg)
                if sample is not None:
                    yield sample
        finally:
            reader.stop()


def _paced(samples, fs_hz: float) -> Iterator:
    """Samples on absolute deadlines of the device clock (``seq``), one per 1/fs."""
    period = 1.0 / fs_hz
    start = None
    index = 0
    last = None
    for s in samples:
        if last is not None:
            index += max(1, (s.seq - last) % samples.seq_modulus)
        last = s.seq
        now = time.perf_counter()
        if start is None:
            start = now
        delay = start + index * period - now
        if delay > 0:
            time.sleep(delay)
        s.host_time = time.perf_counter()
        yield s


class _CommandRecorder:
    """The link of a replayed closed loop: keeps the commands the controller sends, numbered
    as the live link numbered them (:func:`firmware_io.commands.next_cmd_seq`)."""

    closed = False
    disconnected = False

    def __init__(self, modulus: int) -> None:
        from firmware_io.commands import next_cmd_seq
        from firmware_io.logs import LoggedCommand

        self._next_seq, self._command = next_cmd_seq, LoggedCommand
        self.modulus = modulus
        self.last = 0
        self.sent: list = []
        self.position = lambda: 0

    def send_command(self, envelope_cv: int, burst_period_ms: int = 0, enable: bool = True,
                     watchdog_ms_div10: int = 0) -> int:
        self.last = self._next_seq(self.last, self.modulus)
        self.sent.append(self._command(self.position(), self.last, envelope_cv, burst_period_ms, bool(enable),
                                       watchdog_ms_div10))
        return self.last


def _rerun_control(args, meta: dict[str, str], logged: list, loop, watch, model, calibration, samples,
                   kind: str) -> dict:
    """Feed the samples through a fresh controller as ``rtlift control`` did; compare its commands."""
    from firmware_io.commands import CAN_CMD_SEQ_MODULUS, SERIAL_CMD_SEQ_MODULUS
    from rtlift.app.closed_loop import FIRST_DECISION, ControlLoop
    from rtlift.app.control import ControlConfig, LiftController, config_from_gains_text
    from rtlift.app.reference import parse_reference

    try:
        reference = parse_reference(meta["reference"])
        feedback = meta["feedback"] == "on"
        seconds = float(meta["seconds"]) if meta.get("seconds") else None
    except (KeyError, ValueError) as exc:
        raise UserError(f"{args.log}.commands.csv: the command log's metadata lacks or garbles {exc}") from None
    config = (config_from_gains_text(meta["gains"], feedback, model.fs_hz) if meta.get("gains")
              else ControlConfig(feedback=feedback, fs_hz=model.fs_hz))  # logs from before the design: hand PI
    controller = LiftController(model, config)
    recorder = _CommandRecorder(SERIAL_CMD_SEQ_MODULUS if kind == "serial" else CAN_CMD_SEQ_MODULUS)
    closed = ControlLoop(recorder, loop, controller, reference, calibration, model.fs_hz,
                         None if seconds is None else int(round(seconds * model.fs_hz)),
                         first_at_once=meta.get(FIRST_DECISION[0]) == FIRST_DECISION[1])
    watch.follow(closed)     # the monitor holds off after the reference's steps, the swaps change the controller
    recorder.position = lambda: closed.received
    switched_off = bool(logged) and not logged[-1].enable
    stop = logged[-1].after_samples if switched_off else None
    loop.stats.end = "ended"
    for sample in samples:
        if stop is not None and closed.received >= stop:
            break
        closed.feed(sample)
        if closed.done:
            loop.stats.end = "completed"
            break
    if switched_off:
        closed.switch_off(wait_echo=False)
    replayed = recorder.sent
    first = next((i for i, (a, b) in enumerate(zip(logged, replayed, strict=False)) if a != b), None)
    if first is None and len(logged) != len(replayed):
        first = min(len(logged), len(replayed))
    difference = None
    if first is not None:
        def at(rows: list, i: int) -> str:
            return str(rows[i]) if i < len(rows) else "nothing"
        difference = f"command {first + 1}: logged {at(logged, first)}, replayed {at(replayed, first)}"
    return {"logged": len(logged), "replayed": len(replayed), "identical": first is None,
            "first_difference": difference, "reference": meta["reference"], **closed.tracking()}


def _write_record(args, converter, source, fs_hz: float, data: dict, commands) -> None:
    """``--record``: the samples the loop converted as a record file (:mod:`rtlift.app.log_record`)."""
    from pathlib import Path

    from rtlift.app.log_record import loop_record
    from rtlift.core.records import write_record

    meta = {"source_log": args.log, "log_kind": source.kind,
            "loop": "control" if commands is not None else "observe", "model": args.model,
            **{k: data[k] for k in ("received", "lost", "crc_errors", "duplicates", "resyncs", "events") if k in data}}
    if commands is not None:
        meta.update({f"control_{k}": commands[0][k] for k in ("reference", "feedback") if k in commands[0]},
                    commands_logged=len(commands[1]))
    rec = loop_record(converter, source.seq_modulus, fs_hz, Path(args.record).stem, meta)
    try:
        write_record(args.record, rec)
    except OSError as exc:
        raise UserError(f"{args.record}: cannot write record ({exc.strerror or exc})") from None
    print(f"rtlift replay: record {args.record}: {len(rec)} samples ({len(rec) / fs_hz:.1f} s), "
          f"{rec.meta['filled']} filled in {rec.meta['gaps']} gap(s)")


def _watch(args, model):
    """The monitor (``--monitor``), and the live loop's adaptations from ``LOG.events.jsonl``
    repeated at the same samples."""
    import json
    import os

    from rtlift.app.watch import attach, events_path

    path = events_path(args.log, None)
    logged = None
    if os.path.isfile(path):
        try:
            with open(path, encoding="utf-8") as f:
                logged = [json.loads(line) for line in f if line.strip()]
        except (OSError, ValueError) as exc:
            raise UserError(f"{path}: cannot read the loop's events ({exc})") from None
    adaptations = [e for e in logged or [] if e.get("event") == "adaptation"]
    return attach(args, model, "rtlift replay", replay=adaptations if adaptations else None,
                  quiet=True), logged


def _compare_events(logged: list | None, data: dict) -> dict:
    """The replay's departures and swaps against those the live loop logged."""
    deps = [(d["sample"], d["test"]) for d in data.get("departures", [])]
    swaps = [(a["index"], a["model_file"]) for a in data.get("adaptations", []) if a.get("swapped")]
    out = {"logged": None if logged is None else len(logged), "departures": len(deps), "adaptations": len(swaps),
           "identical": True, "first_difference": None}
    if logged is None:
        return out
    live_deps = [(e["sample"], e["test"]) for e in logged if e.get("event") == "departure"]
    live_swaps = [(e["index"], e["model_file"]) for e in logged if e.get("event") == "adaptation"]
    for what, a, b in (("departures", live_deps, deps), ("adaptations", live_swaps, swaps)):
        if a != b:
            i = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b)))
            out.update(identical=False, first_difference=f"{what} {i + 1}: logged "
                       f"{a[i] if i < len(a) else 'nothing'}, replayed {b[i] if i < len(b) else 'nothing'}")
            break
    return out


def run(args: argparse.Namespace) -> int:
    from firmware_io.calibration import Calibration
    from firmware_io.convert import Converter
    from firmware_io.logs import read_command_log, read_log
    from rtlift.app.live import EstimateWriter, ObserverLoop, summary, write_summary
    from rtlift.app.log_record import RecordingConverter
    from rtlift.app.view.arguments import start_view
    from rtlift.model.modelfile import load_model
    from rtlift.observer import Observer

    model = load_model(args.model)
    observer = Observer.from_model(model)
    observer.warm_up()                      # compile before the first frame (matters with --realtime)
    calibration = Calibration.load(args.calibration)
    source = read_log(args.log, calibration)
    commands = None if args.no_control else read_command_log(args.log)
    if args.realtime:
        stream = _SyncedCanLog(args.log) if source.kind == "can" else source
        samples = iter(stream) if source.kind == "can" else _paced(source, model.fs_hz)
        counters_of = stream
    else:
        samples = iter(source)
        counters_of = source
    view = start_view(args, f"rtlift replay {args.log}", model.fs_hz)
    data = None
    try:
        meta = {"model": args.model, "log": args.log, "fs_hz": f"{model.fs_hz:g}"}
        writer = EstimateWriter(args.out, meta) if args.out else None
        converter = Converter(calibration, model.fs_hz)
        if args.record:
            converter = RecordingConverter(converter)
        watch, logged_events = _watch(args, model)
        loop = ObserverLoop(observer, converter, source.seq_modulus, writer=writer, fs_hz=model.fs_hz,
                            monitor=watch.monitor, adapter=watch.adapter, tap=None if view is None else view.tap)
        if view is not None:
            view.counters = lambda: {**counters_of.counters.as_dict(), "estimates": loop.stats.estimates}
        t0 = time.perf_counter()
        control = None
        try:
            if commands is None:
                loop.run(samples)
            else:
                control = _rerun_control(args, *commands, loop, watch, model, calibration, samples, source.kind)
        except KeyboardInterrupt:
            loop.stats.end = "interrupted"
        finally:
            loop.stop()             # the listeners' on_stop: the estimates file closed
        seconds = time.perf_counter() - t0
        data = summary(counters_of.counters.as_dict(), loop.stats, loop.observer, model=str(args.model),
                       log=str(args.log), realtime=bool(args.realtime), host_seconds=seconds,
                       device_seconds=(loop.stats.samples + loop.stats.filled) / model.fs_hz)
        if control is not None:
            data["commands"] = control
        data.update(watch.summary())
        data["loop_events"] = _compare_events(logged_events, data)
        if args.json:
            write_summary(args.json, data)
    finally:
        if view is not None:
            view.close(data)
    if loop.stats.samples == 0:
        raise UserError(f"{args.log}: no samples in the log")
    if args.record:
        _write_record(args, converter, source, model.fs_hz, data, commands)
    o = data["observer"]
    print(f"rtlift replay: {args.log}: {loop.stats.samples} samples ({data['device_seconds']:.1f} s device "
          f"time) in {seconds:.2f} s; received {data['received']} lost {data['lost']} crc_errors "
          f"{data['crc_errors']}; {data['estimates']} estimates"
          + (f"; NIS mean {o['nis_mean']:.3g}" if o["nis_mean"] is not None else ""))
    ev = data["loop_events"]
    if ev["logged"] is not None:
        print(f"rtlift replay: {ev['departures']} departure(s) and {ev['adaptations']} adaptation(s) "
              f"{'as logged' if ev['identical'] else 'DIFFERENT from the log: ' + ev['first_difference']}")
    if loop.stats.end == "interrupted":
        return 130
    if ev["logged"] is not None and not ev["identical"]:
        return 1
    if control is not None:
        if not control["identical"]:
            print(f"rtlift replay: the controller's commands differ from the log at {control['first_difference']}",
                  file=sys.stderr)
            return 1
        print(f"rtlift replay: controller rerun: {control['replayed']} commands, identical to the "
              f"{control['logged']} logged; tracking RMSE "
              + ("–" if control["tracking_rmse"] is None else f"{control['tracking_rmse']:.4g}"))
    return 0
