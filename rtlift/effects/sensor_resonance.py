"""The ``sensor_resonance`` effect: a force balance / wing structural mode filtering the measured lift.

Fit: (f₀, ζ) from the residual spectrum's excess over the fingerprint's (α|H|² + 1 − α), f₀ then
sharpened on the output error within 5 %; without a fingerprint, both by least squares on the
model output filtered by the mode, started on a grid. Evidence: the residual's power near f₀
against the print's. Stage :class:`rtlift.blocks.sensor_resonance.SensorResonance`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy  # its submodules load on first use (scipy's lazy loader): not on a live start's path

from rtlift.blocks.sensor_resonance import SensorResonance, resonance_ba
from rtlift.core.records import Record
from rtlift.effects.base import Effect, no_print
from rtlift.effects.periodic_disturbance import standing_lines
from rtlift.effects.surgery import Context, Fitted, at_bound, augment, filter_chain, predict
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Departure, psd_departure
from rtlift.residual.stats import TestResult

HEAVY_DAMPING = 0.3                # a "resonance" damped more than this is a lag, not a mode


def _psd_excess(ctx: Context) -> np.ndarray:
    """ln(P_new / P_print) per bin of the training residual's PSD (0 without a print)."""
    spec = ctx.tests["spectrum"].data
    f = np.asarray(spec["f"])
    if ctx.fingerprint is None:
        return np.zeros(f.size)
    fp = ctx.fingerprint["psd"]
    return np.log(np.maximum(spec["psd"], 1e-300)) - np.interp(f, fp["f_hz"], fp["log10"]) * math.log(10.0)


def _mode_gain_db(f: np.ndarray, f0: float, zeta: float, fs: float) -> np.ndarray:
    """20 log10 |H(e^{jω})| of the sensor mode (:func:`resonance_ba`) at frequencies f."""
    b, a = resonance_ba(f0, zeta, fs)
    _, h = scipy.signal.freqz(b, a, worN=f, fs=fs)
    return 20.0 * np.log10(np.maximum(np.abs(h), 1e-12))


def _spectral_mode(ctx: Context, lo_f: float, hi_f: float, lo_z: float, hi_z: float) -> tuple[float, float] | None:
    """(f₀, ζ) of the mode the residual's PSD excess over the fingerprint shows. A mode of the
    measurement chain filters the lift and the aerodynamic noise, not the electronics' noise
    added after it, so over [f₀/3, 3 f₀]

        P_new / P_print ≈ α |H(f; f₀, ζ)|² + (1 − α),

    α the share of the residual's power that passes through the mode; fitted in dB from the
    excess's highest point. At the input's lines (burst and envelope harmonics, ±2 bins) the
    mode multiplies the model's own error there, which is not the print's: those bins say
    nothing of the mode's shape and are left out of the peak search and the fit; so are narrow
    lines that stand above the print (:func:`_standing_lines`: a sinusoid added to the
    measurement, a pickup's, has no mode's shape, and a mode fitted to one ends broad and beside
    it); a robust (soft L1) loss takes care of what is left."""
    if ctx.fingerprint is None:
        return None
    f = np.asarray(ctx.tests["spectrum"].data["f"])
    df = float(f[1])                                      # the Welch grid starts at 0 Hz
    locked = np.zeros(f.size, dtype=bool)
    for x in (*ctx.input_lines_hz, *(p.frequency_hz for p, _ in standing_lines(ctx))):
        locked |= np.abs(f - x) <= 2.0 * df
    free = (~locked).astype(float)                        # 3-bin mean over the free bins only
    excess = 10.0 / math.log(10.0) * scipy.ndimage.uniform_filter1d(_psd_excess(ctx) * free, size=3, mode="reflect") \
        / np.maximum(scipy.ndimage.uniform_filter1d(free, size=3, mode="reflect"), 1e-12)
    band = (f >= lo_f) & (f <= hi_f) & ~locked
    if not band.any():
        return None
    k = int(np.flatnonzero(band)[np.argmax(excess[band])])
    f_peak = float(f[k])
    if excess[k] < 3.0 or not psd_departure(ctx.tests["spectrum"], ctx.fingerprint,
                                            [(f_peak - 2.5 * df, f_peak + 2.5 * df)], "peak").departs:
        return None                                       # no peak stands significantly above the print
    sel = (f >= f_peak / 3.0) & (f <= min(3.0 * f_peak, hi_f)) & ~locked

    def resid(theta: np.ndarray) -> np.ndarray:
        h2 = 10.0 ** (_mode_gain_db(f[sel], theta[0], theta[1], ctx.fs) / 10.0)
        return excess[sel] - 10.0 * np.log10(theta[2] * h2 + 1.0 - theta[2])

    res = scipy.optimize.least_squares(resid, [f_peak, 0.1, 0.5],
                                 bounds=([max(lo_f, 0.8 * f_peak), lo_z, 0.01], [min(hi_f, 1.2 * f_peak), hi_z, 1.0]),
                                 x_scale=[max(1.0, 0.05 * f_peak), 0.02, 0.1], loss="soft_l1", f_scale=3.0)
    return float(res.x[0]), float(res.x[1])


