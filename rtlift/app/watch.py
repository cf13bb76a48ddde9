"""``--monitor`` and ``--adapt`` of ``rtlift observe`` and ``rtlift control`` (and their replay).

:func:`attach` makes a :class:`~rtlift.observer.monitor.DepartureMonitor` for an
:class:`~rtlift.app.live.ObserverLoop` (on by default; off with ``--monitor off``, or when the
model file has no fingerprint, which is said in one line) and, with ``--adapt DIR``, an
:class:`~rtlift.app.adapt.Adapter`, both registered with the loop when it is made. Departures and adaptations are

- printed as one line each on stderr,
- appended to the events file (``LOG.events.jsonl`` beside a ``--log``, else
  ``DIR/events.jsonl``), one JSON object a line, flushed at once — ``rtlift replay`` reads the
  adaptations from it,
- and in SUMMARY.json: ``departures`` (``{t_s, test, statistic, threshold, suspect, sample}``),
  ``adaptations`` (``{t_s, index, accepted, rmse_before, rmse_after, model_file, ...}``; a
  diagnosis that accepted nothing is listed with ``swapped`` absent and its ``reason``) and
  ``monitor`` (the scale, evaluations, thresholds, the last statistics).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
from typing import Any

from rtlift.core.errors import UserError


def add_arguments(p: argparse.ArgumentParser, adapt: bool = True) -> None:
    p.add_argument("--monitor", nargs="+", default=["on"], metavar="MODE",
                   help="on: compare the loop's residual with the model's identification fingerprint in "
                        "sliding windows and report departures, with the thresholds in the model file (the "
                        "default); off: no monitor; calibrate OUT.json: a baseline run — record every "
                        "statistic over this (clean) run and write thresholds from it to OUT.json; FILE: "
                        "use the thresholds of such a file")
    if not adapt:
        return
    p.add_argument("--adapt", metavar="DIR",
                   help="on a departure, diagnose the recorded window in another process and swap in the "
                        "augmented model at a burst onset; windows, reports and model files go to DIR")
    p.add_argument("--adapt-structure", action="store_true",
                   help="with --adapt: also swap in what the diagnosis calls structure (a deficiency the model "
                        "had since identification); by default that is reported, not swapped")


def monitor_mode(value: list[str] | str | None) -> tuple[str, str | None]:
    """``--monitor``'s words as (mode, file): ("on", None), ("off", None), ("calibrate", OUT) or
    ("file", FILE); a malformed one is a :class:`UserError`."""
    words = [value] if isinstance(value, str) else list(value or ["on"])
    if words in (["on"], ["off"]):
        return words[0], None
    if words[0] == "calibrate":
        if len(words) != 2:
            raise UserError("--monitor calibrate needs the file to write the thresholds to: "
                            "--monitor calibrate OUT.json")
        return "calibrate", words[1]
    if len(words) != 1:
        raise UserError(f"--monitor {' '.join(words)}: give on, off, calibrate OUT.json or a thresholds file")
    return "file", words[0]


def read_thresholds(path: str) -> dict[str, float]:
    """The thresholds of a ``--monitor calibrate`` file (:func:`calibration_doc`)."""
    from rtlift.observer.monitor import TESTS

    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except OSError as exc:
        raise UserError(f"--monitor {path}: cannot read ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"--monitor {path}: not a JSON file ({exc.msg} at line {exc.lineno})") from None
    th = doc.get("thresholds") if isinstance(doc, dict) else None
    if not isinstance(th, dict) or not th:
        raise UserError(f"--monitor {path}: no 'thresholds' (write one with --monitor calibrate {path})")
    out = {}
    for k, v in th.items():
        if k not in TESTS:
            raise UserError(f"--monitor {path}: unknown test {k!r} (tests: {', '.join(TESTS)})")
        if v is None:
            continue
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise UserError(f"--monitor {path}: threshold of {k} must be a positive number, got {v!r}")
        out[k] = float(v)
    return out


def calibration_doc(monitor: Any, model_path: str) -> dict[str, Any]:
    """Thresholds from a baseline run: each statistic's largest value held for ``persist``
    consecutive evaluations over the run, times :data:`~rtlift.observer.monitor.MARGIN` (a
    statistic never evaluated, or 0 throughout, keeps the model's threshold: ``null``)."""
    from rtlift.observer.monitor import MARGIN, TESTS, persistent_max

    hist = monitor.history or []
    pm = {t: persistent_max([h[t] for h in hist], monitor.config.persist) for t in TESTS}
    return {"format": "rtlift-monitor-thresholds", "version": 1, "model": model_path,
            "evaluations": len(hist), "seconds": monitor._sample / monitor.fs_hz, "margin": MARGIN,
            "persistent_max": pm,
            "thresholds": {t: (round(MARGIN * v, 6) if v > 0 else None) for t, v in pm.items()},
            "rule": "each statistic's largest value held for persist consecutive evaluations over a clean run "
                    "of the real loop, times the margin; null: never evaluated (the model's threshold stays)"}


def follow_reference(monitor: Any, closed: Any) -> None:
    """Tell a monitor when the closed loop's reference steps (no test judges a window holding a
    step's own transient); nothing without a monitor or a closed loop."""
    if closed is not None and monitor is not None:
        monitor.set_steps(*reference_steps(closed.reference, closed.tare_samples, closed.fs_hz))


def reference_steps(reference: Any, offset: int, fs_hz: float) -> tuple[list[int], list[float]]:
    """The samples (the monitor's count: ``offset`` samples before tracking starts, the tare) at
    which a ``steps:`` reference steps, and the steps' sizes (ΔCL; the first from 0). Other kinds
    give none (a sine, a CSV's ramps move the operating point smoothly)."""
    if getattr(reference, "kind", None) != "steps":
        return [], []
    prev, samples, sizes = 0.0, [], []
    for t, v in zip(reference.t, reference.value, strict=True):
        if v != prev:
            samples.append(offset + int(round(t * fs_hz)))
            sizes.append(v - prev)
        prev = v
    return samples, sizes


def events_path(log: str | None, adapt_dir: str | None) -> str | None:
    if log:
        return f"{log}.events.jsonl"
    if adapt_dir:
        return os.path.join(adapt_dir, "events.jsonl")
    return None


class Watch:
    """The monitor and adapter of one loop, and where their events go."""

    def __init__(self, prog: str, events_file: str | None, quiet: bool = False) -> None:
        self.prog = prog
        self.quiet = quiet
        self.monitor = None
        self.adapter = None
        self.departures: list[dict[str, Any]] = []
        self.calibrate_to: str | None = None
        self.model_path = ""
        self._lock = threading.Lock()
        self._f = None
        if events_file:
            try:
                self._f = open(events_file, "w", encoding="utf-8")
            except OSError as exc:
                raise UserError(f"{events_file}: cannot write events ({exc.strerror or exc})") from None

    def event(self, e: dict[str, Any]) -> None:
        with self._lock:
            if self._f is not None:
                self._f.write(json.dumps(e, sort_keys=True, default=float) + "\n")
                self._f.flush()

    def say(self, line: str) -> None:
        if self.quiet:
            return
        print(f"{self.prog}: {line}", file=sys.stderr, flush=True)

    def on_departure(self, d: dict[str, Any]) -> None:
        self.say(f"departure at t={d['t_s']:.2f} s: {d['test']} {d['statistic']:.3g} > {d['threshold']:.3g} "
                 f"(suspect: {d['suspect']})")
        self.event({"event": "departure", **d})
        if self.adapter is not None:
            self.adapter.on_departure(d)

    def on_adapt_event(self, e: dict[str, Any]) -> None:
        if not e.get("swapped"):
            self.say(f"diagnosis of window {e.get('n')}: {', '.join(e.get('accepted') or []) or 'nothing accepted'}"
                     f"{'; ' + e['reason'] if e.get('reason') else ''}; no swap")
        self.event(e)

    def follow(self, closed: Any) -> None:
        """The closed loop (:class:`~rtlift.app.closed_loop.ControlLoop`) this loop runs in: the
        monitor holds off after its reference's steps, the adapter swaps its controller too."""
        follow_reference(self.monitor, closed)
        if self.adapter is not None:
            self.adapter.closed = closed

    def counts(self) -> dict[str, int]:
        """Departures and swaps so far (for the live page)."""
        return {"departures": len(self.monitor.departures) if self.monitor else 0,
                "adaptations": sum(1 for a in self.adapter.adaptations if a.get("swapped")) if self.adapter else 0}

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"departures": list(self.monitor.departures) if self.monitor else []}
        if self.monitor is not None:
            out["monitor"] = self.monitor.summary()
            if out["monitor"]["input"].get("note"):
                self.say(f"monitor: {out['monitor']['input']['note']}")
        if self.adapter is not None:
            out["adaptations"] = list(self.adapter.adaptations)
        return out

    def close(self, wait_s: float | None = None) -> None:
        """The run ended: the adapter waits for a diagnosis in flight (``wait_s``; ``None``: its own
        bound, :data:`rtlift.app.adapt.END_WAIT_S`), then the thresholds and events files are written."""
        if self.adapter is not None:
            self.adapter.close(wait_s)
        if self.calibrate_to and self.monitor is not None:
            from rtlift.core.jsonfile import write_json_atomic

            doc = calibration_doc(self.monitor, self.model_path)
            try:
                write_json_atomic(self.calibrate_to, doc, stage="monitor thresholds")
            except OSError as exc:
                raise UserError(f"{self.calibrate_to}: cannot write thresholds ({exc.strerror or exc})") from None
            self.say(f"monitor thresholds from this run ({doc['evaluations']} evaluations) written to "
                     f"{self.calibrate_to}")
            self.calibrate_to = None
        with self._lock:
            if self._f is not None:
                self._f.close()
                self._f = None


