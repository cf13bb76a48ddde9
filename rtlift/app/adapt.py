"""``--adapt``: re-closing the loop while it runs.

When the departure monitor (:mod:`rtlift.observer.monitor`) raises a departure, the loop keeps
running at 400 Hz and an :class:`Adapter` does, in order:

1. keeps the loop's own rows (Cμ, Cμ_env, ΔCL as measured; the observer loop's sample index)
   in a preallocated ring — three array stores a sample;
2. ``after_s`` seconds after the departure, copies the window
   ``[departure − before_s, departure + after_s)`` out of the ring and hands it to a background
   thread, which writes it as a record file and runs ``rtlift diagnose --model M --run WINDOW
   --split 0.6`` in **another process** (niced): the diagnosis of users' records, fitted on the
   window's first 60 %, judged on the rest. That process is started with the loop and has done
   its imports by the first departure (:class:`~rtlift.app.diagnose_worker.DiagnoseWorker`: on
   a machine at a load average of 16 the imports alone of a fresh ``rtlift diagnose`` took
   25 s, and a 120 s run could end before its swap);
3. when that diagnosis accepts an effect, the thread loads the augmented model, builds its
   observer (and compiles it) and catches it up over the ring's rows from the window's start
   to as far as the loop has got; the loop then, at the next burst onset (Cμ rising from 0),
   steps the new observer through the few rows left, and swaps it in — and the controller,
   rebuilt on the new model's static map with the old one's integrator and phase
   (:meth:`rtlift.app.control.LiftController.carry_from`).

The state carried over is thus the new model's own state after the same rows from the
window's start: what the diagnosis fitted it on. Every swap is written to the events file
(``{"event": "adaptation", "index", "window_start", "model_file", ...}``), so ``rtlift
replay`` of the log makes the same swap at the same sample with the same rows and reproduces
every estimate and command bit for bit. Each adaptation's model file is kept in the adapt
directory with its provenance (the loop, the departure, the window, the diagnosis report).

What the diagnosis calls ``structure`` (the model lacked it at identification: its evidence does
not depart from the fingerprint) is not a change of the plant: unless the user asked
(``--adapt-structure``), a window whose accepted entries include one is not swapped in; it is a
finding, reported in one line, in the events file and in the summary (``finding``, ``reason``).
One exception: the departure's own suspect. The monitor raised it against the model's own null
in time (quiet before, departed now), which is the evidence of a change the window's diagnosis
cannot give on its own: a live window is a record type the fingerprint never saw (it is compared
with the static sweep's residual), so a fade that set in mid-run can read "within the
fingerprint" there. What the monitor suspected and the diagnosis accepted is swapped in.

An effect swapped in is fitted on one window; if the plant goes on changing after it (a fade still
fading), the monitor raises it again, suspecting the same effect. That window is diagnosed from the
model before that swap (:meth:`Adapter.diagnosed_from`), so the effect is fitted anew on it instead of
another being stacked on top to patch its residual; a fade's clock there starts where the running
fade's is at the window's start (:func:`fade_clock_at`, the window record's metadata), so a fade
nearly complete is not fitted as an immediate loss. The event says ``refit``.

One diagnosis at a time; departures while one runs are logged, not acted on. The window must
still be in the ring when the swap comes (``ring_s``): a diagnosis that takes longer is
dropped (``reason``).
"""

from __future__ import annotations

import json
import os
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np

from rtlift.app.diagnose_worker import DiagnoseWorker
from rtlift.blocks.actuator_fade import ActuatorFade
from rtlift.core.rate import FS_HZ
from rtlift.core.split import SPLIT_DEFAULT
from rtlift.effects import EFFECT_NAMES