class SensorResonanceEffect(Effect):
    """The unity-DC-gain mode ω²/(s² + 2ζωs + ω²) on the measured lift."""

    name = SensorResonance.name
    row = 20
    meaning = "force balance / wing structural mode filtering the measured lift"
    params = {"frequency_hz": (30.0, 12.0, 80.0, "Hz"), "damping_ratio": (0.05, 0.02, 0.3, "1")}
    path = "filter"
    stages = (SensorResonance,)
    spent = 2

    def fit(self, base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
        out = predict(base, train)
        filtered = filter_chain(base)(out.high + out.low)     # linear filters commute (from rest)
        extra = out.total - filtered                           # the additive stages' share
        z = train.dcl[ctx.start:]

        def sse(f: float, zeta: float) -> float:
            b, a = resonance_ba(f, zeta, ctx.fs)
            return float(np.sum((z - (scipy.signal.lfilter(b, a, filtered) + extra)[ctx.start:]) ** 2))

        lo_f, hi_f, lo_z, hi_z = 5.0, 0.47 * ctx.fs, 0.005, 0.7
        mode = _spectral_mode(ctx, lo_f, hi_f, lo_z, hi_z)
        if mode is not None:
            # the spectrum says where the mode is; f₀ (within 5 % of it) and ζ (over its whole
            # range) are fitted on the output error, from the spectrum's ζ and a few others: where
            # the mode sits on a burst harmonic, the model's error there, amplified by the mode,
            # leaks into the bins next to the line and makes the spectral peak look narrower than
            # it is; the output error, which holds the lift filtered by the mode, is not fooled.
            f_s, z_s = mode
            fits = [scipy.optimize.least_squares(lambda th: [math.sqrt(sse(th[0], th[1]))], [f_s, z0],
                                           bounds=([0.95 * f_s, lo_z], [1.05 * f_s, hi_z]),
                                           x_scale=[max(1.0, 0.05 * f_s), 0.3 * z0])
                    for z0 in sorted({min(max(z_s, lo_z), hi_z), 0.02, 0.05, 0.1, 0.2})]
            best = min(fits, key=lambda r: r.cost)
            f, zeta = float(best.x[0]), float(best.x[1])
        else:
            grid = [(f, zt) for f in np.geomspace(8.0, 0.45 * ctx.fs, 14) for zt in (0.05, 0.2)]
            f0, z0 = min(grid, key=lambda th: sse(*th))
            res = scipy.optimize.least_squares(lambda th: [math.sqrt(sse(th[0], th[1]))], [f0, z0],
                                         bounds=([lo_f, lo_z], [hi_f, hi_z]), x_scale=[max(1.0, 0.05 * f0), 0.02])
            f, zeta = float(res.x[0]), float(res.x[1])
        fitted = SensorResonance(f, zeta, ctx.fs)
        bound = at_bound(f, lo_f, hi_f, "frequency_hz") or at_bound(zeta, lo_z, hi_z, "damping_ratio")
        if not bound and zeta > HEAVY_DAMPING:
            bound = (f"damping_ratio {zeta:.2f} > {HEAVY_DAMPING}: a heavily damped 'mode' is a lag, not a "
                     f"resonance (compare delay)")
        return Fitted(self.name, augment(base, output_stage=fitted), fitted.params(),
                      "(f0, damping) started from the residual spectrum's excess over the fingerprint, refined "
                      "on the output error" if mode else "",
                      on_bound=bound)

    def evidence(self, tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
        f, z = fitted.params["frequency_hz"], fitted.params["damping_ratio"]
        df = float(tests["spectrum"].data["f"][1])
        half = max(2 * z * f, 2 * df)
        return psd_departure(tests["spectrum"], fp, [(f - half, f + half)], f"residual power near {f:.1f} Hz") \
            if fp else no_print(f"mode at {f:.1f} Hz")

    def bands(self, params: dict[str, Any], df: float) -> list[tuple[float, float]]:
        """A sensor mode's half-power band f(1 ± ζ), widened by half a spectrum bin ``df``."""
        f0, zeta = float(params["frequency_hz"]), float(params["damping_ratio"])
        return [(f0 * (1 - zeta) - 0.5 * df, f0 * (1 + zeta) + 0.5 * df)]