def attach(args: argparse.Namespace, model: Any, prog: str, *, replay: list[dict] | None = None,
           quiet: bool = False) -> Watch:
    """The monitor (and adapter) ``args.monitor`` / ``args.adapt`` ask for, to be given to the
    :class:`~rtlift.app.live.ObserverLoop` when it is made (``monitor=watch.monitor,
    adapter=watch.adapter``; a closed loop then :meth:`Watch.follow`); ``quiet``: no stderr
    lines — a replay sums them up in one."""
    from rtlift.app.adapt import Adapter
    from rtlift.observer.monitor import DepartureMonitor

    adapt_dir = getattr(args, "adapt", None)
    if adapt_dir:
        try:
            os.makedirs(adapt_dir, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{adapt_dir}: cannot create the adapt directory ({exc.strerror})") from None
    watch = Watch(prog, events_path(getattr(args, "log", None), adapt_dir) if replay is None and not quiet else None,
                  quiet)
    watch.model_path = str(getattr(args, "model", ""))
    mode, path = monitor_mode(getattr(args, "monitor", ["on"]))
    thresholds = read_thresholds(path) if mode == "file" else None
    if mode != "off":
        try:
            watch.monitor = DepartureMonitor.for_model(model)
        except ValueError as exc:
            watch.say(f"monitor off: {exc}")
    if watch.monitor is not None:
        if thresholds is not None:
            watch.monitor.use_thresholds(thresholds, f"the baseline run {path}")
        if mode == "calibrate":
            watch.monitor.use_thresholds(dict.fromkeys(watch.monitor.thresholds, math.inf),
                                         f"none: a baseline run (--monitor calibrate {path})")
            watch.monitor.history = []
            watch.calibrate_to = path
        if not quiet:
            watch.say(f"monitor thresholds: {watch.monitor.threshold_source}")
    if watch.monitor is None and adapt_dir:
        raise UserError("--adapt needs the departure monitor (--monitor on and a model file with a fingerprint)")
    if watch.monitor is not None:
        watch.monitor.on_departure = watch.on_departure
    if adapt_dir or replay:
        watch.adapter = Adapter(None, args.model, adapt_dir or ".", fs_hz=model.fs_hz,
                                events=watch.on_adapt_event, replay=replay, log=watch.say,
                                structure=bool(getattr(args, "adapt_structure", False)))
    return watch
