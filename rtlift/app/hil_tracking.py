"""``rtlift control`` against the simulated bench as a hardware-in-the-loop plant, scored on
the bench's truth (shared by ``rtlift demo`` and ``benchmarks/control_loop.py``).

:class:`BenchTracking` serves a :class:`hil_sim.hil.HilStream` on a pseudo-terminal (serial,
or slcan), runs ``rtlift control`` on it in its own process, and scores the plant's noise-free
ΔCL (which the host never sees) against the reference, both low-passed at 1 Hz (zero phase):

    RMSE = sqrt(mean((LP ΔCL_true − LP r)²))   over the tracking time.

Step response, on the same truth averaged over one burst period (the burst ripple's period,
trailing, so causal): after each step of a piecewise-constant reference, the settling time is
the time until that average stays within ``SETTLE_TOL`` of the new level up to the next step
(``None`` if it never does: a level beyond the actuator's reach). After an unreachable level,
the next step's settling time is the recovery time (windup shows there).

Tracking starts after the host's settle and tare (``rtlift.app.closed_loop``): 3 s on the default
calibration, counted in device samples (none lost, the host received from sample 0). Several
runs can go side by side: :meth:`BenchTracking.start` them all, then :meth:`~BenchTracking.finish`.

:class:`InProcessTracking` is the same closed loop without the pseudo-terminal and the clock: the
device's order (the bench streams sample k, the firmware's command side steps it, the sample is
encoded as the serial wire carries it) and the host's (the serial decoder, the converter, the
observer, :class:`~rtlift.app.closed_loop.ControlLoop`, the controller) in one thread, a command
sent after sample k arriving before sample k + 1 (a command latency under one period, as measured
live: p99 ≈ 1 ms). It runs as fast as the CPU allows (≈ 25 s of plant per second), for
benchmarks and tests that need minutes of plant time.

With ``log``, ``rtlift control`` also writes its log, and :meth:`~BenchTracking.record` turns it
into a record file through ``rtlift replay LOG --record`` (issue 27's closed-loop record: the
end-to-end test and ``benchmarks/null_rate.py``'s ``closed_loop`` training type).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import Any

import numpy as np
from scipy import signal

from rtlift.app.closed_loop import LOWPASS_HZ, SETTLE_S
from rtlift.core.rate import FS_HZ

TRACKING_STARTS = int(round((SETTLE_S + 2.0) * FS_HZ))
"""Device sample where tracking starts: settle (1 s) and the default tare (2 s)."""
FADE = "actuator_fade:final_fraction=0.75,time_constant_s=0.4"
"""The undeclared drift: the actuator's authority fades to 75 % during the run."""


def reference_values(spec: str, n: int, fs_hz: float = FS_HZ) -> np.ndarray:
    """r(k / fs) for k < n, the reference ``rtlift control`` tracks (spec as ``--reference``)."""
    from rtlift.app.reference import parse_reference

    ref = parse_reference(spec)
    return np.array([ref.at(k / fs_hz) for k in range(n)])


def lowpass(x: np.ndarray, fs_hz: float = FS_HZ) -> np.ndarray:
    """``x`` low-passed at 1 Hz, zero phase (2nd-order Butterworth, forward and back)."""
    return signal.sosfiltfilt(signal.butter(2, LOWPASS_HZ, fs=fs_hz, output="sos"), x)


SETTLE_TOL = 0.01
RIPPLE_SAMPLES = 50
"""One burst period at the lift-optimal 8 Hz (``rtlift.app.control.BURST_PERIOD_SAMPLES``)."""


def settling_times(truth: np.ndarray, reference: np.ndarray, fs_hz: float = FS_HZ, tol: float = SETTLE_TOL,
                   window: int = RIPPLE_SAMPLES) -> list[float | None]:
    """Seconds after each step of ``reference`` until ``truth``'s trailing ``window`` mean stays
    within ``tol`` of the new level up to the next step; ``None`` if it never does (module docstring)."""
    truth = np.asarray(truth, dtype=float)
    c = np.concatenate([[0.0], np.cumsum(truth)])
    k = np.arange(truth.size)
    lo = np.maximum(0, k + 1 - window)
    mean = (c[k + 1] - c[lo]) / (k + 1 - lo)
    edges = np.flatnonzero(np.abs(np.diff(reference)) > 1e-12) + 1
    out: list[float | None] = []
    if edges.size == 0:  # a constant reference: no step to settle after
        return out
    for a, b in zip(edges, [*edges[1:], truth.size], strict=True):
        bad = np.flatnonzero(np.abs(mean[a:b] - reference[a]) > tol)
        if bad.size == 0:
            out.append(0.0)
        elif bad[-1] == b - a - 1:
            out.append(None)
        else:
            out.append(float((bad[-1] + 1) / fs_hz))
    return out


