"""``--monitor`` and ``--adapt`` of ``rtlift observe`` and ``rtlift control`` (and their replay).

:func:`attach` puts a :class:`~rtlift.observer.monitor.DepartureMonitor` on an
:class:`~rtlift.app.live.ObserverLoop` (on by default; off with ``--monitor off``, or when the
model file has no fingerprint, which is said in one line) and, with ``--adapt DIR``, an
:class:`~rtlift.app.adapt.Adapter`. Departures and adaptations are

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
import os
import sys
import threading
from typing import Any

from rtlift.core.errors import UserError


def add_arguments(p: argparse.ArgumentParser, adapt: bool = True) -> None:
    p.add_argument("--monitor", choices=("on", "off"), default="on",
                   help="on: compare the loop's residual with the model's identification fingerprint in "
                        "sliding windows and report departures (the default); off: no monitor")
    if not adapt:
        return
    p.add_argument("--adapt", metavar="DIR",
                   help="on a departure, diagnose the recorded window in another process and swap in the "
                        "augmented model at a burst onset; windows, reports and model files go to DIR")


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

    def counts(self) -> dict[str, int]:
        """Departures and swaps so far (for the live page)."""
        return {"departures": len(self.monitor.departures) if self.monitor else 0,
                "adaptations": sum(1 for a in self.adapter.adaptations if a.get("swapped")) if self.adapter else 0}

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"departures": list(self.monitor.departures) if self.monitor else []}
        if self.monitor is not None:
            out["monitor"] = self.monitor.summary()
        if self.adapter is not None:
            out["adaptations"] = list(self.adapter.adaptations)
        return out

    def close(self, wait_s: float = 0.0) -> None:
        if self.adapter is not None:
            self.adapter.close(wait_s)
        with self._lock:
            if self._f is not None:
                self._f.close()
                self._f = None


def attach(loop: Any, args: argparse.Namespace, model: Any, prog: str, *, closed: Any = None,
           replay: list[dict] | None = None, quiet: bool = False) -> Watch:
    """Monitor (and adapter) on ``loop`` as ``args.monitor`` / ``args.adapt`` say (``quiet``: no
    stderr lines — a replay sums them up in one)."""
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
    if getattr(args, "monitor", "on") == "on":
        try:
            watch.monitor = DepartureMonitor.for_model(model)
        except ValueError as exc:
            watch.say(f"monitor off: {exc}")
    if watch.monitor is None and adapt_dir:
        raise UserError("--adapt needs the departure monitor (--monitor on and a model file with a fingerprint)")
    if watch.monitor is not None:
        watch.monitor.on_departure = watch.on_departure
        loop.monitor = watch.monitor
    if adapt_dir or replay:
        watch.adapter = Adapter(loop, args.model, adapt_dir or ".", closed=closed, fs_hz=model.fs_hz,
                                events=watch.on_adapt_event, replay=replay, log=watch.say)
        loop.adapter = watch.adapter
    return watch
