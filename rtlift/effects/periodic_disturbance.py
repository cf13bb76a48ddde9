"""The ``periodic_disturbance`` effect: narrow-band pickup (mains, fan blade passing) as sampled.

Fit: the narrow line standing highest above the fingerprint, its frequency refined by maximising
the periodogram; its harmonics n f₀ as sampled (aliased) that also stand above the fingerprint;
amplitudes and phases by linear LS. Evidence: the line's power against the print's. Stage
:class:`rtlift.blocks.periodic_disturbance.PeriodicDisturbance`; the observer tracks it with
rotating oscillators (the phases are a record's own).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import scipy  # its submodules load on first use (scipy's lazy loader): not on a live start's path

from rtlift.blocks.periodic_disturbance import PeriodicDisturbance, alias_hz
from rtlift.core.records import Record
from rtlift.effects.base import Effect, StateBlock, no_print
from rtlift.effects.surgery import Context, Fitted, augment, predict
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Departure, psd_departure
from rtlift.residual.stats import Peak, TestResult


def line_departs(ctx: Context, f_hz: float) -> Departure:
    df = float(ctx.tests["spectrum"].data["f"][1])
    return psd_departure(ctx.tests["spectrum"], ctx.fingerprint, [(f_hz - 1.5 * df, f_hz + 1.5 * df)],
                         f"line at {f_hz:.2f} Hz") if ctx.fingerprint else Departure(99.0, True, "no print")


def standing_lines(ctx: Context) -> list[tuple[Peak, Departure]]:
    """The training residual's narrow lines (not at the input's lines) whose power stands above
    the print, with their departures."""
    lines = [p for p in ctx.tests["spectrum"].data["peaks"] if p.kind == "line"]
    return [(p, d) for p, d in ((p, line_departs(ctx, p.frequency_hz)) for p in lines) if d.departs]


class PeriodicDisturbanceEffect(Effect):
    """d(k) = Σ_i A_i sin(2π f_i t_k + φ_i), a fundamental and its harmonics as sampled."""

    name = PeriodicDisturbance.name
    row = 50
    meaning = "narrow-band pickup (mains, fan blade passing) as sampled (ΔCL units)"
    params = {"frequency_hz": (20.0, 1.0, 190.0, "Hz"), "amplitude": (0.006, 0.002, 0.02, "ΔCL")}
    path = "additive"
    stages = (PeriodicDisturbance,)
    per_record = PeriodicDisturbance.per_record
    observed = True

    def fit(self, base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
        spec = ctx.tests["spectrum"].data
        standing = standing_lines(ctx)
        if not standing:
            return ("no narrow line stands above the fingerprint's spectrum (lines at burst harmonics "
                    "are input-locked)")
        line = max(standing, key=lambda pd: pd[1].z)[0]
        e = train.dcl - predict(base, train).total
        s = ctx.start
        k = np.arange(e.size)
        ek = e[s:] - e[s:].mean()
        kk = k[s:]
        df = float(spec["f"][1])

        def neg_power(f: float) -> float:
            w = 2 * math.pi * f / ctx.fs
            return -abs(np.dot(ek, np.exp(-1j * w * kk))) ** 2

        nfft = 1 << int(math.ceil(math.log2(16 * ek.size)))         # ≈ 1/16 of the DTFT main lobe
        power = np.abs(np.fft.rfft(ek, nfft)) ** 2
        freqs = np.fft.rfftfreq(nfft, 1.0 / ctx.fs)
        near = np.flatnonzero(np.abs(freqs - line.frequency_hz) <= 1.5 * df)
        f_grid = float(freqs[near[np.argmax(power[near])]])
        step = freqs[1]
        f0 = float(scipy.optimize.minimize_scalar(neg_power, bounds=(f_grid - step, f_grid + step), method="bounded",
                                            options={"xatol": 1e-7}).x)
        # harmonics n f0 as sampled that also stand above the print and clear of the input's lines
        taken = [f0]
        harmonics = []
        for n in range(2, 16):
            fh = alias_hz(n * f0, ctx.fs)
            if fh < 1.0 or fh > 0.5 * ctx.fs - df or any(abs(fh - x) <= 2 * df for x in taken) or \
                    any(abs(fh - x) <= 2 * df for x in ctx.input_lines_hz):
                continue
            if line_departs(ctx, fh).departs:
                harmonics.append(n)
                taken.append(fh)
        omegas = 2 * math.pi * np.array(taken) / ctx.fs
        X = np.column_stack([np.ones(e.size)] + [g(w * k) for w in omegas for g in (np.sin, np.cos)])
        coef, *_ = np.linalg.lstsq(X[s:], e[s:], rcond=None)
        a, b = coef[1::2], coef[2::2]
        amps, phases = np.hypot(a, b), np.arctan2(b, a)
        harm = [{"n": n, "amplitude": float(A), "phase_rad": float(p)}
                for n, A, p in zip(harmonics, amps[1:], phases[1:], strict=True)]
        stage = PeriodicDisturbance(f0, float(amps[0]), float(phases[0]), ctx.fs, harm)
        note = line.describe() + (f"; harmonics {', '.join(str(n) for n in harmonics)} as sampled at "
                                  f"{', '.join(f'{f:.2f}' for f in taken[1:])} Hz" if harmonics else "")
        return Fitted(self.name, augment(base, output_stage=stage), stage.params(), note)

    def evidence(self, tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
        f = fitted.params["frequency_hz"]
        df = float(tests["spectrum"].data["f"][1])
        return psd_departure(tests["spectrum"], fp, [(f - 1.5 * df, f + 1.5 * df)], f"line at {f:.2f} Hz") \
            if fp else no_print(f"line at {f:.2f} Hz")

    def n_params(self, params: Mapping[str, Any]) -> int:
        """frequency, amplitude and phase of the fundamental, amplitude and phase per harmonic."""
        return 3 + 2 * len(params.get("harmonics", ()))

    def bands(self, params: dict[str, Any], df: float) -> list[tuple[float, float]]:
        """A pickup's lines (the fundamental and its harmonics as sampled) ± 1.5 bins (the window its
        fit searches), widened by half a bin ``df``."""
        lines = [params["frequency_hz"], *(h["frequency_hz"] for h in params.get("harmonics", ()))]
        return [(float(x) - 2.0 * df, float(x) + 2.0 * df) for x in lines]

    def observer_form(self, params: dict[str, Any], fs_hz: float) -> StateBlock:
        """A periodic disturbance Σ A_i sin(ω_i k + φ_i) as rotating 2-state oscillators, one per
        line (the stage's own state space); the phases are the observer's to track."""
        stage = PeriodicDisturbance.from_params(params, fs_hz)
        F, _, h, _ = stage.statespace()
        amp = np.repeat(np.maximum(np.abs(stage.amplitudes), 1e-6), 2)
        return StateBlock(self.name, F, np.diag((1e-3 * amp) ** 2), h, np.diag(amp**2))
