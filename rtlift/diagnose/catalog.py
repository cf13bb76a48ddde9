"""The effect catalog: one augmentation per INTERFACES.md effect name, each with its own fit.

Every ``fit_<effect>(base, train, ctx)`` takes the current model and the training record
and returns a :class:`Fitted` (the augmented model and its parameters) or ``None`` with a
reason when the residual offers nothing to fit. The objective is always the output error
on the training record after ``ctx.start`` (Ljung's simulation error, eq. 7.12):

- ``delay``: D = argmin_D ‖z(k) − ŷ(k − D)‖ over 1 … 60 samples (the lag search);
- ``actuator_fade``: (f, τ) by Levenberg–Marquardt on the full augmented model;
- ``sensor_resonance``: (f₀, ζ) by least squares on the model output filtered by the mode,
  started from the residual spectrum's sharp peaks and a grid;
- ``zero_drift``: offset + rate·t, or offset + A(1 − e^{−t/τ}) (τ on a grid), linear LS;
- ``periodic_disturbance``: the residual spectrum's strongest narrow line, frequency refined
  by maximising the periodogram, amplitude and phase by linear LS;
- ``hysteresis``: ε ≈ m · F(N(Cμ) y h_τ) for τ on a grid, m by linear LS (F = the model's
  filter stages);
- ``output_nonlinearity``: f(y) as a piecewise-linear table on 10 quantile knots of y, node
  values by ridge-regularised linear LS of the output error.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize, signal

from rtlift.blocks.stages import (
    ActuatorFade,
    Delay,
    InputStage,
    OutputStage,
    PeriodicDisturbance,
    SensorResonance,
    ZeroDrift,
    resonance_ba,
)
from rtlift.blocks.wiener import HysteresisGain, InputGain, OutputNonlinearity
from rtlift.diagnose.residual import TestResult, falling_indicator
from rtlift.hybrid import HybridModel, HybridOutput
from rtlift.modelfile import model_from_dict, model_to_dict
from rtlift.records import Record

EFFECT_NAMES = ("delay", "sensor_resonance", "actuator_fade", "zero_drift", "periodic_disturbance",
                "hysteresis", "output_nonlinearity")


@dataclass
class Fitted:
    name: str
    model: HybridModel
    params: dict[str, Any]
    note: str = ""


@dataclass
class Context:
    fs: float
    start: int                                   # first scored sample of every record
    tests: dict[str, TestResult] = field(default_factory=dict)   # on the training residual
    burst_hz: float = 0.0
    envelope_hz: float = 0.0


# ------------------------------------------------------------------ model surgery
def augment(model: HybridModel, *, input_stage: InputStage | None = None,
            output_stage: OutputStage | None = None, nonlinearity: Any = None,
            lti: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> HybridModel:
    """A fresh copy of ``model`` with one more stage (filters before additive output stages)
    or another Wiener nonlinearity."""
    d = model_to_dict(model)
    if input_stage is not None:
        d["input_stages"].append({"name": input_stage.name, "params": input_stage.params()})
    if output_stage is not None:
        entry = {"name": output_stage.name, "params": output_stage.params()}
        stages = d["output_stages"]
        if output_stage.kind == "filter":
            first_additive = next((i for i, s in enumerate(model.output_stages) if s.kind == "additive"),
                                  len(stages))
            stages.insert(first_additive, entry)
        else:
            stages.append(entry)
    if nonlinearity is not None:
        d["wiener"]["nonlinearity"] = nonlinearity.to_dict()
    if lti is not None:
        d["wiener"].update(A=np.asarray(lti[0]).tolist(), B=np.asarray(lti[1]).tolist(),
                           C=np.asarray(lti[2]).tolist())
    return model_from_dict(d, allow_unstable=not model.stable)


def simulate(model: HybridModel, rec: Record) -> HybridOutput:
    model.reset()
    out = model.simulate(rec.cmu, rec.cmu_envelope)
    model.reset()
    return out


def predict(model: HybridModel, rec: Record, window: int) -> HybridOutput:
    """Open-loop model output; a periodic disturbance's phase (a property of the record, not of
    the pickup) is re-estimated on the record's first ``window`` samples, never on the rest."""
    out = simulate(model, rec)
    total = out.total
    n = total.size
    k = np.arange(n)
    for s in model.output_stages:
        if isinstance(s, PeriodicDisturbance) and window >= 8:
            old = s.amplitude * np.sin(s.omega * k + s.phase_rad)
            r = rec.dcl[:window] - (total[:window] - old[:window])
            X = np.column_stack([np.sin(s.omega * k[:window]), np.cos(s.omega * k[:window])])
            (a, b), *_ = np.linalg.lstsq(X, r, rcond=None)
            phase = math.atan2(b, a)
            total = total - old + s.amplitude * np.sin(s.omega * k + phase)
    return HybridOutput(total, out.high, out.low)


