"""``rtlift demo``: the whole product on the simulated bench, end to end.

1. serve the simulated DAQ on a pseudo-terminal as a protocol-version-2 HIL device and record
   the standard campaign as ``rtlift record`` does: the host commands each program (envelope,
   burst period) over the serial link (COBS + CRC, exact counters), faster than real time;
2. identify the hybrid model (static map, single-burst kernel, HPF, PEM) and tune the
   observer's Q and R from the same records;
3. validate with the paper's protocol (identify on sine_k0125; ρ on sine_k0125, sine_k025,
   random) beside the paper's numbers and the convolution-only / Wiener-only baselines;
4. run the Kalman observer live at 400 Hz on the link for ``live_seconds`` and compare the
   estimate with the measurement and the bench's noise-free truth;
5. record experiments carrying an effect the model was not told about, diagnose them, and
   report the error before and after the augmentation;
6. close the loop: ``rtlift control`` tracks a ΔCL reference (steps, then a slow sine) on the
   bench as a hardware-in-the-loop plant while an undeclared actuator fade to 75 % sets in,
   feedforward only beside feedforward + feedback (the two runs side by side), scored on the
   bench's truth low-passed at 1 Hz (:mod:`rtlift.app.hil_tracking`);
7. write everything to ``out_dir``: records, model files, figures, ``report.md`` and
   ``summary.json``.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from rtlift.app.demo_report import live_report, report_markdown, tracking_figure
from rtlift.core.errors import UserError
from rtlift.core.rate import FS_HZ, PERIOD_S
from rtlift.core.records import Record, write_record

CAMPAIGN = ("static", "single_burst", "train_T1p75", "train_T3p5", "train_T7", "sine_k0125", "sine_k025",
            "random")
PAPER_CORR = {"sine_k0125": 0.9596, "sine_k025": 0.8654, "random": 0.9277}
DEMO_EFFECT = "sensor_resonance:frequency_hz=24,damping_ratio=0.06"
DIAGNOSE_RECORDS = ("sine_k0125", "sine_k025", "random")
TRACKING_S = 16.0
"""Closed-loop section: seconds of tracking, steps for the first half, a slow sine after."""
STEPS = ((0.0, 0.06), (4.0, 0.13))
SINE = {"mean": 0.10, "amp": 0.04, "hz": 0.125, "from_s": 8.0}


@dataclass
class DemoOptions:
    out_dir: str = "rtlift-demo"
    seed: int = 0
    live_seconds: float = 20.0
    speedup: float = 10.0              # campaign recording pace, × real time (device clock stays 400 Hz)
    effect: str = DEMO_EFFECT
    progress: bool = True


class _Progress:
    """One line per stage on stderr (tqdm for the long ones)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def say(self, text: str) -> None:
        if self.enabled:
            print(f"[{time.perf_counter() - self.t0:6.1f} s] {text}", file=sys.stderr, flush=True)

    def bar(self, total: int, desc: str):
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit="sample", unit_scale=True, leave=False, file=sys.stderr,
                    disable=not self.enabled, mininterval=0.5)


def record_through_link(names: tuple[str, ...], seed: int, effects: tuple[str, ...], speedup: float,
                        progress: _Progress) -> tuple[dict[str, Record], dict[str, int]]:
    """Experiments recorded as ``rtlift record`` records them (:class:`rtlift.app.record.Recorder`):
    the bench served as a protocol-version-2 HIL device on a real pty (``rtlift bench serve``'s
    device), the host commanding each program over the serial link, at up to ``speedup`` × real
    time (the device's clock stays 400 Hz), the device's clock held to the host's
    (:class:`Lockstep`): the same seed gives the same records, bit for bit, however busy the host.

    The records' ``dcl`` is what the host computed from the transducer counts on the wire; the
    bench's noise-free truth is added as ``extra["dcl_true"]`` (matched by device sample index).
    """
    from firmware_io.calibration import Calibration
    from firmware_io.links import open_link
    from hil_sim.devices import SerialDaq
    from hil_sim.hil import HilStream
    from rtlift.app.record import OFF_PERIOD_MS, Recorder
    from rtlift.core.programs import standard_program

    cal = Calibration()
    stream = HilStream("random", seed=seed, effects=effects)
    records: dict[str, Record] = {}
    clock = Lockstep()
    with SerialDaq(clock.samples(stream), fs_hz=FS_HZ * speedup, period_us=int(round(1e6 * PERIOD_S)),
                   seed=seed) as device:
        clock.device = device
        stream.control = device.control
        try:
            with open_link({"kind": "serial", "port": device.path, "calibration": cal}) as link:
                device.start()
                rec = Recorder(clock.link(link), cal, meta={"link": "serial (simulated bench on a pty)",
                                                            "seed": str(seed), "effects": ";".join(effects) or "none"},
                               progress=lambda total, name: progress.bar(total, f"recording {name}"))
                rec.check_protocol(OFF_PERIOD_MS)
                results = [rec.run(standard_program(name, cal.volts_from_cmu, seed), None) for name in names]
                counters = dict(link.counters.as_dict())
        finally:
            clock.close()
    idx, truth = stream.truth_array()
    lookup = np.full(int(idx.max()) + 1, np.nan)
    lookup[idx] = truth
    for r in results:
        if not r.complete or r.record is None:
            raise RuntimeError(f"demo: recording {r.name} over the pty did not complete ({r.reason})")
        index = r.first_index + np.rint(r.record.t * FS_HZ).astype(int)
        r.record.extra["dcl_true"] = lookup[index]
        records[r.name] = r.record
    return records, counters


