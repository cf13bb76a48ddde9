"""``rtlift replay``: hardware-in-the-loop replay of a recorded serial or CAN log through the
same observer loop as ``rtlift observe`` — the same frames in give the same estimates out,
bit for bit. As fast as possible by default; ``--realtime`` paces a CAN log with python-can's
``MessageSync`` (its recorded timestamps) and a raw serial capture on the device clock
(one sample per 1/fs on absolute deadlines). ``--view`` serves the live plot of ``rtlift
observe`` (most useful with ``--realtime``).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    from rtlift.view.arguments import add_view_argument

    p = subparsers.add_parser("replay", help="replay a recorded serial or CAN log through the observer",
                              description=__doc__.splitlines()[0])
    p.add_argument("log", metavar="LOG", help="raw serial capture (.bin/.raw) or CAN log (.asc/.blf/...)")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file with observer settings")
    p.add_argument("--realtime", action="store_true", help="pace the replay in real time")
    p.add_argument("--out", metavar="ESTIMATES.csv", help="estimates, one row per sample")
    p.add_argument("--calibration", metavar="FILE", help="calibration TOML (default: the bench's)")
    p.add_argument("--json", metavar="SUMMARY.json", help="counters and observer monitors")
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


def run(args: argparse.Namespace) -> int:
    from firmware_io.calibration import Calibration
    from firmware_io.convert import Converter
    from firmware_io.logs import read_log
    from rtlift.live import EstimateWriter, ObserverLoop, summary, write_summary
    from rtlift.modelfile import load_model
    from rtlift.observer import Observer
    from rtlift.view.arguments import start_view

    model = load_model(args.model)
    observer = Observer.from_model(model)
    observer.warm_up()                      # compile before the first frame (matters with --realtime)
    calibration = Calibration.load(args.calibration)
    source = read_log(args.log, calibration)
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
        writer = EstimateWriter(args.out, {"model": args.model, "log": args.log, "fs_hz": "400"}) if args.out else None
        loop = ObserverLoop(observer, Converter(calibration, model.fs_hz), source.seq_modulus, writer=writer,
                            fs_hz=model.fs_hz)
        if view is not None:
            view.counters = lambda: {**counters_of.counters.as_dict(), "estimates": loop.stats.estimates}
            loop.tap = view.tap
        t0 = time.perf_counter()
        try:
            loop.run(samples)
        except KeyboardInterrupt:
            loop.stats.end = "interrupted"
        finally:
            if writer is not None:
                writer.close()
        seconds = time.perf_counter() - t0
        data = summary(counters_of.counters.as_dict(), loop.stats, observer, model=str(args.model),
                       log=str(args.log), realtime=bool(args.realtime), host_seconds=seconds,
                       device_seconds=(loop.stats.samples + loop.stats.filled) / model.fs_hz)
        if args.json:
            write_summary(args.json, data)
    finally:
        if view is not None:
            view.close(data)
    if loop.stats.samples == 0:
        raise UserError(f"{args.log}: no samples in the log")
    o = data["observer"]
    print(f"rtlift replay: {args.log}: {loop.stats.samples} samples ({data['device_seconds']:.1f} s device "
          f"time) in {seconds:.2f} s; received {data['received']} lost {data['lost']} crc_errors "
          f"{data['crc_errors']}; {data['estimates']} estimates"
          + (f"; NIS mean {o['nis_mean']:.3g}" if o["nis_mean"] is not None else ""))
    return 130 if loop.stats.end == "interrupted" else 0
