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
    """One closed-loop run: the bench (in this process) and ``rtlift control`` (a subprocess)."""

    def __init__(self, model: str, reference: str, feedback: bool, seconds: float, out_json: str, *,
                 seed: int = 11, effects: tuple[str, ...] = (FADE,), can: bool = False,
                 experiment: str = "random", log: str | None = None) -> None:
        from hil_sim.devices import SerialDaq, SlcanAdapter
        from hil_sim.hil import HilStream

        self.reference = reference
        self.feedback = feedback
        self.seconds = seconds
        self.out_json = out_json
        self.model = model
        self.log = log
        self.stream = HilStream(experiment, seed=seed, effects=list(effects))
        self.device = (SlcanAdapter if can else SerialDaq)(self.stream)
        self.stream.control = self.device.control
        link = ["--can", f"slcan:{self.device.path}"] if can else ["--serial", self.device.path]
        self.cmd = [sys.executable, "-m", "rtlift", "control", *link, "--model", model, "--reference",
                    reference, "--seconds", str(seconds), "--feedback", "on" if feedback else "off",
                    "--json", out_json, *(["--log", log] if log else [])]
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
        """Wait for ``rtlift control``; its summary's counters beside the bench truth's RMSE."""
        try:
            _, err = self.proc.communicate(timeout=self.seconds + 60)
        finally:
            self.device.stop()
        if self.proc.returncode != 0:
            raise RuntimeError(f"rtlift control exited {self.proc.returncode}: {err.strip()[-500:]}")
        with open(self.out_json, encoding="utf-8") as f:
            s = json.load(f)
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
        n = int(round(self.seconds * FS_HZ))
        idx, truth = self.stream.truth_array()
        _, envelope = self.stream.envelope_array()
        sel = (idx >= TRACKING_STARTS) & (idx < TRACKING_STARTS + n)
        return (idx[sel] - TRACKING_STARTS) / FS_HZ, truth[sel], envelope[sel]
