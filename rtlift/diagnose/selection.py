"""Closing the loop: residual tests → candidate effects → greedy forward selection.

Every candidate of the catalog is fitted on the training record and judged on validation
records it never saw. A candidate is **accepted** only if, on the pooled validation records
(scored from ``start`` on; the first seconds are where a pickup's phase is estimated):

1. RMSE falls by at least ``min_gain`` (relative),
2. the fall is significant: the per-second squared-error differences have a mean at least
   ``min_t`` standard errors above zero (a Diebold–Mariano test over 1 s blocks),
3. no validation record gets worse by more than 1 % RMSE, and
4. the correlation coefficient ρ does not drop by more than 0.002 (an effect that shrinks
   the signal can lower RMSE while the fit gets worse).

The best accepted candidate is added, the residual re-tested, and the search repeated
(greedy forward selection) until nothing more is accepted. What the final residual still
shows is listed in plain words. Nothing is accepted to look useful.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rtlift.diagnose.catalog import EFFECT_NAMES, EXCLUSIVE, FITS, N_PARAMS, Context, Fitted, predict
from rtlift.diagnose.residual import TestResult, run_all
from rtlift.hybrid import HybridModel
from rtlift.metrics import scores
from rtlift.records import Record


@dataclass(frozen=True)
class DiagnoseOptions:
    start_s: float = 2.0          # scored from here; the first seconds estimate a pickup's phase
    min_gain: float = 0.015       # relative validation RMSE decrease
    min_t: float = 3.0            # significance of the decrease (1 s blocks)
    max_effects: int = 4


@dataclass
class Trial:
    name: str
    accepted: bool
    params: dict[str, Any]
    evidence: str
    rmse_before: float
    rmse_after: float
    detail: str = ""
    model: HybridModel | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "accepted": self.accepted, "params": _plain(self.params),
                "evidence": self.evidence, "validation_rmse_before": self.rmse_before,
                "validation_rmse_after": self.rmse_after}


@dataclass
class Diagnosis:
    report: dict[str, Any]
    baseline: HybridModel
    augmented: HybridModel
    trials: list[Trial]
    tests_before: dict[str, dict[str, TestResult]]
    tests_after: dict[str, dict[str, TestResult]]
    residual_before: dict[str, np.ndarray]
    residual_after: dict[str, np.ndarray]
    start: int
    rounds: list[dict[str, Any]] = field(default_factory=list)


def _plain(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in d.items()}


def burst_rate_hz(rec: Record) -> float:
    """Repetition frequency of the bursts (0 if there are fewer than two)."""
    on = np.flatnonzero((rec.cmu[1:] > 0) & (rec.cmu[:-1] <= 0)) + 1
    if on.size < 2:
        return 0.0
    return float(rec.fs_hz / np.median(np.diff(on)))


def envelope_line_hz(rec: Record) -> float:
    """Fundamental of a periodic envelope (0 if the envelope is not periodic): its low harmonics
    are input-locked model error, not pickup."""
    env = rec.cmu_envelope - rec.cmu_envelope.mean()
    n = env.size
    spec = np.abs(np.fft.rfft(env * np.hanning(n))) ** 2
    f = np.fft.rfftfreq(n, 1.0 / rec.fs_hz)
    k = int(np.argmax(spec[1:])) + 1
    return float(f[k]) if spec[k] > 0.5 * spec[1:].sum() else 0.0


def _tests(model: HybridModel, rec: Record, ctx: Context) -> tuple[dict[str, TestResult], np.ndarray]:
    out = predict(model, rec, ctx.start)
    s = ctx.start
    e = rec.dcl - out.total
    harmonics = tuple(ctx.burst_hz * k for k in range(1, int(0.5 * ctx.fs / ctx.burst_hz) + 1)) \
        if ctx.burst_hz > 0 else ()
    harmonics += tuple(ctx.envelope_hz * k for k in range(1, 7)) if ctx.envelope_hz > 0 else ()
    tests = run_all(rec.dcl[s:], e[s:], out.total[s:], out.low[s:], rec.cmu_envelope[s:], rec.cmu[s:],
                    ctx.fs, harmonics)
    return tests, e


class _Judge:
    """Scores a model on the validation records against a reference model's errors."""

    def __init__(self, records: list[Record], start: int, fs: float) -> None:
        self.records, self.start, self.block = records, start, int(fs)

    def errors(self, model: HybridModel) -> list[np.ndarray]:
        return [r.dcl[self.start:] - predict(model, r, self.start).total[self.start:] for r in self.records]

    def pooled(self, errs: list[np.ndarray]) -> float:
        return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))

    def corr(self, errs: list[np.ndarray]) -> float:
        meas = np.concatenate([r.dcl[self.start:] for r in self.records])
        return scores(meas, meas - np.concatenate(errs))["corr"]

    def verdict(self, before: list[np.ndarray], after: list[np.ndarray], opt: DiagnoseOptions) -> tuple[bool, str]:
        rb, ra = self.pooled(before), self.pooled(after)
        gain = 1.0 - ra / rb if rb > 0 else 0.0
        diffs = []
        for b, a in zip(before, after, strict=True):
            d = b**2 - a**2
            nb = max(1, d.size // self.block)
            diffs += [float(np.mean(x)) for x in np.array_split(d, nb)]
        diffs_a = np.asarray(diffs)
        t = float(diffs_a.mean() / (diffs_a.std(ddof=1) / np.sqrt(diffs_a.size))) if diffs_a.size > 1 and \
            diffs_a.std() > 0 else 0.0
        worst = max(float(np.sqrt(np.mean(a**2)) / np.sqrt(np.mean(b**2))) for b, a in
                    zip(before, after, strict=True))
        dcorr = self.corr(after) - self.corr(before)
        ok = gain >= opt.min_gain and t >= opt.min_t and worst <= 1.01 and dcorr >= -0.002
        why = (f"validation RMSE {rb:.5f} -> {ra:.5f} ({100 * gain:+.1f} %), t = {t:.1f} over "
               f"{diffs_a.size} one-second blocks, worst record x{worst:.3f}, rho {dcorr:+.4f}")
        return ok, why


EVIDENCE_TESTS = {
    "delay": ("lag", "input_crosscorr"),
    "sensor_resonance": ("spectrum",),
    "actuator_fade": ("gain_trend",),
    "zero_drift": ("slow_trend",),
    "periodic_disturbance": ("spectrum",),
    "hysteresis": ("direction",),
    "output_nonlinearity": ("bv_y2_e", "bv_u2_e", "level"),
}


def _evidence(name: str, tests: dict[str, TestResult]) -> str:
    parts = []
    for key in EVIDENCE_TESTS[name]:
        t = tests[key]
        if name == "sensor_resonance":
            peaks = [p for p in t.data["peaks"] if p.kind == "resonance"]
            parts.append(("residual spectrum: " + peaks[0].describe()) if peaks else
                         "residual spectrum: no sharp resonance-like peak")
        elif name == "periodic_disturbance":
            lines = [p for p in t.data["peaks"] if p.kind == "line"]
            parts.append(("residual spectrum: " + lines[0].describe()) if lines else
                         "residual spectrum: no narrow line off the burst harmonics")
        else:
            parts.append(f"{key} ({t.verdict}): {t.detail}")
    return "; ".join(parts)


def diagnose(model: HybridModel, train: Record, validate: list[Record],
             options: DiagnoseOptions | None = None) -> Diagnosis:
    """Residual tests, candidate effects, greedy selection on held-out records (module doc)."""
    opt = options or DiagnoseOptions()
    fs = model.fs_hz
    start = int(round(opt.start_s * fs))
    ctx = Context(fs=fs, start=start, burst_hz=burst_rate_hz(train), envelope_hz=envelope_line_hz(train))
    judge = _Judge(validate, start, fs)
    current = model
    accepted: list[Trial] = []
    last: dict[str, Trial] = {}
    rounds = []
    records = [train, *validate]
    tests_before = {r.name: _tests(model, r, ctx)[0] for r in records}
    resid_before = {r.name: r.dcl - predict(model, r, start).total for r in records}
    for _ in range(opt.max_effects):
        ctx.tests = _tests(current, train, ctx)[0]
        before = judge.errors(current)
        rb = judge.pooled(before)
        taken = {t.name for t in accepted}
        blocked = {EXCLUSIVE[n] for n in taken if n in EXCLUSIVE}
        round_trials: list[Trial] = []
        for name in EFFECT_NAMES:
            if name in taken or name in blocked:
                continue
            evidence = _evidence(name, ctx.tests)
            fitted = FITS[name](current, train, ctx)
            if not isinstance(fitted, Fitted):
                trial = Trial(name, False, {}, f"{evidence}; not fitted: {fitted}", rb, rb,
                              f"not fitted: {fitted}")
            else:
                after = judge.errors(fitted.model)
                ok, why = judge.verdict(before, after, opt)
                trial = Trial(name, ok, fitted.params, f"{evidence}; {why}", rb, judge.pooled(after),
                              why, fitted.model)
            round_trials.append(trial)
            last[name] = trial
        rounds.append({t.name: t.to_dict() for t in round_trials})
        winners = [t for t in round_trials if t.accepted]
        if not winners:
            break
        best = min(winners, key=lambda t: t.rmse_after)
        # parsimony: a simpler effect within 3 % of the best one's error is preferred
        best = min((t for t in winners if t.rmse_after <= 1.03 * best.rmse_after),
                   key=lambda t: (N_PARAMS[t.name], t.rmse_after))
        accepted.append(best)
        current = best.model
        for t in round_trials:
            if t is not best:
                last.pop(t.name, None)
    trials = [*accepted, *[last[n] for n in EFFECT_NAMES if n in last and n not in {t.name for t in accepted}]]
    tests_after = {r.name: _tests(current, r, ctx)[0] for r in records}
    _name_resonance_by_spectrum(trials, tests_after[train.name])
    resid_after = {r.name: r.dcl - predict(current, r, start).total for r in records}
    report = {
        "version": 1,
        "baseline": {"records": {r.name: _scores(r, model, start) for r in records}},
        "augmented": {"records": {r.name: _scores(r, current, start) for r in records}},
        "effects": [t.to_dict() for t in trials],
        "unexplained": unexplained(tests_after[train.name], trials, accepted),
    }
    return Diagnosis(report, model, current, trials, tests_before, tests_after, resid_before,
                     resid_after, start, rounds)


def _name_resonance_by_spectrum(trials: list[Trial], tests: dict[str, TestResult]) -> None:
    """A mode the open-loop fit could not use is still named, with the spectrum's estimate."""
    peaks = [p for p in tests["spectrum"].data["peaks"] if p.kind == "resonance"]
    for t in trials:
        if t.name == "sensor_resonance" and not t.accepted and peaks:
            p = peaks[0]
            t.params = {"frequency_hz": p.frequency_hz, "damping_ratio": p.damping_ratio}
            t.evidence = (f"named by the residual spectrum only ({p.describe()}); the open-loop fit "
                          f"was not accepted: {t.detail}")


def _scores(rec: Record, model: HybridModel, start: int) -> dict[str, float]:
    out = predict(model, rec, start)
    return scores(rec.dcl[start:], out.total[start:])


def unexplained(tests: dict[str, TestResult], trials: list[Trial], accepted: list[Trial]) -> list[str]:
    """One plain line per residual feature that no accepted effect explains."""
    names = {t.name for t in accepted}
    rejected = {t.name: t for t in trials if not t.accepted}
    lines: list[str] = []
    spec = tests["spectrum"]
    locked = [p for p in spec.data["peaks"] if p.kind == "input_line"]
    if locked:
        freqs = ", ".join(f"{p.frequency_hz:.1f}" for p in sorted(locked, key=lambda q: q.frequency_hz))
        lines.append(f"narrow lines at burst harmonics ({freqs} Hz, up to +{max(p.prominence_db for p in locked):.0f} "
                     f"dB): input-locked ripple error of the convolution part, not a pickup")
    for p in spec.data["peaks"]:
        if p.kind == "line":
            lines.append(f"{p.describe()}: a pickup the model does not explain")
        elif p.kind == "resonance":
            tr = rejected.get("sensor_resonance")
            tail = (f"; sensor_resonance fitted to the deterministic part did not help on validation "
                    f"({tr.rmse_before:.5f} -> {tr.rmse_after:.5f}): the mode rings with noise an "
                    f"open-loop model cannot predict (an observer with this filter stage can)"
                    if tr else "")
            lines.append(f"{p.describe()}: looks like sensor_resonance at {p.frequency_hz:.1f} Hz, "
                         f"damping ratio {p.damping_ratio:.3f}{tail}")
        elif p.kind == "bump":
            lines.append(f"{p.describe()}: coloured aerodynamic noise (separated-flow buffeting near "
                         f"7 Hz is one), not a periodic disturbance")
    w = tests["whiteness"]
    if w.significant:
        lines.append(f"residual is not white ({w.detail})")
    labels = {
        "input_crosscorr": ("residual correlates with past Cmu_env", "delay"),
        "bv_u2_e": ("residual correlates with the squared input (Billings-Voon)", "output_nonlinearity"),
        "bv_u2_e2": ("squared residual correlates with the squared input (Billings-Voon)", None),
        "bv_y2_e": ("residual correlates with the squared model output (Billings-Voon)", "output_nonlinearity"),
        "level": ("residual depends on the Cmu level", "output_nonlinearity"),
        "direction": ("residual depends on the direction of change of Cmu", "hysteresis"),
        "slow_trend": ("slow trend in the residual", "zero_drift"),
        "gain_trend": ("the model's gain error drifts over the record", "actuator_fade"),
    }
    for key, (text, effect) in labels.items():
        t = tests[key]
        if not t.significant:
            continue
        hint = ""
        if effect and effect not in names and effect in rejected:
            hint = f" ({effect} was tried and not accepted: {rejected[effect].detail})"
        lines.append(f"{text}: {t.detail}{hint}")
    return lines