FADE = ActuatorFade.name
BEFORE_S = 2.0
AFTER_S = 24.0
"""The window diagnosed: 2 s before the departure, 24 s after it: 26 s, so its first 60 % (15.6 s)
is ≥ diagnose's 12 s least training length and the rest (10.4 s) ≥ its 10 s least validation
length. It starts about where what changed set in *or after*, not before: the monitor's ``hold``
test raises a fade 3–4 s after its onset; an effect whose model starts at the window's first sample
(a fade's on-time clock, a drift's ramp) fits a window that starts after the onset (a fade already
under way is the same curve with a smaller initial loss) but not one whose first seconds precede it
(with the window 8 s before the departure, the bench's fade was fitted as a ``zero_drift``)."""
SPLIT = SPLIT_DEFAULT
"""The window's share the diagnosis fits on (:data:`rtlift.core.split.SPLIT_DEFAULT`, as ``rtlift diagnose --run``)."""
END_WAIT_S = 120.0
"""How long the run's end waits for a diagnosis in flight (:meth:`Adapter.close`) so that its event
says what it found: at a load average of 16 a window's diagnosis took 95 s of wall time."""
RING_S = 240.0
"""Rows kept: the window plus up to ~3 minutes of diagnosis."""
SWITCH_INTERVAL_S = 5e-5
"""The interpreter's thread switch interval while the background thread works (Python's default
is 5 ms). That thread writes the window, loads the new model, builds and compiles its observer and
catches it up over tens of thousands of rows — in the loop's process, holding the GIL; the loop's
thread, wanting it back for its next sample, would wait up to the switch interval, inside a
400 Hz step. At 50 µs the loop waits at most that long (the diagnosis itself runs in another
process and does not hold this one's GIL)."""