def run_demo(opt: DemoOptions) -> dict[str, Any]:
    from rtlift.diagnose import DiagnoseOptions, diagnose
    from rtlift.diagnose.report import write as write_diagnosis
    from rtlift.identify.campaign import identify_hybrid
    from rtlift.model.modelfile import save_model
    from rtlift.model.validation import plot_validation, validate_record
    from rtlift.observer import tune_observer

    out = opt.out_dir
    for sub in ("records", "figures", "diagnosis"):
        os.makedirs(os.path.join(out, sub), exist_ok=True)
    prog = _Progress(opt.progress)
    summary: dict[str, Any] = {"version": 1, "seed": opt.seed}

    # 1. the standard campaign through the serial link ---------------------------------------
    prog.say(f"1/6 recording the standard campaign host-commanded through a serial pty at {opt.speedup:g}x "
             "real time")
    records, link_totals = record_through_link(CAMPAIGN, opt.seed, (), opt.speedup, prog)
    for name, rec in records.items():
        write_record(os.path.join(out, "records", f"{name}.csv"), rec)
    summary["campaign"] = {"records": list(CAMPAIGN), "seconds": sum(len(r) for r in records.values()) / FS_HZ,
                           "link": link_totals}
    prog.say(f"    {link_totals.get('received', 0)} samples received, {link_totals.get('lost', 0)} lost, "
             f"{link_totals.get('crc_errors', 0)} bad frames")

    # 2. identification + observer tuning --------------------------------------------------
    prog.say("2/6 identifying the hybrid model (static map, kernel, HPF, PEM) and tuning the observer")
    t0 = time.perf_counter()
    idf = identify_hybrid(records["static"], records["single_burst"], records["sine_k0125"])
    identify_s = time.perf_counter() - t0
    observer_cfg = tune_observer(idf.model, [records[n] for n in ("sine_k0125", "random", "train_T1p75")])
    model_path = os.path.join(out, "model.json")
    save_model(idf.model, model_path, provenance=idf.provenance, metrics=idf.metrics,
               observer={**idf.observer, **observer_cfg})
    summary["identify"] = {"seconds": identify_s, "model": model_path,
                           "highpass": {"order": idf.highpass.order, "cutoff_hz": idf.highpass.cutoff_hz},
                           "wiener_order": int(idf.model.wiener.lti.n)}

    # 3. validation: the paper's protocol --------------------------------------------------
    prog.say("3/6 validating: the paper's protocol and baselines")
    validation = _validate(idf, records, out, validate_record, plot_validation)
    summary["validation"] = validation

    # 4. the observer live at 400 Hz ---------------------------------------------------------
    prog.say(f"4/6 running the Kalman observer live at 400 Hz for {opt.live_seconds:g} s")
    summary["live"] = _live(model_path, opt, out, prog)

    # 5. close the loop on a record with an undeclared effect ----------------------------------
    prog.say(f"5/6 recording with an undeclared effect ({opt.effect}) and diagnosing it")
    eff_records, _ = record_through_link(DIAGNOSE_RECORDS, opt.seed + 1, (opt.effect,), opt.speedup, prog)
    for rec in eff_records.values():
        rec.name = f"{rec.name}_effect"
        write_record(os.path.join(out, "records", f"{rec.name}.csv"), rec)
    train = eff_records["sine_k0125"]
    validate = [eff_records["sine_k025"], eff_records["random"]]
    diag = diagnose(idf.model, train, validate, DiagnoseOptions())
    diag_dir = os.path.join(out, "diagnosis")
    write_diagnosis(diag, diag_dir, {"model": model_path, "train": train.name,
                                     "validate": [r.name for r in validate], "injected": opt.effect})
    rep = diag.report
    summary["diagnosis"] = {
        "injected": opt.effect,
        "accepted": [{"name": e["name"], "params": e["params"]} for e in rep["effects"] if e["accepted"]],
        "records": {k: {"rmse_before": v["rmse"], "rmse_after": rep["augmented"]["records"][k]["rmse"]}
                    for k, v in rep["baseline"]["records"].items()},
        "unexplained": rep["unexplained"],
        "report": os.path.join(diag_dir, "report.md"),
    }

    # 6. closed-loop tracking on the bench as a HIL plant -----------------------------------
    prog.say(f"6/6 tracking a ΔCL reference for {TRACKING_S:g} s under an undeclared actuator fade, "
             "feedforward only beside feedforward + feedback")
    summary["closed_loop"] = _closed_loop(model_path, opt, out)

    with open(os.path.join(out, "summary.json"), "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=1, default=float)
        f.write("\n")
    with open(os.path.join(out, "report.md"), "w", encoding="utf-8") as f:
        f.write(report_markdown(summary))
    summary["elapsed_s"] = time.perf_counter() - prog.t0
    return summary


def _validate(idf, records: dict[str, Record], out: str, validate_record, plot_validation) -> dict[str, Any]:
    """The paper's table: hybrid, convolution only, Wiener only; ρ, NRMSE, RMSE per record."""
    from rtlift.core.metrics import scores

    model = idf.model
    table: dict[str, Any] = {}
    for name in ("sine_k0125", "sine_k025", "random", "train_T1p75", "train_T7"):
        rec = records[name]
        res = validate_record(model, rec)
        plot_validation(rec, res, os.path.join(out, "figures", f"validate_{name}.png"))
        model.reset()
        conv = model.convolution.simulate(rec.cmu)
        low, _ = model.wiener.simulate(rec.cmu_envelope)
        model.reset()
        table[name] = {"hybrid": res.scores, "convolution_only": scores(rec.dcl, conv),
                       "wiener_only": scores(rec.dcl, low), "paper_corr": PAPER_CORR.get(name),
                       "measurement_vs_truth": scores(rec.extra["dcl_true"], rec.dcl)}
    return table


class _Tap:
    """The link as a :class:`~rtlift.app.record.Recorder` sees it: ``asking()`` runs each time the
    host asks for a sample, ``got(sample)`` on each sample it gets (before the Recorder sees it)."""

    def __init__(self, link: Any, got=None, asking=None, waiting=None) -> None:
        self._link = link
        self._got = got
        self._asking = asking
        self._waiting = waiting

    def recv(self, timeout: float | None = None):
        if self._asking is not None:
            self._asking()
        s = self._link.recv(timeout)
        while s is None and self._waiting is not None and self._waiting():
            s = self._link.recv(timeout)
        if s is not None and self._got is not None:
            self._got(s)
        return s

    def __getattr__(self, name: str) -> Any:
        return getattr(self._link, name)


PATIENCE_S = 60.0
"""How long the host waits for one sample of a :class:`Lockstep` device before calling it silent (s)."""


class Lockstep:
    """The simulated device's clock held to the host's: sample k leaves the device only once the
    host has handled the k samples before it and asked for the next, so every command it wrote
    meanwhile is read before sample k (and applied there). The records then do not depend on the
    host's speed or load: at 10× real time a host late by a few ms on a busy machine used to
    miss burst onsets (``commands_late`` up to 110 in one record, the first burst 9 or 108 samples
    after its command), so each run of one seed recorded a different plant input, identified a
    different model and could accept different effects (issue 44). The device still paces at
    most at its ``fs_hz``.

    ``link(link)`` wraps the host's link; ``samples(chunks)`` the device's source (one sample per
    chunk); ``device`` is set once the device exists; ``close()`` releases a waiting device."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._got = 0
        self._handled = 0
        self._closed = False
        self._asked_at = 0.0
        self.device: Any = None

    def link(self, link: Any) -> _Tap:
        """The host's side; a sample late by more than the host's timeout on a busy machine is
        waited for while the device runs (up to :data:`PATIENCE_S`): its clock waits for the host
        and never falls silent by itself, so silence is starvation, not a device gone."""
        return _Tap(link, got=self._count, asking=self._asking, waiting=self._running)

    def _running(self) -> bool:
        d = self.device
        if d.error is not None:
            raise RuntimeError(f"demo: the simulated device failed: {d.error!r}")
        if time.perf_counter() - self._asked_at > PATIENCE_S:
            return False
        return not d.finished.is_set() and not self._closed

    def _asking(self) -> None:
        self._asked_at = time.perf_counter()
        with self._cond:
            self._handled = self._got
            self._cond.notify_all()

    def _count(self, sample: Any) -> None:
        self._got += 1

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def _wait(self, k: int) -> bool:
        """Wait until the host has handled ``k`` samples, then read what it wrote; ``False`` once closed."""
        with self._cond:
            while self._handled < k and not self._closed:
                self._cond.wait(0.1)
            if self._closed:
                return False
        self.device._serve_input()      # the emulator's own reader (hil_sim.devices.pty_device), on its thread
        return True

    def samples(self, chunks: Any) -> Any:
        from hil_sim.hil import FIELDS

        it = iter(chunks)
        k = 0
        while self._wait(k):
            chunk = next(it, None)       # after the wait: the bench reads the commands at each onset
            if chunk is None:
                return
            for i in range(len(chunk.t)):
                if i and not self._wait(k):
                    return
                yield SimpleNamespace(**{f: getattr(chunk, f)[i:i + 1] for f in FIELDS})
                k += 1


def program_prefix(program, seconds: float):
    """The first ``seconds`` of ``program`` (:class:`rtlift.core.programs.Program`), ended there
    with the actuator off."""
    from dataclasses import replace

    keep = program.t < seconds
    return replace(program, t=np.append(program.t[keep], seconds),
                   envelope_v=np.append(program.envelope_v[keep], 0.0),
                   burst_period_ms=np.append(program.burst_period_ms[keep], 0))


def _live(model_path: str, opt: DemoOptions, out: str, prog: _Progress) -> dict[str, Any]:
    """The bench on a pty at real-time 400 Hz, host-commanded as in stage 1 (``rtlift record``'s
    settle, tare and the ``random`` program of seed + 2, which the model never saw), the observer
    stepping on every sample the link delivers; estimate vs the bench's truth.

    The plant is driven as during identification: by the host's commands, the envelope taking
    effect at burst onsets (PROTOCOL.md). A version-1 stream (the device's own program, its
    envelope changing at every sample) is an input the identified model was never fitted on; on
    it the observer did worse than the raw measurement (issue 44)."""
    from firmware_io.calibration import Calibration
    from firmware_io.convert import Converter
    from firmware_io.links import open_link
    from firmware_io.samples import STATUS_BURST_ON
    from hil_sim.devices import SerialDaq
    from hil_sim.hil import HilStream
    from rtlift.app.live import ObserverLoop
    from rtlift.app.record import OFF_PERIOD_MS, SETTLE_S, Recorder
    from rtlift.core.programs import standard_program
    from rtlift.model.modelfile import load_model
    from rtlift.observer import Observer

    model = load_model(model_path)
    n = int(round(opt.live_seconds * FS_HZ))
    cal = Calibration()
    cols = np.full((n, 3), np.nan)          # measured ΔCL, observer ΔĈL, open-loop model
    seqs = np.zeros(n, dtype=np.int64)
    observer = Observer.from_model(model)
    observer.warm_up()                      # compile before the link opens, not on its first sample
    converter = Converter(cal, model.fs_hz)
    measured: list[float | None] = [None]
    applied = [0.0, 0]                      # the envelope driving the plant (Cμ), the last status

    def convert(sample):
        """Cμ, the envelope as applied, ΔCL. A version-2 device reports the envelope it was
        commanded, which drives the plant only from the next burst onset on (PROTOCOL.md): held
        from each onset (burst-on rising edge) to the next, as the records of stage 1 hold it
        (:meth:`rtlift.app.record._Run.applied_cv`)."""
        cmu, env, dcl = converter(sample)
        if sample.status & STATUS_BURST_ON and not applied[1] & STATUS_BURST_ON:
            applied[0] = env
        applied[1] = sample.status
        measured[0] = dcl                   # kept for the comparison
        return cmu, applied[0], dcl

    # the program ends ½ s after the observer's last sample (the protocol check and the first
    # burst's alignment come before it)
    program = program_prefix(standard_program("random", cal.volts_from_cmu, opt.seed + 2),
                             opt.live_seconds - SETTLE_S - cal.tare_seconds + 0.5)
    stream = HilStream("random", seed=opt.seed + 2)
    with SerialDaq(stream, period_us=int(round(1e6 * PERIOD_S)), seed=opt.seed + 2) as device:
        stream.control = device.control
        with open_link({"kind": "serial", "port": device.path, "calibration": cal,
                        "log": os.path.join(out, "live_frames.bin")}) as link:
            loop = ObserverLoop(observer, convert, link.seq_modulus, max_samples=n, time_steps=True)
            est = observer.estimate
            with prog.bar(n, "observer live") as bar:
                def feed(s) -> None:
                    if loop.done:
                        return
                    loop.feed(s)
                    i = est.sample - 1
                    if 0 <= i < n:
                        cols[i] = (np.nan if measured[0] is None else measured[0], est.dcl, est.model_dcl)
                        seqs[i] = s.seq
                    bar.update(1)

                device.start()
                rec = Recorder(_Tap(link, got=feed), cal, meta={"link": "serial (simulated bench on a pty)"})
                rec.check_protocol(OFF_PERIOD_MS)
                result = rec.run(program, None)
            counters = link.counters.as_dict()
    if not result.complete or not loop.done:
        raise UserError(f"demo: the live run over the pty did not complete ({result.reason or 'too short'}); "
                        "on a loaded machine a pseudo-terminal can stall: run it again")
    p50, p99 = loop.stats.latency_ms()
    step_us = np.frombuffer(loop.stats.step_times, dtype=float) * 1e6
    idx, truth = stream.truth_array()
    lookup = np.full(int(idx.max()) + 1, np.nan)
    lookup[idx] = truth
    settled = int(round((SETTLE_S + cal.tare_seconds + 1.0) * FS_HZ))   # off, then 1 s of the program
    return live_report(cols, lookup[seqs], counters, p50, p99, step_us, out, settled)


def tracking_reference(path: str) -> str:
    """Write the closed-loop reference as a ``t, dcl_ref`` CSV (``rtlift control --reference``):
    :data:`STEPS` (held), then the :data:`SINE` from ``from_s`` to :data:`TRACKING_S`; its path."""
    rows = []
    for (t0, v), (t1, _) in zip(STEPS, (*STEPS[1:], (SINE["from_s"], None)), strict=True):
        rows += [(t0, v), (t1 - 1e-3, v)]
    for t in np.arange(SINE["from_s"], TRACKING_S + 0.05, 0.05):
        rows.append((t, SINE["mean"] + SINE["amp"] * np.sin(2 * np.pi * SINE["hz"] * (t - SINE["from_s"]))))
    with open(path, "w", encoding="utf-8") as f:
        f.write("t,dcl_ref\n" + "".join(f"{t:.4f},{v:.6f}\n" for t, v in rows))
    return path


def _closed_loop(model_path: str, opt: DemoOptions, out: str) -> dict[str, Any]:
    """Feedforward only and feedforward + feedback side by side on two benches with the same fade.

    The feedback is designed here first (:func:`rtlift.app.control_design.cached_design`; ``rtlift
    control`` then finds it cached beside the model): a target the design misses is run anyway
    (``--accept-design-warnings``: the demo shows what the design gives) and said in the report."""
    from rtlift.app.control_design import cached_design
    from rtlift.app.hil_tracking import FADE, BenchTracking, reference_values
    from rtlift.model.modelfile import load_model

    t0 = time.perf_counter()
    design, _ = cached_design(load_model(model_path), model_path, accept_warnings=True)
    warnings = [str(v) for v in design.violations()]
    spec = tracking_reference(os.path.join(out, "tracking_reference.csv"))
    runs = {fb: BenchTracking(model_path, spec, fb == "on", TRACKING_S,
                              os.path.join(out, f"control_feedback_{fb}.json"), seed=opt.seed + 3,
                              extra=("--accept-design-warnings",) if warnings else ())
            for fb in ("off", "on")}
    for run in runs.values():
        run.start()
    rows = {fb: run.finish() for fb, run in runs.items()}
    traces = {fb: run.traces() for fb, run in runs.items()}
    seconds = time.perf_counter() - t0
    t = traces["on"][0]
    ref = reference_values(spec, len(t))
    tracking_figure(t, ref, traces, rows, os.path.join(out, "figures", "closed_loop.png"))
    return {"seconds": TRACKING_S, "elapsed_s": seconds, "effect": FADE, "reference": os.path.basename(spec),
            "feedforward": rows["off"], "feedback": rows["on"],
            "ratio": rows["on"]["rmse_truth"] / rows["off"]["rmse_truth"], "figure": "figures/closed_loop.png",
            "design_warnings": warnings, "design_cautions": design.cautions()}