def _filter_chain(model: HybridModel) -> Callable[[np.ndarray], np.ndarray]:
    """F: the model's filter-kind output stages (linear), applied from rest."""
    filters = [s for s in model.output_stages if s.kind == "filter"]

    def apply(x: np.ndarray) -> np.ndarray:
        for s in filters:
            s.reset()
            x = s.simulate(x)
            s.reset()
        return x
    return apply


def _wiener_parts(model: HybridModel, rec: Record) -> tuple[np.ndarray, np.ndarray]:
    """(Cμ_env after the input stages, y = C x) on a record, from rest."""
    model.reset()
    cmu, env = rec.cmu, rec.cmu_envelope
    for s in model.input_stages:
        cmu, env = s.simulate(cmu, env)
    y = model.wiener.lti.simulate(env)
    model.reset()
    return env, y


# ------------------------------------------------------------------ fits
def fit_delay(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    lag = ctx.tests["lag"]
    d = int(lag.data["lag"])
    if d == 0:
        return "the lag search finds the model in step with the measurement"
    stage = Delay(d / ctx.fs, ctx.fs)
    return Fitted("delay", augment(base, input_stage=stage), stage.params())


def fit_actuator_fade(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    stage = ActuatorFade(1.0, 1.0, ctx.fs)
    model = augment(base, input_stage=stage)
    stage = model.input_stages[-1]
    z = train.dcl[ctx.start:]

    def resid(theta: np.ndarray) -> np.ndarray:
        stage.final_fraction = float(np.clip(theta[0], 0.0, 1.0))
        stage.time_constant_s = float(np.exp(theta[1]))
        return z - predict(model, train, ctx.start).total[ctx.start:]

    best = None
    for f0, tau0 in ((0.6, 3.0), (0.85, 8.0), (0.4, 1.0)):
        res = optimize.least_squares(resid, [f0, math.log(tau0)],
                                     bounds=([0.0, math.log(0.05)], [1.0, math.log(200.0)]),
                                     x_scale=[0.1, 0.5], max_nfev=60)
        if best is None or res.cost < best.cost:
            best = res
    stage.final_fraction = float(best.x[0])
    stage.time_constant_s = float(math.exp(best.x[1]))
    return Fitted("actuator_fade", augment(base, input_stage=stage), stage.params())


def fit_sensor_resonance(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    out = predict(base, train, ctx.start)
    filtered = _filter_chain(base)(out.high + out.low)     # linear filters commute (from rest)
    extra = out.total - filtered                           # the additive stages' share
    z = train.dcl[ctx.start:]

    def output(f: float, zeta: float) -> np.ndarray:
        b, a = resonance_ba(f, zeta, ctx.fs)
        return signal.lfilter(b, a, filtered) + extra

    def resid(theta: np.ndarray) -> np.ndarray:
        return z - output(theta[0], theta[1])[ctx.start:]

    named = [p for p in ctx.tests["spectrum"].data["peaks"] if p.kind == "resonance"]
    if named:
        # the spectrum has seen the mode: the fit may only refine it (the deterministic part alone
        # would also use the mode to reshape the model's ripple error at the burst harmonics)
        f_spec = named[0].frequency_hz
        lo, hi = max(5.0, 0.8 * f_spec), min(0.47 * ctx.fs, 1.2 * f_spec)
        starts = [(f_spec, min(max(named[0].damping_ratio, 0.02), 0.3))]
    else:
        lo, hi = 5.0, 0.47 * ctx.fs
        grid = [(f, zt) for f in np.geomspace(8.0, 0.45 * ctx.fs, 14) for zt in (0.05, 0.2)]
        starts = sorted(grid, key=lambda th: float(np.sum(resid(np.array(th)) ** 2)))[:2]
    best = None
    for f0, z0 in starts:
        res = optimize.least_squares(resid, [f0, z0], bounds=([lo, 0.01], [hi, 0.35]),
                                     x_scale=[max(1.0, 0.05 * f0), 0.02], max_nfev=80)
        if best is None or res.cost < best.cost:
            best = res
    fitted = SensorResonance(float(best.x[0]), float(best.x[1]), ctx.fs)
    return Fitted("sensor_resonance", augment(base, output_stage=fitted), fitted.params())


def fit_zero_drift(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    e = train.dcl - predict(base, train, ctx.start).total
    t = np.arange(e.size) / ctx.fs
    s = ctx.start
    X = np.column_stack([np.ones(e.size), t])
    (off, rate), *_ = np.linalg.lstsq(X[s:], e[s:], rcond=None)
    sse_lin = float(np.sum((e[s:] - X[s:] @ [off, rate]) ** 2))
    best = None
    for tau in np.geomspace(1.0, 300.0, 30):
        Xe = np.column_stack([np.ones(e.size), 1.0 - np.exp(-t / tau)])
        coef, *_ = np.linalg.lstsq(Xe[s:], e[s:], rcond=None)
        sse = float(np.sum((e[s:] - Xe[s:] @ coef) ** 2))
        if best is None or sse < best[0]:
            best = (sse, tau, coef)
    if best is not None and best[0] < 0.98 * sse_lin:
        _, tau, (off_e, amp) = best
        stage = ZeroDrift(ctx.fs, amplitude=float(amp), time_constant_s=float(tau), offset=float(off_e))
    else:
        stage = ZeroDrift(ctx.fs, rate_per_s=float(rate), offset=float(off))
    return Fitted("zero_drift", augment(base, output_stage=stage), stage.params())


def fit_periodic_disturbance(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    lines = [p for p in ctx.tests["spectrum"].data["peaks"] if p.kind == "line"]
    if not lines:
        return "no narrow line in the residual spectrum (peaks at burst harmonics are input-locked)"
    e = train.dcl - predict(base, train, ctx.start).total
    s = ctx.start
    k = np.arange(e.size)
    ek = e[s:] - e[s:].mean()
    kk = k[s:]
    df = ctx.tests["spectrum"].data["f"][1]
    line = max(lines[:3], key=lambda q: _line_power(ek, kk, q.frequency_hz, ctx.fs))

    def neg_power(f: float) -> float:
        w = 2 * math.pi * f / ctx.fs
        return -abs(np.dot(ek, np.exp(-1j * w * kk))) ** 2

    nfft = 1 << int(math.ceil(math.log2(16 * ek.size)))         # ≈ 1/16 of the DTFT main lobe
    spec = np.abs(np.fft.rfft(ek, nfft)) ** 2
    freqs = np.fft.rfftfreq(nfft, 1.0 / ctx.fs)
    near = np.flatnonzero(np.abs(freqs - line.frequency_hz) <= 1.5 * df)
    f_grid = float(freqs[near[np.argmax(spec[near])]])
    step = freqs[1]
    res = optimize.minimize_scalar(neg_power, bounds=(f_grid - step, f_grid + step), method="bounded",
                                   options={"xatol": 1e-7})
    f = float(res.x)
    w = 2 * math.pi * f / ctx.fs
    X = np.column_stack([np.sin(w * k), np.cos(w * k), np.ones(e.size)])
    (a, b, _), *_ = np.linalg.lstsq(X[s:], e[s:], rcond=None)
    stage = PeriodicDisturbance(f, float(math.hypot(a, b)), float(math.atan2(b, a)), ctx.fs)
    return Fitted("periodic_disturbance", augment(base, output_stage=stage), stage.params(),
                  line.describe())


def _line_power(e: np.ndarray, k: np.ndarray, f: float, fs: float) -> float:
    return float(abs(np.dot(e, np.exp(-2j * math.pi * f / fs * k))) ** 2)


def fit_hysteresis(base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
    nl = base.wiener.nonlinearity
    if type(nl) is not InputGain:
        return f"the Wiener nonlinearity is already '{nl.form}'"
    env, y = _wiener_parts(base, train)
    e = train.dcl - predict(base, train, ctx.start).total
    F = _filter_chain(base)
    ny = nl.simulate(env, y)
    fall = falling_indicator(env)
    s = ctx.start
    best = None
    for tau in (0.0, 0.02, 0.05, 0.1, 0.2, 0.35, 0.6, 1.0, 2.0):
        lam = math.exp(-1.0 / (tau * ctx.fs)) if tau > 0 else 0.0
        h = signal.lfilter([1.0 - lam], [1.0, -lam], fall)
        col = F(ny * h)[s:]
        den = float(np.dot(col, col))
        if den <= 0:
            continue
        m = float(np.dot(col, e[s:]) / den)
        sse = float(np.sum((e[s:] - m * col) ** 2))
        if best is None or sse < best[0]:
            best = (sse, tau, m)
    if best is None:
        return "the model's low-frequency part is zero on the training record"
    _, tau, m = best
    new = HysteresisGain(nl.cmu, nl.gain, m, tau, ctx.fs)
    return Fitted("hysteresis", augment(base, nonlinearity=new),
                  {"magnitude": m, "time_constant_s": tau})


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
    out = predict(base, train, s)
    env, _ = _wiener_parts(base, train)
    z = train.dcl - out.total + out.low                 # what the Wiener part must explain
    grid, fmap = nl.cmu, nl.gain * nl.cmu
    try:
        pem = fit_wiener(env, z, base.wiener.lti.n, form="output_map", fs_hz=ctx.fs,
                         table=(grid, fmap), skip=s, n_starts=1, max_nfev=200)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return f"PEM with f(y) failed ({exc})"
    lti = (pem.lti.A, pem.lti.B, pem.lti.C)
    first = augment(base, nonlinearity=OutputNonlinearity(grid, fmap), lti=lti)
    _, y = _wiener_parts(first, train)
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

        def sse(m: HybridModel) -> float:
            return float(np.sum((train.dcl - predict(m, train, s).total)[s:] ** 2))
        if sse(refined) < sse(first):
            best = refined
    return Fitted("output_nonlinearity", best,
                  {"form": OutputNonlinearity.form, "knots": int(best.wiener.nonlinearity.y.size)})


FITS: dict[str, Callable[[HybridModel, Record, Context], Fitted | str]] = {
    "delay": fit_delay,
    "sensor_resonance": fit_sensor_resonance,
    "actuator_fade": fit_actuator_fade,
    "zero_drift": fit_zero_drift,
    "periodic_disturbance": fit_periodic_disturbance,
    "hysteresis": fit_hysteresis,
    "output_nonlinearity": fit_output_nonlinearity,
}

EXCLUSIVE = {"hysteresis": "output_nonlinearity", "output_nonlinearity": "hysteresis"}

N_PARAMS = {"delay": 1, "zero_drift": 2, "periodic_disturbance": 3, "hysteresis": 2, "actuator_fade": 2,
            "sensor_resonance": 2, "output_nonlinearity": 10}
