"""The live closed loop of ``rtlift control``: samples in, observer, controller, commands out.

Per received sample (the device's ``seq`` is the clock, as in :mod:`rtlift.app.live`)::

    observer loop: converter → observer.step → estimate ΔĈL
    envelope = controller.step(estimate, r(t))          # t from the start of tracking
    if controller.updated: link.send_command(envelope_cv)

Phases: for ``SETTLE_S`` the host holds the actuator off (envelope-0 commands; samples not fed
to the observer, so a bench that was actuating relaxes before the tare), then the converter's
tare window (actuator still off), then tracking. Decisions are aligned ``MARGIN_SAMPLES``
ahead of the device's burst onsets (status bit3 rising edge), so each command is applied at
the next onset; the first is decided at the first tracked sample (on the one estimate there),
so the first onset of tracking already carries it: waiting for a period's average first left
the actuator off for up to two periods while the reference asked for lift (on plant draw 220
that wait alone was 0.03 of the 70 % fade's tracking ratio, 0.511 → 0.481). On the way out the
actuator is switched off (``enable`` false) and that command's echo awaited briefly, so
``commands_applied`` stays exact.
"""

from __future__ import annotations

import math
import time
from array import array
from typing import Any

import numpy as np

from firmware_io.commands import ENVELOPE_LIMIT_CV
from firmware_io.samples import Sample
from rtlift.app.control import LiftController
from rtlift.app.live import SILENCE_S, ObserverLoop
from rtlift.app.reference import Reference

SETTLE_S = 1.0
FIRST_DECISION = ("first_decision", "at_start")
"""The command log's metadata line saying the loop decided at its first tracked sample (module
docstring); ``rtlift replay`` of a log without it starts the loop as before (a period later)."""
MARGIN_SAMPLES = 10
"""Decide this many samples (25 ms) ahead of the next burst onset: ≫ the command latency."""
STATUS_BURST_ON = 0x08
LOWPASS_HZ = 1.0
OFF_ECHO_S = 0.5
"""Device time (s, counted in samples received) to wait for the echo of the switch-off command:
the device applies a command at its next sample. Time the wire carries nothing (a stall of the
pty: docs/results/control.md, "Host command timing under load") does not use it up; the wait
ends anyway after :data:`rtlift.app.live.SILENCE_S` of the host clock."""


def lowpassed_rmse(reference: np.ndarray, estimate: np.ndarray, fs_hz: float) -> float | None:
    """RMSE of ``estimate`` against ``reference``, both low-passed at 1 Hz (zero phase)."""
    ok = np.isfinite(estimate)
    if ok.sum() < 20:
        return None
    from scipy import signal  # lazy: scipy.signal (and scipy.stats) cost ~1 s of start-up
    sos = signal.butter(2, LOWPASS_HZ, fs=fs_hz, output="sos")
    r, e = reference[ok], estimate[ok]
    pad = min(len(r) - 1, 3 * 6)
    return float(np.sqrt(np.mean((signal.sosfiltfilt(sos, r, padlen=pad)
                                  - signal.sosfiltfilt(sos, e, padlen=pad)) ** 2)))


class ControlLoop:
    """One closed-loop run on an open link (module docstring)."""

    def __init__(self, link: Any, loop: ObserverLoop, controller: LiftController, reference: Reference,
                 calibration: Any, fs_hz: float, tracking_samples: int | None = None, *,
                 first_at_once: bool = True) -> None:
        self.link = link
        self.first_at_once = first_at_once
        """Decide at the first tracked sample (false: after a period, as logs from before
        :data:`FIRST_DECISION` was written were made, so that ``rtlift replay`` repeats them)."""
        self.loop = loop
        self.controller = controller
        self.reference = reference
        self.calibration = calibration
        self.fs_hz = fs_hz
        self.tracking_samples = tracking_samples
        self.settle_samples = int(round(SETTLE_S * fs_hz))
        self.tare_samples = max(1, int(round(calibration.tare_seconds * fs_hz)))
        self.received = 0
        self.tracked = 0
        self.decisions = 0
        self.saturated = 0
        self.refs = array("d")
        self.estimates = array("d")
        self._burst = False
        self._period = controller.config.period

    @property
    def done(self) -> bool:
        return self.tracking_samples is not None and self.tracked >= self.tracking_samples

    def envelope_cv(self, cmu: float) -> int:
        v = float(self.calibration.volts_from_cmu(cmu))
        return min(ENVELOPE_LIMIT_CV, max(0, int(round(v * 100.0))))

    def _hold_off(self) -> None:
        if self.received % self._period == 1:
            self.link.send_command(0)

    def feed(self, sample: Sample) -> None:
        self.received += 1
        if self.received <= self.settle_samples:
            self._hold_off()
            return
        self.loop.feed(sample)
        if self.received <= self.settle_samples + self.tare_samples:
            self._hold_off()
            return
        burst = bool(sample.status & STATUS_BURST_ON)
        ctl = self.controller
        if burst and not self._burst:
            ctl.sync(self._period - MARGIN_SAMPLES)
        elif not self.tracked and self.first_at_once:   # the next onset already carries it
            ctl.sync(1)
        self._burst = burst
        est = self.loop.observer.estimate
        r = self.reference.at(self.tracked / self.fs_hz)
        envelope = ctl.step(est, r)
        self.tracked += 1
        self.refs.append(r)
        self.estimates.append(est.dcl)
        if ctl.updated:
            self.decisions += 1
            self.saturated += ctl.saturated
            self.link.send_command(self.envelope_cv(envelope))

    def switch_off(self, wait_echo: bool = True) -> None:
        """Actuator off (``enable`` false); wait briefly for its echo (exact counters)."""
        link = self.link
        if link.closed or link.disconnected:
            return
        try:
            cmd_seq = link.send_command(0, enable=False)
        except Exception:  # noqa: BLE001 - best effort on the way out
            return
        if cmd_seq is None or not wait_echo:
            return
        left = int(round(OFF_ECHO_S * self.fs_hz))
        end = time.perf_counter() + SILENCE_S
        while left > 0 and time.perf_counter() < end:
            s = link.recv(0.05)
            if s is None:
                if link.closed or link.disconnected:
                    return
                continue
            if s.cmd_seq == cmd_seq:
                return
            left -= 1

    def tracking(self) -> dict[str, Any]:
        """Tracking RMSE (low-passed at 1 Hz), saturated share of the decisions, samples tracked."""
        rmse = lowpassed_rmse(np.asarray(self.refs), np.asarray(self.estimates), self.fs_hz)
        return {"tracking_rmse": rmse if rmse is not None and math.isfinite(rmse) else None,
                "saturated_fraction": self.saturated / self.decisions if self.decisions else 0.0,
                "tracking_samples": self.tracked, "feedback": self.controller.config.feedback}

    def results(self) -> dict[str, Any]:
        """The link's command counters and latency, its longest silence (ms) and its stalls
        (silences ≥ the device's watchdog: trips the host could not prevent,
        :attr:`firmware_io.link_base.Link.stalls`), then :meth:`tracking`."""
        c = self.link.counters
        out: dict[str, Any] = {k: int(c.as_dict()[k]) for k in ("commands_sent", "commands_applied",
                                                                  "watchdog_trips")}
        out.update(c.command_latency_ms())
        link = self.link
        out["link_silence_max_ms"] = getattr(link, "silence_max_s", 0.0) * 1000.0
        out["link_stalls"] = getattr(link, "stalls", 0)
        out.update(self.tracking())
        return out