def truth_rmse(truth: np.ndarray, reference: np.ndarray, fs_hz: float = FS_HZ) -> float:
    """RMSE of the bench truth against the reference, both low-passed at 1 Hz (zero phase)."""
    return float(np.sqrt(np.mean((lowpass(truth, fs_hz) - lowpass(reference, fs_hz)) ** 2)))


class BenchTracking:
    """One closed-loop run: the bench (in this process) and ``rtlift control`` (a subprocess);
    ``gust`` a lift disturbance on the bench's truth (``F:A,...``, :mod:`hil_sim.gust`)."""

    def __init__(self, model: str, reference: str, feedback: bool, seconds: float, out_json: str, *,
                 seed: int = 11, effects: tuple[str, ...] = (FADE,), can: bool = False,
                 experiment: str = "random", gust: str | None = None, log: str | None = None,
                 extra: tuple[str, ...] = ()) -> None:
        from hil_sim.devices import SerialDaq, SlcanAdapter
        from hil_sim.gust import parse_gust
        from hil_sim.hil import HilStream

        self.reference = reference
        self.feedback = feedback
        self.seconds = seconds
        self.out_json = out_json
        self.model = model
        self.log = log
        self.stream = HilStream(experiment, seed=seed, effects=list(effects), gust=parse_gust(gust))
        self.device = (SlcanAdapter if can else SerialDaq)(self.stream)
        self.stream.control = self.device.control
        link = ["--can", f"slcan:{self.device.path}"] if can else ["--serial", self.device.path]
        self.cmd = [sys.executable, "-m", "rtlift", "control", *link, "--model", model, "--reference",
                    reference, "--seconds", str(seconds), "--feedback", "on" if feedback else "off",
                    "--json", out_json, *(["--log", log] if log else []), *extra]
        self.summary: dict[str, Any] = {}
        self.stderr = ""
        self.proc: subprocess.Popen | None = None

    def start(self) -> BenchTracking:
        """Start ``rtlift control``; start the device once its link is open."""
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        path = os.pathsep.join(filter(None, (root, os.environ.get("PYTHONPATH"))))
        self.proc = subprocess.Popen(self.cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "PYTHONPATH": path})
        line = self.proc.stderr.readline()
        if "link open" not in line:
            self.device.stop()
            raise RuntimeError(f"rtlift control did not start: {line.strip()}")
        self.device.start()
        return self

    def finish(self) -> dict[str, Any]:
        """Wait for ``rtlift control`` (a bench behind real time on a loaded machine is waited
        for up to three times the run); its summary's counters beside the bench truth's RMSE."""
        try:
            _, err = self.proc.communicate(timeout=3 * self.seconds + 60)
        finally:
            self.device.stop()
        self.stderr = err
        if self.proc.returncode != 0:
            raise RuntimeError(f"rtlift control exited {self.proc.returncode}: {err.strip()[-500:]}")
        with open(self.out_json, encoding="utf-8") as f:
            s = self.summary = json.load(f)
        idx, truth = self.stream.truth_array()
        n = int(round(self.seconds * FS_HZ))
        y = truth[(idx >= TRACKING_STARTS) & (idx < TRACKING_STARTS + n)]
        r = reference_values(self.reference, len(y))
        st = self.device.stats
        return {"feedback": "on" if self.feedback else "off",
                "rmse_truth": truth_rmse(y, r),
                "settling_s": settling_times(y, r) if self.reference.startswith("steps:") else None,
                "rmse_estimate": s["tracking_rmse"], "lost": s["lost"], "received": s["received"],
                "commands_sent": s["commands_sent"], "commands_applied": s["commands_applied"],
                "superseded": st.commands_superseded, "device_applied": st.commands_applied,
                "watchdog_trips": s["watchdog_trips"],
                "command_latency_p50_ms": s["command_latency_p50_ms"],
                "command_latency_p99_ms": s["command_latency_p99_ms"],
                "saturated_fraction": s["saturated_fraction"]}

    def record(self, path: str) -> None:
        """After :meth:`finish`: the run's ``log`` as a record file at ``path`` (``rtlift replay
        LOG --model M --record path``, in this process; its one-line summary goes to stdout)."""
        from rtlift.app.cli import main

        if self.log is None:
            raise RuntimeError("BenchTracking(log=...) is needed for a record")
        if main(["replay", self.log, "--model", self.model, "--record", path]) != 0:
            raise RuntimeError(f"rtlift replay {self.log} --record {path} failed (its error is on stderr)")

    def traces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t from the start of tracking in s, bench truth ΔCL, commanded envelope in V) over
        the tracking time, per device sample."""
        return tracking_traces(self.stream, self.seconds)


def tracking_traces(stream: Any, seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t from the start of tracking in s, bench truth ΔCL, envelope driving the plant in V) of a
    :class:`hil_sim.hil.HilStream` over ``seconds`` of tracking, per device sample."""
    n = int(round(seconds * FS_HZ))
    idx, truth = stream.truth_array()
    _, envelope = stream.envelope_array()
    sel = (idx >= TRACKING_STARTS) & (idx < TRACKING_STARTS + n)
    return (idx[sel] - TRACKING_STARTS) / FS_HZ, truth[sel], envelope[sel]