class Ring:
    """The loop's last rows (Cμ, Cμ_env, ΔCL; NaN for no measurement) by loop sample index."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.data = np.zeros((capacity, 3))
        self.next = 0   # loop sample index of the next row

    def put(self, index: int, cmu: float, env: float, dcl: float | None) -> None:
        row = self.data[index % self.capacity]
        row[0] = cmu
        row[1] = env
        row[2] = np.nan if dcl is None else dcl
        self.next = index + 1

    def holds(self, start: int) -> bool:
        return start >= 0 and self.next - start <= self.capacity

    def rows(self, start: int, stop: int) -> np.ndarray:
        """A copy of rows ``start ≤ index < stop`` (which must still be held)."""
        idx = np.arange(start, stop) % self.capacity
        return self.data[idx].copy()


def window_record(rows: np.ndarray, fs_hz: float, meta: dict[str, str]):
    """The window as a record: ΔCL missing on a row (a gap the loop predicted through) is
    interpolated between its neighbours, and counted in the metadata."""
    from rtlift.core.records import Record

    dcl = rows[:, 2].copy()
    bad = ~np.isfinite(dcl)
    if bad.all():
        raise ValueError("no measured ΔCL in the window")
    if bad.any():
        k = np.arange(len(dcl))
        dcl[bad] = np.interp(k[bad], k[~bad], dcl[~bad])
    t = np.arange(len(rows)) / fs_hz
    return Record(t, rows[:, 0].copy(), rows[:, 1].copy(), dcl, {**meta, "filled": str(int(bad.sum()))}, {},
                  meta.get("experiment", "window"))


def fade_clock_at(observer: Any, rows: np.ndarray, fs_hz: float) -> dict[str, str]:
    """The window record's metadata giving the running model's fade clock at the window's first row
    (:data:`rtlift.effects.actuator_fade.ON_TIME0_META`): its clock now (after the window's last row)
    less what the window's rows added to it (on-time: the rows with Cμ > 0; wall time: all). Empty if
    the running model has no fade."""
    from rtlift.effects.actuator_fade import ON_TIME0_META

    fade = next((s for s in getattr(observer.model, "input_stages", ()) if isinstance(s, ActuatorFade)), None)
    if fade is None:
        return {}
    added = len(rows) if fade.clock == "time" else int(np.count_nonzero(rows[:, 0] > 0.0))
    return {ON_TIME0_META[fade.clock]: repr(max(0.0, fade.on_time - added / fs_hz))}


class Adapter:
    """The ``--adapt`` machinery of one loop (module docstring).

    ``loop`` is the :class:`~rtlift.app.live.ObserverLoop`; ``closed`` the
    :class:`~rtlift.app.closed_loop.ControlLoop` (``None`` for ``observe``); ``model_path`` the
    running model's file; ``out_dir`` where windows, reports and model files go; ``events`` a
    callable taking each event dict (the events file, the summary). ``replay`` is a list of
    recorded adaptation events to repeat instead of diagnosing (``rtlift replay``).
    """

    def __init__(self, loop: Any, model_path: str, out_dir: str | os.PathLike, *, closed: Any = None,
                 fs_hz: float = FS_HZ, events: Any = None, before_s: float = BEFORE_S,
                 after_s: float = AFTER_S, replay: list[dict] | None = None, log: Any = None,
                 structure: bool = False) -> None:
        self.loop = loop
        self.closed = closed
        self.model_path = str(model_path)
        self._before_last: tuple[str, frozenset[str]] | None = None
        """(the model the last swap's window was diagnosed from, what that swap accepted)."""
        self.out_dir = Path(out_dir).resolve()
        self.fs_hz = fs_hz
        self.before = int(round(before_s * fs_hz))
        self.after = int(round(after_s * fs_hz))
        self.ring = Ring(int(RING_S * fs_hz))
        self.events = events or (lambda e: None)
        self.log = log or (lambda line: None)
        self.adaptations: list[dict[str, Any]] = []
        self.structure = structure
        """Swap in what the diagnosis calls ``structure`` too (``--adapt-structure``); by default a
        window whose accepted entries include one is a finding, reported, not swapped."""
        self.replaying = replay is not None
        self._replay = sorted(replay or [], key=lambda e: e["index"])
        self._pending_departure: int | None = None   # loop index at which to cut the window
        self._busy = False
        self._ready: dict[str, Any] | None = None    # set by the thread: a prepared swap
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._last_cmu = 0.0
        self.count = 0
        self._worker = None if self.replaying else DiagnoseWorker(_nice)
        """``rtlift diagnose`` kept warm in another process (niced) from the loop's start."""

    @property
    def busy(self) -> bool:
        """A window is being diagnosed (or its swap prepared or awaited)."""
        return self._busy

    # -- from the monitor -------------------------------------------------------------
    def on_departure(self, departure: dict[str, Any]) -> None:
        """A departure (its ``sample`` is the monitor's count, the loop index + 1)."""
        if self.replaying or self._busy or self._pending_departure is not None:
            return
        self._pending_departure = int(departure["sample"]) - 1 + self.after
        self._departure = departure

    # -- every sample, before the observer steps -----------------------------------------
    def before_step(self, index: int, cmu: float) -> None:
        """At loop index ``index`` with this sample's Cμ: swap now if one is ready and a burst
        starts (Cμ rising from 0)."""
        onset = cmu > 0.0 >= self._last_cmu
        self._last_cmu = cmu
        if self.replaying:
            if self._replay and self._replay[0]["index"] == index:
                self._swap(self._prepare(self._replay.pop(0), index), index)
            return
        if self._ready is not None and onset:
            with self._lock:
                ready, self._ready = self._ready, None
            self._swap(ready, index)

    # -- every sample, after the observer stepped -----------------------------------------
    def after_step(self, index: int, cmu: float, env: float, dcl: float | None) -> None:
        self.ring.put(index, cmu, env, dcl)
        if self._pending_departure is not None and index + 1 >= self._pending_departure:
            self._cut(index + 1)

    def _cut(self, stop: int) -> None:
        start = max(0, stop - self.before - self.after)
        self._pending_departure = None
        if not self.ring.holds(start):
            return
        rows = self.ring.rows(start, stop)
        self._busy = True
        self.count += 1
        job = {"n": self.count, "start": start, "stop": stop, "rows": rows, "departure": self._departure}
        suspect = (self._departure or {}).get("suspect")
        if suspect == FADE and self.diagnosed_from(suspect) != self.model_path:   # a refit: the running
            job["clock"] = fade_clock_at(self.loop.observer, rows, self.fs_hz)     # fade's clock, read here
        self._thread = threading.Thread(target=self._diagnose, args=(job,), name="rtlift-adapt", daemon=True)
        self._thread.start()

    # -- the background thread ---------------------------------------------------------
    def _diagnose(self, job: dict[str, Any]) -> None:
        previous = sys.getswitchinterval()
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        try:
            self._diagnose_window(job)
        finally:
            sys.setswitchinterval(previous)

    def _diagnose_window(self, job: dict[str, Any]) -> None:
        from rtlift.core.records import write_record

        n = job["n"]
        suspect = (job["departure"] or {}).get("suspect")
        job["model"] = self.diagnosed_from(suspect)   # no swap comes between the cut and here (busy)
        work = self.out_dir / f"adapt_{n}"
        event: dict[str, Any] = {"event": "diagnosis", "n": n, "window_start": job["start"],
                                 "window_stop": job["stop"], "departure": job["departure"]}
        try:
            work.mkdir(parents=True, exist_ok=True)
            rec = window_record(job["rows"], self.fs_hz,
                                {"experiment": f"adapt_{n}", "source": "rtlift --adapt window",
                                 "model": job["model"], **job.get("clock", {}),
                                 "window_samples": f"{job['start']}..{job['stop'] - 1}"})
            path = work / "window.csv"
            write_record(path, rec)
            if job["model"] != self.model_path:
                event["refit"] = suspect
            code, stderr = self._worker.run(["diagnose", "--model", job["model"], "--run", str(path),
                                             "--split", str(SPLIT), "--out", str(work / "diagnosis"),
                                             *(["--suspect", suspect] if suspect in EFFECT_NAMES else [])])
            if code != 0:
                raise RuntimeError((stderr.strip().splitlines() or ["diagnose failed"])[-1])
            rep = json.loads((work / "diagnosis" / "report.json").read_text())
            acc = [e for e in rep["effects"] if e["accepted"]]
            base = next(iter(rep["baseline"]["records"].values()))
            aug = next(iter(rep["augmented"]["records"].values()))
            event.update(accepted=[e["name"] for e in acc], rmse_before=base["rmse"], rmse_after=aug["rmse"],
                         kinds={e["name"]: e.get("kind", "effect") for e in acc})
            if not acc:
                event["reason"] = "nothing accepted"
                self._finish(event)
                return
            structure = [e["name"] for e in acc if e.get("kind") == "structure" and e["name"] != suspect]
            if structure and not self.structure:
                event["finding"] = structure
                event["reason"] = (f"structure: {', '.join(structure)} (a deficiency the model had since "
                                   "identification, not a change of the plant): reported, not swapped "
                                   "(--adapt-structure swaps it in)")
                self._finish(event)
                return
            model_file = self._keep_model(work, n, job, event)
            event["model_file"] = str(model_file)
            prepared = self._prepare({"index": None, "window_start": job["start"], "model_file": str(model_file),
                                      "diagnosed_from": job["model"]}, None)
            prepared["event"] = event
            with self._lock:
                self._ready = prepared
        except Exception as exc:  # noqa: BLE001 - the loop runs on; the event says why
            event["reason"] = f"{type(exc).__name__}: {exc}"
            self._finish(event)

    def diagnosed_from(self, suspect: str | None) -> str:
        """The model a window is diagnosed from: the running one, unless the departure suspects an
        effect the last swap put in (module docstring): then the one that swap's window was diagnosed
        from, so the effect is fitted anew."""
        if suspect and self._before_last is not None and suspect in self._before_last[1]:
            return self._before_last[0]
        return self.model_path

    def _keep_model(self, work: Path, n: int, job: dict[str, Any], event: dict[str, Any]) -> Path:
        from rtlift.core.jsonfile import write_json_atomic

        doc = json.loads((work / "diagnosis" / "model_augmented.json").read_text())
        prov = dict(doc.get("provenance") or {})
        prov["adaptation"] = {"n": n, "running_model": self.model_path, "diagnosed_from": job["model"],
                              "window_samples": [job["start"], job["stop"]],
                              "departure": job["departure"], "accepted": event["accepted"],
                              "report": str(work / "diagnosis" / "report.json"), "tool": "rtlift --adapt"}
        doc["provenance"] = prov
        path = self.out_dir / f"model_adapt_{n}.json"
        write_json_atomic(path, doc, stage="adapted model")
        return path

    def _prepare(self, spec: dict[str, Any], upto: int | None) -> dict[str, Any]:
        """The new model's observer, caught up over the ring from the window's start to ``upto``
        (or as far as the loop has got)."""
        from rtlift.model.modelfile import load_model
        from rtlift.observer import Observer

        model = load_model(spec["model_file"])
        obs = Observer.from_model(model)
        obs.warm_up()
        obs.reset()
        start = int(spec["window_start"])
        stop = self.ring.next if upto is None else upto
        _catch_up(obs, self.ring.rows(start, stop))
        return {"model": model, "observer": obs, "at": stop, "spec": spec}

    def _finish(self, event: dict[str, Any]) -> None:
        self.adaptations.append(event)
        self.events(event)
        self._busy = False

    # -- the swap, in the loop --------------------------------------------------------
    def _swap(self, ready: dict[str, Any], index: int) -> None:
        obs = ready["observer"]
        if not self.ring.holds(ready["at"]):
            ev = dict(ready.get("event") or {}, reason="window no longer held at the swap")
            self._finish(ev)
            return
        _catch_up(obs, self.ring.rows(ready["at"], index))
        self.loop.observer = obs
        if self.loop.monitor is not None:
            self.loop.monitor.clear_windows()
        if self.closed is not None:
            from rtlift.app.control import LiftController

            ctl = LiftController(ready["model"], self.closed.controller.config)
            ctl.carry_from(self.closed.controller)
            self.closed.controller = ctl
        spec = ready["spec"]
        ev = dict(ready.get("event") or {"event": "diagnosis"})
        ev.update(event="adaptation", index=index, t_s=index / self.fs_hz, window_start=int(spec["window_start"]),
                  model_file=spec["model_file"], swapped=True)
        ev.setdefault("accepted", spec.get("accepted"))
        self._before_last = (spec.get("diagnosed_from", self.model_path), frozenset(ev.get("accepted") or ()))
        self.model_path = spec["model_file"]    # the next diagnosis starts from the running model
        self.log(f"adaptation at t={index / self.fs_hz:.2f} s: {', '.join(ev.get('accepted') or [])} "
                 f"(model {spec['model_file']})")
        self.adaptations.append(ev)
        self.events(ev)
        self._busy = False

    def close(self, timeout: float | None = None) -> None:
        """The run ended: wait for a diagnosis in flight (up to ``timeout`` s; ``None``:
        :data:`END_WAIT_S`), then end the worker. Every diagnosis started is one event: one the
        wait cut off says so (``reason``: the run ended before the window's diagnosis did); one
        that finished (its swap prepared) after the loop's last burst onset says what it accepted
        and that the run ended before the swap — so a run that ends first, on a loaded machine,
        still tells what its diagnosis found."""
        wait = END_WAIT_S if timeout is None else timeout
        if self._thread is not None and self._thread.is_alive() and wait > 0:
            self.log(f"the run ended with window {self.count}'s diagnosis in flight: waiting up to {wait:g} s for it")
            self._thread.join(wait)
        if self._worker is not None:
            self._worker.close()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(1.0)                  # its request answered "closed": its event is written
        with self._lock:
            ready, self._ready = self._ready, None
        if ready is not None and not self.replaying:
            event = dict(ready.get("event") or {"event": "diagnosis"})
            event["reason"] = ("the run ended before the swap (the window's diagnosis finished after the "
                               "loop's last burst)")
            self._finish(event)


def _catch_up(obs: Any, rows: np.ndarray) -> None:
    step = obs.step
    for cmu, env, dcl in rows.tolist():
        step(cmu, env, None if dcl != dcl else dcl)


def _nice() -> None:
    try:
        os.nice(10)
    except OSError:
        pass


def read_adaptations(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The adaptation events of an events file (``rtlift replay`` repeats them)."""
    out = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            line = line.strip()
            if line:
                e = json.loads(line)
                if e.get("event") == "adaptation":
                    out.append(e)
    return out
