"""The fit of each lift effect, as the registry (:mod:`rtlift.core.registry`) names it. Every
``fit_<effect>(base, train, ctx)`` takes the current model and the training record and returns a
:class:`~rtlift.diagnose.surgery.Fitted` (the augmented model, its parameters, and whether a
parameter ended on a bound of its range) or a string saying why there is nothing to fit. The
objective is the output error on the training record after ``ctx.start`` (Ljung's simulation
error, eq. 7.12):

- ``delay``: D = argmin_D ‖z(k) − ŷ(k − D)‖ over 1 … 100 samples (the lag search);
- ``actuator_fade``: (f, τ) by Levenberg–Marquardt on the full augmented model, for both
  clocks (burst on-time: heating by actuation; wall time), the better kept;
- ``sensor_resonance``: (f₀, ζ) from the residual spectrum's excess over the fingerprint's
  (α|H|² + 1 − α), f₀ then sharpened on the output error within 5 %; without a fingerprint,
  both by least squares on the model output filtered by the mode, started on a grid;
- ``zero_drift``: offset + rate·t, or offset + A(1 − e^{−t/τ}) (τ on a grid), linear LS;
- ``periodic_disturbance``: the narrow line standing highest above the fingerprint, its
  frequency refined by maximising the periodogram; its harmonics n f₀ as sampled (aliased)
  that also stand above the fingerprint; amplitudes and phases by linear LS;
- ``hysteresis``: ε ≈ m · F(static(Cμ, y) h) for the play operator's branch h (driven by Cμ or by
  the quasi-steady lift itself; width w, relaxation τ, on a grid), m by linear LS (F = the
  model's filter stages), on either Wiener form;
- ``output_nonlinearity``: f(y) as a piecewise-linear table on 10 quantile knots of y, node
  values by ridge-regularised linear LS of the output error (paper form only).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage, optimize, signal

from rtlift.blocks.actuator_fade import ActuatorFade
from rtlift.blocks.delay import Delay
from rtlift.blocks.delivered import STRUCTURE_STAGES
from rtlift.blocks.periodic_disturbance import PeriodicDisturbance, alias_hz
from rtlift.blocks.sensor_resonance import SensorResonance, resonance_ba
from rtlift.blocks.wiener import HysteresisGain, InputGain, OutputHysteresis, OutputNonlinearity
from rtlift.blocks.zero_drift import ZeroDrift
from rtlift.core.records import Record
from rtlift.diagnose.surgery import (
    Context,
    Fitted,
    at_bound,
    augment,
    burst_slow,
    filter_chain,
    output_sse,
    predict,
    wiener_parts,
)
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Z_DEPART, Departure, psd_departure
from rtlift.residual.stats import Peak, cluster_ols

MAX_LAG = 100                      # samples the delay search reaches (0.25 s at 400 Hz)
HEAVY_DAMPING = 0.3                # a "resonance" damped more than this is a lag, not a mode


def fit_delay(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    d = int(ctx.tests["lag"].data["lag"])
    if d == 0:
        return "the lag search finds the model in step with the measurement"
    stage = Delay(d / ctx.fs, ctx.fs)
    bound = f"the lag search ended at its largest lag ({MAX_LAG} samples)" if d >= MAX_LAG else ""
    return Fitted("delay", augment(base, input_stage=stage), stage.params(), on_bound=bound)


def fit_actuator_fade(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    z = train.dcl[ctx.start:]
    lo_tau, hi_tau = 0.05, 500.0
    fits: dict[str, Any] = {}
    for clock in ActuatorFade.CLOCKS:
        model = augment(base, input_stage=ActuatorFade(1.0, 1.0, ctx.fs, clock))
        stage = next(s for s in model.input_stages if type(s) is ActuatorFade)

        def resid(theta: np.ndarray, stage: ActuatorFade = stage, model: HybridModel = model) -> np.ndarray:
            stage.final_fraction = float(np.clip(theta[0], 0.0, 1.0))
            stage.time_constant_s = float(np.exp(theta[1]))
            return z - predict(model, train).total[ctx.start:]

        scale = 1.0 if clock == "time" else 0.1        # burst on-time runs at the duty cycle
        for f0, tau0 in ((0.6, 3.0), (0.85, 8.0), (0.4, 1.0)):
            res = optimize.least_squares(resid, [f0, math.log(tau0 * scale)],
                                         bounds=([0.0, math.log(lo_tau)], [1.0, math.log(hi_tau)]),
                                         x_scale=[0.1, 0.5], max_nfev=60)
            if clock not in fits or res.cost < fits[clock].cost:
                fits[clock] = res
    # with bursts at a fixed period the two clocks are proportional: heating by actuation (the
    # burst on-time) stays unless the wall clock fits the training record clearly better
    clock = "time" if fits["time"].cost < 0.98 * fits["on_time"].cost else "on_time"
    res = fits[clock]
    stage = ActuatorFade(float(res.x[0]), float(math.exp(res.x[1])), ctx.fs, clock)
    bound = at_bound(stage.final_fraction, 0.0, 1.0, "final_fraction") or \
        at_bound(math.log(stage.time_constant_s), math.log(lo_tau), math.log(hi_tau), "log time_constant_s")
    return Fitted("actuator_fade", augment(base, input_stage=stage), stage.params(), on_bound=bound)


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
    _, h = signal.freqz(b, a, worN=f, fs=fs)
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
    for x in (*ctx.input_lines_hz, *(p.frequency_hz for p, _ in _standing_lines(ctx))):
        locked |= np.abs(f - x) <= 2.0 * df
    free = (~locked).astype(float)                        # 3-bin mean over the free bins only
    excess = 10.0 / math.log(10.0) * ndimage.uniform_filter1d(_psd_excess(ctx) * free, size=3, mode="reflect") \
        / np.maximum(ndimage.uniform_filter1d(free, size=3, mode="reflect"), 1e-12)
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

    res = optimize.least_squares(resid, [f_peak, 0.1, 0.5],
                                 bounds=([max(lo_f, 0.8 * f_peak), lo_z, 0.01], [min(hi_f, 1.2 * f_peak), hi_z, 1.0]),
                                 x_scale=[max(1.0, 0.05 * f_peak), 0.02, 0.1], loss="soft_l1", f_scale=3.0)
    return float(res.x[0]), float(res.x[1])


def fit_sensor_resonance(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    out = predict(base, train)
    filtered = filter_chain(base)(out.high + out.low)     # linear filters commute (from rest)
    extra = out.total - filtered                           # the additive stages' share
    z = train.dcl[ctx.start:]

    def sse(f: float, zeta: float) -> float:
        b, a = resonance_ba(f, zeta, ctx.fs)
        return float(np.sum((z - (signal.lfilter(b, a, filtered) + extra)[ctx.start:]) ** 2))

    lo_f, hi_f, lo_z, hi_z = 5.0, 0.47 * ctx.fs, 0.005, 0.7
    mode = _spectral_mode(ctx, lo_f, hi_f, lo_z, hi_z)
    if mode is not None:
        # the spectrum says where the mode is; f₀ (within 5 % of it) and ζ (over its whole
        # range) are fitted on the output error, from the spectrum's ζ and a few others: where
        # the mode sits on a burst harmonic, the model's error there, amplified by the mode,
        # leaks into the bins next to the line and makes the spectral peak look narrower than
        # it is; the output error, which holds the lift filtered by the mode, is not fooled.
        f_s, z_s = mode
        fits = [optimize.least_squares(lambda th: [math.sqrt(sse(th[0], th[1]))], [f_s, z0],
                                       bounds=([0.95 * f_s, lo_z], [1.05 * f_s, hi_z]),
                                       x_scale=[max(1.0, 0.05 * f_s), 0.3 * z0])
                for z0 in sorted({min(max(z_s, lo_z), hi_z), 0.02, 0.05, 0.1, 0.2})]
        best = min(fits, key=lambda r: r.cost)
        f, zeta = float(best.x[0]), float(best.x[1])
    else:
        grid = [(f, zt) for f in np.geomspace(8.0, 0.45 * ctx.fs, 14) for zt in (0.05, 0.2)]
        f0, z0 = min(grid, key=lambda th: sse(*th))
        res = optimize.least_squares(lambda th: [math.sqrt(sse(th[0], th[1]))], [f0, z0],
                                     bounds=([lo_f, lo_z], [hi_f, hi_z]), x_scale=[max(1.0, 0.05 * f0), 0.02])
        f, zeta = float(res.x[0]), float(res.x[1])
    fitted = SensorResonance(f, zeta, ctx.fs)
    bound = at_bound(f, lo_f, hi_f, "frequency_hz") or at_bound(zeta, lo_z, hi_z, "damping_ratio")
    if not bound and zeta > HEAVY_DAMPING:
        bound = (f"damping_ratio {zeta:.2f} > {HEAVY_DAMPING}: a heavily damped 'mode' is a lag, not a "
                 f"resonance (compare delay)")
    return Fitted("sensor_resonance", augment(base, output_stage=fitted), fitted.params(),
                  "(f0, damping) started from the residual spectrum's excess over the fingerprint, refined "
                  "on the output error" if mode else "",
                  on_bound=bound)


def fit_zero_drift(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    e = train.dcl - predict(base, train).total
    t = np.arange(e.size) / ctx.fs
    s = ctx.start
    X = np.column_stack([np.ones(e.size), t])
    (off, rate), *_ = np.linalg.lstsq(X[s:], e[s:], rcond=None)
    sse_lin = float(np.sum((e[s:] - X[s:] @ [off, rate]) ** 2))
    taus = np.geomspace(1.0, 300.0, 30)
    best = None
    for tau in taus:
        Xe = np.column_stack([np.ones(e.size), 1.0 - np.exp(-t / tau)])
        coef, *_ = np.linalg.lstsq(Xe[s:], e[s:], rcond=None)
        sse = float(np.sum((e[s:] - Xe[s:] @ coef) ** 2))
        if best is None or sse < best[0]:
            best = (sse, tau, coef)
    # a thermal drift approaches its end value: the exponential unless its time constant runs
    # to the grid's end (then it is a straight line over the record) or it fits no better
    interior = best is not None and taus[0] < best[1] < taus[-1]
    if interior and best[0] < sse_lin:
        _, tau, (off_e, amp) = best
        stage = ZeroDrift(ctx.fs, amplitude=float(amp), time_constant_s=float(tau), offset=float(off_e))
    else:
        stage = ZeroDrift(ctx.fs, rate_per_s=float(rate), offset=float(off))
    return Fitted("zero_drift", augment(base, output_stage=stage), stage.params())


def _line_departs(ctx: Context, f_hz: float) -> Departure:
    df = float(ctx.tests["spectrum"].data["f"][1])
    return psd_departure(ctx.tests["spectrum"], ctx.fingerprint, [(f_hz - 1.5 * df, f_hz + 1.5 * df)],
                         f"line at {f_hz:.2f} Hz") if ctx.fingerprint else Departure(99.0, True, "no print")


def _standing_lines(ctx: Context) -> list[tuple[Peak, Departure]]:
    """The training residual's narrow lines (not at the input's lines) whose power stands above
    the print, with their departures."""
    lines = [p for p in ctx.tests["spectrum"].data["peaks"] if p.kind == "line"]
    return [(p, d) for p, d in ((p, _line_departs(ctx, p.frequency_hz)) for p in lines) if d.departs]


def fit_periodic_disturbance(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    spec = ctx.tests["spectrum"].data
    standing = _standing_lines(ctx)
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
    f0 = float(optimize.minimize_scalar(neg_power, bounds=(f_grid - step, f_grid + step), method="bounded",
                                        options={"xatol": 1e-7}).x)
    # harmonics n f0 as sampled that also stand above the print and clear of the input's lines
    taken = [f0]
    harmonics = []
    for n in range(2, 16):
        fh = alias_hz(n * f0, ctx.fs)
        if fh < 1.0 or fh > 0.5 * ctx.fs - df or any(abs(fh - x) <= 2 * df for x in taken) or \
                any(abs(fh - x) <= 2 * df for x in ctx.input_lines_hz):
            continue
        if _line_departs(ctx, fh).departs:
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
    return Fitted("periodic_disturbance", augment(base, output_stage=stage), stage.params(), note)


def fit_hysteresis(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    """Kept only where evidence points at it: the training residual's gain differs between
    falling and rising Cμ (the direction test, |t| > 4), or the fitted play operator's branch
    column itself stands out, t ≥ ``Z_DEPART`` (cluster-robust over 1 s blocks, in the final
    regression below) with more gain on the falling branch (m > 0: stall hysteresis, the flow
    once attached stays attached as the actuation falls). The direction test alone misses a
    hysteresis that follows the lift on a random input (the branch switches with the flow's state,
    not with each wiggle of Cμ: t = −3.1 on the independent plant's ``random``, where the branch
    column's t is 16); on clean random records the branch column's t was ≤ 2.7 with m > 0
    (independent plant, campaign and clean seeds) and negative on ten bench seeds
    (``benchmarks.null_rate``). A play operator on the lift can fit a misfit of another kind,
    and the name must rest on the evidence that points at it.

    (driver, width, τ) on a grid by linear LS of ε ≈ (g − 1) F(q) + g m F(q h) + c F(q Cμ/span)
    (q = the nonlinearity's quasi-steady lift static(Cμ, y), h the play operator's branch of
    :class:`rtlift.blocks.wiener._DirectionMemory` on the driver — Cμ, or q itself — computed
    by the block itself): the last column, a static level-dependent gain, is a nuisance that
    keeps a very wide play operator (which degenerates into one) from standing in for the map's
    own misfit; the grid's best (width in fractions of the driver's range on the record) is
    refined continuously (Nelder–Mead in √w, √τ, the grid is coarse: a relaxation of 0.245 s
    fitted at 0.2 s biases m by 15 %); then (g, m) by linear LS without the nuisance.

    In the interaction structure the lift driver is the flow's whole quasi-steady lift, q plus
    the burst part's slow term (:func:`.surgery.burst_slow`, as the model steps it), and the
    ``cmu`` driver is not offered: the Wiener input there is the delivered envelope's static
    lift u, not the command, and a play operator on u fits the training record's noise. On the
    independent plant's ``hysteresis`` case (model from the full campaign, trained on the sine
    it repeats) a u-driven operator beat the lift by 3 % in SSE on the training sine and took
    24 % of the hysteresis imprint off random; the lift driver on the whole slow lift takes 66 %
    (the paper's hybrid: 68 %); on the Wiener part alone it took 44 %."""
    nl = base.wiener.nonlinearity
    if type(nl) not in (InputGain, OutputNonlinearity):
        return f"the Wiener nonlinearity is already '{nl.form}'"
    direction = ctx.tests.get("direction")
    env, y = wiener_parts(base, train)
    e = train.dcl - predict(base, train).total
    F = filter_chain(base)
    ny = nl.simulate(env, y)
    s = ctx.start
    span = float(np.ptp(env[s:]))
    fractions = (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.7)
    taus = (0.0, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
    flow = burst_slow(base, train)                  # the lift driver's offset (interaction structure)
    spans = {"cmu": span, "lift": float(np.ptp((ny + flow)[s:]))}
    if any(st.name in STRUCTURE_STAGES for st in base.input_stages):
        del spans["cmu"]                            # the Wiener input is not the command (docstring)

    z = e[s:]
    plain = F(ny)[s:]
    level = F(ny * env / max(span, 1e-300))[s:]     # a static, level-dependent gain: nuisance

    def column(driver: str, width: float, tau: float) -> np.ndarray:
        memory = OutputHysteresis([0.0, 1.0], [0.0, 1.0], 1.0, tau, ctx.fs, width, driver=driver)
        memory.offset = flow
        return F(ny * memory.branch(env, ny))[s:]

    def sse(col: np.ndarray) -> float:
        X = np.column_stack([plain, col, level])
        coef, *_ = np.linalg.lstsq(X, z, rcond=None)
        return float(np.sum((z - X @ coef) ** 2))

    best = None
    for driver, driver_span in spans.items():
        for fraction in fractions:
            for tau in taus:
                cost = sse(column(driver, fraction * driver_span, tau))
                if best is None or cost < best[0]:
                    best = (cost, driver, fraction, tau)
    _, driver, fraction, tau = best
    # the grid's point refined: (w, τ) = (a² · range, b²), Nelder–Mead on the same cost
    scale = spans[driver]
    a0, b0 = math.sqrt(fraction), math.sqrt(tau)
    simplex = [[a0, b0], [a0 + 0.1, b0], [a0, b0 + 0.1]]
    sol = optimize.minimize(lambda v: sse(column(driver, v[0] ** 2 * scale, v[1] ** 2)), [a0, b0],
                            method="Nelder-Mead",
                            options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 0.0, "maxfev": 80})
    if sol.fun < best[0]:
        fraction, tau = float(sol.x[0] ** 2), float(sol.x[1] ** 2)
    width = fraction * scale
    col = column(driver, width, tau)
    (dg, dm), se = cluster_ols(np.column_stack([plain, col]), z, int(ctx.fs))
    t_branch = float(dm / se[1])
    if direction is not None and not direction.significant and t_branch < Z_DEPART:
        return (f"the residual's gain does not depend on the direction ({direction.detail}) and the play "
                f"operator's branch does not stand out (t = {t_branch:.1f} < {Z_DEPART:g} with more gain falling)")
    if 1.0 + dg <= 0:
        return "the fitted rising-branch gain is not positive"
    g = 1.0 + float(dg)
    m = float(dm) / g
    if isinstance(nl, InputGain):
        new = HysteresisGain(nl.cmu, nl.gain, m, tau, ctx.fs, width, g, driver)
    else:
        new = OutputHysteresis(nl.y, nl.f, m, tau, ctx.fs, width, g, driver)
    bound = (f"time_constant_s ended beyond the grid's largest value ({taus[-1]:g} s)" if tau >= taus[-1] else
             f"width ended beyond the grid's largest value ({width:.3g})" if fraction >= fractions[-1] else "")
    return Fitted("hysteresis", augment(base, nonlinearity=new),
                  {"magnitude": m, "rising_gain": g, "width": width, "time_constant_s": tau, "driver": driver},
                  on_bound=bound)


def fit_output_nonlinearity(base: HybridModel, train: Record, ctx: Context,
                            knots: int = 10, ridge: float = 1e-3) -> Fitted | str:
    """Textbook Wiener: f(y) instead of N(Cμ)·y. The LTI is re-identified by output-error PEM
    with f = the model's own static map (Cμ ↦ N(Cμ)·Cμ), then f's node values are refined by
    linear LS on quantile knots of the new y; the better of the two on training is kept."""
    from rtlift.identify.pem import fit_wiener

    nl = base.wiener.nonlinearity
    if type(nl) is not InputGain:
        return f"the Wiener nonlinearity is already '{nl.form}'"
    if base.output_stages and any(st.kind == "filter" for st in base.output_stages):
        return "not tried behind a filter stage"
    s = ctx.start
    out = predict(base, train)
    env, _ = wiener_parts(base, train)
    z = train.dcl - out.total + out.low                 # what the Wiener part must explain
    grid, fmap = nl.cmu, nl.gain * nl.cmu
    try:
        pem = fit_wiener(env, z, base.wiener.lti.n, form="output_map", fs_hz=ctx.fs,
                         table=(grid, fmap), skip=s, n_starts=1, max_nfev=200)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return f"PEM with f(y) failed ({exc})"
    lti = (pem.lti.A, pem.lti.B, pem.lti.C)
    first = augment(base, nonlinearity=OutputNonlinearity(grid, fmap), lti=lti)
    _, y = wiener_parts(first, train)
    knots_y = np.unique(np.quantile(y[s:], np.linspace(0, 1, knots)))
    best = first
    if knots_y.size >= 3:
        cols = []
        for i in range(knots_y.size):
            unit = np.zeros(knots_y.size)
            unit[i] = 1.0
            cols.append(OutputNonlinearity(knots_y, unit).simulate(env, y))
        Phi = np.column_stack(cols)[s:]
        D2 = np.diff(np.eye(knots_y.size), 2, axis=0)
        A = np.vstack([Phi, ridge * float(np.linalg.norm(Phi, 2)) * D2])
        v, *_ = np.linalg.lstsq(A, np.concatenate([z[s:], np.zeros(D2.shape[0])]), rcond=None)
        refined = augment(base, nonlinearity=OutputNonlinearity(knots_y, v), lti=lti)
        if output_sse(refined, train, s) < output_sse(first, train, s):
            best = refined
    return Fitted("output_nonlinearity", best,
                  {"form": OutputNonlinearity.form, "knots": int(best.wiener.nonlinearity.y.size)})