class _InProcessLink:
    """The host's side of a serial link whose device runs in the same thread: a command goes
    straight to the firmware's command side, arriving before the next sample."""

    kind = "in-process"
    closed = False
    disconnected = False

    def __init__(self, control: Any, counters: Any, modulus: int) -> None:
        self.control = control
        self.counters = counters
        self.seq_modulus = 65536
        self.modulus = modulus
        self.next_index = 0
        self.last_sent = 0

    def send_command(self, envelope_cv: int, burst_period_ms: int = 0, enable: bool = True,
                     watchdog_ms_div10: int = 0) -> int:
        from firmware_io.commands import Command, next_cmd_seq

        seq = self.last_sent = next_cmd_seq(self.last_sent, self.modulus)
        self.control.receive(Command(seq, envelope_cv, burst_period_ms, enable, watchdog_ms_div10),
                             self.next_index)
        self.counters.commands_sent += 1
        return seq


class InProcessTracking:
    """``rtlift control``'s closed loop on the bench in one process, not paced (module docstring).

    ``controller`` a :class:`~rtlift.app.control.LiftController` (its config says feedback on or
    off and the gains); ``reference`` a ``--reference`` spec; ``gust`` a ``--gust`` spec. After
    :meth:`run`, :meth:`traces` gives the bench truth and the envelope over the tracking time
    and ``estimates`` the observer's ΔĈL there."""

    def __init__(self, model: Any, controller: Any, reference: str, seconds: float, *, seed: int = 11,
                 effects: tuple[str, ...] = (FADE,), gust: str | None = None,
                 experiment: str = "random", monitor: Any = None, on_loop: Any = None) -> None:
        from hil_sim.gust import parse_gust
        from hil_sim.hil import HilStream

        self.monitor = monitor   # a DepartureMonitor stepped by the observer loop, as --monitor does
        self.on_loop = on_loop   # called with (ObserverLoop, ControlLoop) before the run (an --adapt Adapter)
        self.model = model
        self.controller = controller
        self.reference = reference
        self.seconds = seconds
        self.stream = HilStream(experiment, seed=seed, effects=list(effects), gust=parse_gust(gust))
        self.estimates = np.zeros(0)

    def run(self) -> InProcessTracking:
        """Run until ``seconds`` of tracking are done."""
        from firmware_io.calibration import Calibration
        from firmware_io.commands import SERIAL_CMD_SEQ_MODULUS
        from firmware_io.convert import Converter
        from firmware_io.serial_codec import SerialDecoder, encode_sample
        from hil_sim.devices.faults import DeviceStats
        from hil_sim.devices.host_control import HostControl
        from hil_sim.devices.source import serial_wire, wire_samples
        from rtlift.app.applied import commands_not_applied
        from rtlift.app.closed_loop import ControlLoop
        from rtlift.app.live import ObserverLoop
        from rtlift.app.reference import parse_reference
        from rtlift.observer import Observer

        fs = self.model.fs_hz
        calibration = Calibration()
        control = HostControl(DeviceStats(), SERIAL_CMD_SEQ_MODULUS, fs)
        self.stream.control = control
        received: list = []
        decoder = SerialDecoder(received.append, calibration)
        decoder.feed(b"\x00")
        link = _InProcessLink(control, decoder.counters, SERIAL_CMD_SEQ_MODULUS)
        observer = Observer.from_model(self.model)
        observer.warm_up()
        self.controller.reset()
        loop = ObserverLoop(observer, Converter(calibration, fs), link.seq_modulus, fs_hz=fs, monitor=self.monitor)
        closed = ControlLoop(link, loop, self.controller, parse_reference(self.reference), calibration, fs,
                             int(round(self.seconds * fs)))
        if self.on_loop is not None:
            self.on_loop(loop, closed)
        period_us = int(round(1e6 / fs))
        for index, (volt_cv, envelope_cv, status, counts) in enumerate(wire_samples(self.stream, serial_wire)):
            cmd_seq, status, envelope_cv = control.step(index, status, envelope_cv)
            decoder.feed(encode_sample(index, index * period_us, volt_cv, counts, status, envelope_cv, cmd_seq))
            link.next_index = index + 1
            for sample in received:
                closed.feed(sample)
            received.clear()
            if closed.done:
                break
        ignored = commands_not_applied(link.counters.commands_sent, link.counters.commands_applied)
        if ignored:                 # as rtlift control's exit 1 (issue 44)
            raise RuntimeError(f"in-process tracking: {ignored}")
        self.closed = closed
        self.estimates = np.asarray(closed.estimates)
        return self

    def traces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t from the start of tracking in s, bench truth ΔCL, envelope driving the plant in V)."""
        return tracking_traces(self.stream, self.seconds)
