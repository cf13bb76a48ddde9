"""The residual fingerprint: what the identified model's residual looked like on its own campaign.

A model is never perfect: on the records it was identified on, its residual ε = ΔCL − ŷ is
coloured, correlates with the input a little, has a spectrum with input-locked lines. A
diagnosis that tests a later record's residual against *zero* reports that misfit as new
physical events. ``rtlift identify`` therefore stores, per record type of its campaign
(held-out part included), the statistics the residual tests compute (:mod:`.residual`):

- level: RMSE, mean and standard deviation of ε, and the mean squared error over 1 s blocks
  with its standard error (the model's error level on that kind of record);
- spectrum: Welch PSD (log10) and its number of averaged segments, for confidence bands;
- regressions with cluster-robust standard errors: offset drift (``slow_trend``), gain drift
  (``gain_trend``), direction dependence (``direction``), mean ε per Cμ level (``level``);
- the lag that best aligns model and measurement, whiteness (Ljung–Box Q), input and
  Billings–Voon correlations;
- ``input``: each record's input descriptor (:mod:`.inputs`: burst period, on-time, envelope
  frequency and bandwidth, level range), by which a later record finds its reference from its
  input, never its name (:func:`reference`);
- ``misfit``: the model's own misfit as a function of its input (:mod:`.misfit`), fitted over all
  identification records: where a later record's input matches none of them, its reference is
  the print of the residual the model would have had on that input (:func:`predicted_print`);
- ``repeats``: for each identification record of at most ``REPEAT_MAX_SAMPLES`` samples, its
  measured ΔCL and a digest of its input (:func:`input_digest`). A later record that repeats
  the experiment (the same Cμ sequence) meets the model's own misfit on it sample for sample:
  m(k) = ΔCL_id(k) − ŷ(k), ŷ the model's output for that input. :func:`repeat_misfit` returns it,
  and the diagnosis fits its candidates to ΔCL − m, what changed since identification (and
  twice the measurement noise), not to a misfit the model already had (on the independent
  plant, the model's misfit on its training sine is 0.008 RMS against a hysteresis imprint of
  0.016, and a direction-dependent gain fitted to both took the misfit for part of the effect).

:func:`departure` functions compare a new record's statistics with these. Two independent
estimates b₁ ± s₁ and b₂ ± s₂ of one coefficient differ significantly when
z = |b₁ − b₂| / √(s₁² + s₂²) is large. Two Welch PSDs P̂₁, P̂₂ averaged over K₁, K₂ half-
overlapping Hann segments have var(ln P̂ᵢ) ≈ 2/νᵢ with νᵢ ≈ 1.8 Kᵢ degrees of freedom
(Welch 1967; the overlap costs ≈ 10 %); over B bins of a band (adjacent Hann bins are
correlated: B/2 independent) z = mean(ln P̂₁/P̂₂) / √((2/ν₁ + 2/ν₂) / (B/2)).
For the error level, z = ln(MSE₁/MSE₂) / √((s₁/MSE₁)² + (s₂/MSE₂)²) with sᵢ the standard
errors of the block means of ε². What departs from the fingerprint is an *effect*; what was
already there is *structure*.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtlift.core.records import Record
from rtlift.model.hybrid import HybridModel
from rtlift.model.validation import predict_record
from rtlift.residual.inputs import best_match, describe, input_descriptor, nearest_dynamics
from rtlift.residual.misfit import fit_misfit, predicted_misfit, synthetic_residual
from rtlift.residual.stats import TestResult, run_all

FINGERPRINT_VERSION = 2
Z_DEPART = 4.0                 # |z| beyond which a statistic has left the fingerprint
FINGERPRINT_START_S = 2.0      # residual tests leave out each record's first seconds (start from rest)
REPEAT_MAX_SAMPLES = 20_000    # identification records kept for repeats (a long static sweep is not)


def record_type(rec: Record) -> str:
    """The experiment a record is of (``# experiment:`` metadata, else the file's stem)."""
    return rec.meta.get("experiment") or rec.name


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


def input_lines_hz(rec: Record) -> tuple[float, ...]:
    """Frequencies locked to the input: burst-rate harmonics and envelope harmonics 1 … 6."""
    fs, burst, env = rec.fs_hz, burst_rate_hz(rec), envelope_line_hz(rec)
    lines = tuple(burst * k for k in range(1, int(0.5 * fs / burst) + 1)) if burst > 0 else ()
    return lines + (tuple(env * k for k in range(1, 7)) if env > 0 else ())


def record_tests(model: HybridModel, rec: Record, start: int) -> tuple[dict[str, TestResult], np.ndarray]:
    """Every residual test on ε = ΔCL − ŷ from sample ``start`` on; and ε over the record."""
    out = predict_record(model, rec)
    e = rec.dcl - out.total
    s = start
    tests = run_all(rec.dcl[s:], e[s:], out.total[s:], out.low[s:], rec.cmu_envelope[s:], rec.cmu[s:],
                    rec.fs_hz, input_lines_hz(rec), envelope_line_hz(rec))
    return tests, e


def _coef(t: TestResult) -> dict[str, float]:
    return {"coef": float(t.data["coef"]), "se": float(t.data["se"])}


def block_mse(e: np.ndarray, block: int) -> dict[str, float]:
    """Mean of ε² over ``block``-sample blocks and its standard error."""
    nb = max(2, e.size // block)
    m = np.array([np.mean(x**2) for x in np.array_split(e, nb)])
    return {"mean": float(m.mean()), "se": float(m.std(ddof=1) / math.sqrt(nb))}


def summarize(tests: dict[str, TestResult], e: np.ndarray, fs: float) -> dict[str, Any]:
    """The fingerprint entry of one record (``e`` the scored residual)."""
    spec = tests["spectrum"].data
    level = tests["level"].data
    return {
        "n": int(e.size), "rmse": float(np.sqrt(np.mean(e**2))), "mean": float(np.mean(e)),
        "std": float(np.std(e)), "mse_blocks": block_mse(e, int(fs)),
        "psd": {"f_hz": np.asarray(spec["f"]).tolist(),
                "log10": np.log10(np.maximum(spec["psd"], 1e-300)).tolist(),
                "segments": int(spec["segments"])},
        "lag_samples": int(tests["lag"].data["lag"]),
        "slow_trend": _coef(tests["slow_trend"]), "gain_trend": _coef(tests["gain_trend"]),
        "direction": _coef(tests["direction"]),
        "level": {"cmu": np.asarray(level["cmu"]).tolist(), "mean": np.asarray(level["mean"]).tolist(),
                  "se": np.asarray(level["se"]).tolist()},
        "whiteness_q": float(tests["whiteness"].statistic),
        "correlations": {k: float(tests[k].statistic) for k in ("input_crosscorr", "bv_u2_e", "bv_u2_e2",
                                                                "bv_y2_e")},
    }


def fingerprint(model: HybridModel, records: list[Record], start: int) -> dict[str, Any]:
    """The model's residual fingerprint on its identification records, keyed by record type."""
    per = {}
    for rec in records:
        if len(rec) - start < 4 * int(rec.fs_hz):
            continue
        tests, e = record_tests(model, rec, start)
        per[record_type(rec)] = {**summarize(tests, e[start:], rec.fs_hz), "input": input_descriptor(rec)}
    repeats = [{"type": record_type(rec), "input_sha256": input_digest(rec), "dcl": rec.dcl.tolist()}
               for rec in records if len(rec) <= REPEAT_MAX_SAMPLES]
    usable = [rec for rec in records if len(rec) - start >= 4 * int(rec.fs_hz)]
    return {"version": FINGERPRINT_VERSION, "start": start, "records": per, "repeats": repeats,
            "misfit": fit_misfit(model, usable, start) if usable else None}


def input_digest(rec: Record) -> str:
    """SHA-256 of the record's sample rate, Cμ and envelope (float64 bytes): two runs of one
    experiment read from their files have the same digest."""
    h = hashlib.sha256(np.float64(rec.fs_hz).tobytes())
    for col in (rec.cmu, rec.cmu_envelope):
        h.update(np.ascontiguousarray(col, dtype=np.float64).tobytes())
    return h.hexdigest()


def repeat_misfit(fp: dict[str, Any] | None, model: HybridModel, rec: Record) -> tuple[np.ndarray | None, str]:
    """The model's misfit on the identification run of the experiment ``rec`` repeats, m(k) =
    ΔCL_id(k) − ŷ(k) (module docstring), or None where ``rec`` repeats none; and a line saying so."""
    digest = input_digest(rec)
    for r in (fp or {}).get("repeats", []):
        if r.get("input_sha256") == digest and len(r.get("dcl", ())) == len(rec):
            m = np.asarray(r["dcl"], dtype=float) - predict_record(model, rec).total
            return m, (f"the training record repeats the identification's {r['type']} experiment (same input): "
                       "effects are fitted to what changed since, the model's own misfit on that run taken out")
    return None, "the training record repeats no identification experiment: effects are fitted to its residual"


@dataclass(frozen=True)
class Departure:
    """How far a statistic of a new record stands from the fingerprint."""

    z: float
    departs: bool
    text: str


def coef_departure(new: TestResult, fp: dict[str, Any], what: str, unit: str = "") -> Departure:
    """z of a regression coefficient (slow_trend, gain_trend, direction: ``new.name``) against
    the record print ``fp``'s."""
    b1, s1 = float(new.data["coef"]), float(new.data["se"])
    b2, s2 = fp[new.name]["coef"], fp[new.name]["se"]
    z = (b1 - b2) / math.sqrt(s1 * s1 + s2 * s2) if s1 > 0 or s2 > 0 else 0.0
    return Departure(z, abs(z) >= Z_DEPART,
                     f"{what} {b1:+.3g}{unit} against {b2:+.3g}{unit} at identification (z = {z:+.1f})")


def psd_departure(new: TestResult, fp: dict[str, Any], bands_hz: list[tuple[float, float]],
                  what: str) -> Departure:
    """z of the mean log-PSD ratio new/print over the bins of ``bands_hz`` (module docstring).
    Positive z: the new residual has more power there than the model's own residual had."""
    f = np.asarray(new.data["f"])
    p_new = np.maximum(np.asarray(new.data["psd"]), 1e-300)
    p_fp = 10.0 ** np.interp(f, fp["psd"]["f_hz"], fp["psd"]["log10"])
    sel = np.zeros(f.size, dtype=bool)
    for lo, hi in bands_hz:
        sel |= (f >= lo) & (f <= hi)
    if not sel.any():               # a band narrower than a bin: its nearest bin
        for lo, hi in bands_hz:
            sel[int(np.argmin(np.abs(f - 0.5 * (lo + hi))))] = True
    ratio = np.log(p_new[sel] / p_fp[sel])
    nu1, nu2 = 1.8 * new.data["segments"], 1.8 * fp["psd"]["segments"]
    b = max(1.0, sel.sum() / 2.0)
    z = float(np.mean(ratio) / math.sqrt((2.0 / nu1 + 2.0 / nu2) / b))
    db = float(10.0 * np.mean(ratio) / math.log(10.0))
    return Departure(z, z >= Z_DEPART, f"{what}: {db:+.1f} dB against the model's own residual (z = {z:+.1f})")


def lag_departure(new: TestResult, fp: dict[str, Any], fitted_samples: int) -> Departure:
    """A delay departs when it moves the best alignment by two samples or more from the print's
    (one sample is within the lag search's own spread) and the shift lowers the RMSE clearly."""
    d0 = int(fp["lag_samples"])
    rmse = np.asarray(new.data["rmse"])
    gain = 1.0 - float(rmse[min(fitted_samples + d0, rmse.size - 1)]) / float(rmse[min(d0, rmse.size - 1)]) \
        if fitted_samples + d0 >= 0 else 0.0
    moved = abs(fitted_samples) >= 2
    return Departure(float(fitted_samples), moved and gain > 0.02,
                     f"best alignment moved by {fitted_samples} samples from identification's "
                     f"{d0} (RMSE {100 * gain:+.1f} % at the new lag)")


def level_departure(new: TestResult, fp: dict[str, Any]) -> Departure:
    """Largest z of the mean residual per Cμ level against the print's (levels interpolated)."""
    c = np.asarray(new.data["cmu"])
    m1, s1 = np.asarray(new.data["mean"]), np.asarray(new.data["se"])
    m2 = np.interp(c, fp["level"]["cmu"], fp["level"]["mean"])
    s2 = np.interp(c, fp["level"]["cmu"], fp["level"]["se"])
    z = (m1 - m2) / np.sqrt(s1**2 + s2**2)
    k = int(np.argmax(np.abs(z)))
    return Departure(float(z[k]), abs(z[k]) >= Z_DEPART,
                     f"mean residual at Cmu ~ {c[k]:.4f} is {m1[k]:+.4f} against {m2[k]:+.4f} at "
                     f"identification (z = {z[k]:+.1f})")


def error_departure(e: np.ndarray, fp: dict[str, Any], fs: float) -> Departure:
    """z of the error level (ln MSE over 1 s blocks) of a residual ``e`` (scored part) against
    the print's: positive when the model does worse than on its own campaign."""
    new = block_mse(e, int(fs))
    old = fp["mse_blocks"]
    z = math.log(new["mean"] / old["mean"]) / math.hypot(new["se"] / new["mean"], old["se"] / old["mean"])
    return Departure(z, z >= Z_DEPART, f"error level {math.sqrt(new['mean']):.4g} against "
                                       f"{math.sqrt(old['mean']):.4g} at identification (z = {z:+.1f})")


def print_for(fp: dict[str, Any] | None, rec: Record) -> tuple[dict[str, Any] | None, str]:
    """The rule for a model file without input descriptors (fingerprint version 1; :func:`reference`
    finds the entry from the input otherwise): the entry of ``rec``'s record type by name, else
    the entry with the most samples (said in the note); None if the model has no fingerprint."""
    if not fp or not fp.get("records"):
        return None, "the model file has no residual fingerprint (identified before rtlift 0.2): " \
                     "every accepted entry is reported as kind 'effect' against a white residual"
    recs = fp["records"]
    kind = record_type(rec)
    if kind in recs:
        return recs[kind], f"compared with the model's residual on its own {kind} record"
    other = max(recs, key=lambda k: recs[k]["n"])
    return recs[other], (f"no {kind} record at identification: compared with the model's residual "
                         f"on {other}")


@dataclass(frozen=True)
class PrintReference:
    """What a record is compared with, and why: ``source`` is ``repeat`` (its input is an
    identification record's, bit for bit), ``input`` (its input descriptor matches an
    identification record's, :mod:`.inputs`), ``predicted`` (it matches none: the print of the
    residual the model would have had on its input, :func:`predicted_print`), or, for a model
    file without input descriptors, ``name`` / ``largest`` (today's rule, :func:`print_for`), or
    ``none`` (no fingerprint)."""

    entry: dict[str, Any] | None
    source: str
    key: str | None
    nearest: str | None
    distance: float | None
    text: str

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "entry": self.key, "nearest": self.nearest,
                "distance": None if self.distance is None or not math.isfinite(self.distance)
                else round(self.distance, 3), "text": self.text}


def predicted_print(fp: dict[str, Any], model: HybridModel, rec: Record, start: int,
                    nearest: str) -> dict[str, Any]:
    """The fingerprint entry of the residual the model would have had on ``rec``'s input at
    identification (:func:`.misfit.synthetic_residual`: its misfit predicted, the noise of
    identification record ``nearest``, :func:`.inputs.nearest_dynamics`), summarised as every other
    entry is."""
    out = predict_record(model, rec)
    e = synthetic_residual(fp["misfit"], model, rec, nearest)
    s = start
    tests = run_all(out.total[s:] + e[s:], e[s:], out.total[s:], out.low[s:], rec.cmu_envelope[s:], rec.cmu[s:],
                    rec.fs_hz, input_lines_hz(rec), envelope_line_hz(rec))
    return {**summarize(tests, e[s:], rec.fs_hz), "input": input_descriptor(rec)}


def reference(fp: dict[str, Any] | None, model: HybridModel, rec: Record, start: int) -> PrintReference:
    """The fingerprint entry to compare ``rec`` with, found from its input (:class:`PrintReference`)."""
    recs = (fp or {}).get("records") or {}
    if not recs:
        entry, note = print_for(fp, rec)
        return PrintReference(entry, "none", None, None, None, note)
    if not all("input" in r for r in recs.values()):           # a model file from before descriptors
        entry, note = print_for(fp, rec)
        key = record_type(rec) if record_type(rec) in recs else max(recs, key=lambda k: recs[k]["n"])
        return PrintReference(entry, "name" if key == record_type(rec) else "largest", key, None, None, note)
    digest = input_digest(rec)
    for r in fp.get("repeats", []):
        if r.get("input_sha256") == digest and r.get("type") in recs:
            return PrintReference(recs[r["type"]], "repeat", r["type"], r["type"], 0.0,
                             f"its input repeats the identification's {r['type']} record bit for bit: compared "
                             f"with the model's residual there")
    d = input_descriptor(rec)
    key, dist, worst = best_match({k: v["input"] for k, v in recs.items()}, d)
    if dist <= 1.0:
        return PrintReference(recs[key], "input", key, key, dist,
                         f"its input ({describe(d)}) is of the identification's {key} kind (distance "
                         f"{dist:.2f} <= 1): compared with the model's residual there")
    away = f"its input ({describe(d)}) matches no identification record (nearest {key}, distance {dist:.1f}, " \
           f"by {worst})"
    noise = (fp.get("misfit") or {}).get("noise", {})
    like = nearest_dynamics({k: v["input"] for k, v in recs.items() if k in noise}, d)
    if like is not None:
        lam = fp["misfit"]["transfer"]
        return PrintReference(predicted_print(fp, model, rec, start, like), "predicted", None, key, dist,
                         f"{away}: compared with the residual the model is predicted to have on this input "
                         f"(its misfit carried over from the campaign at lambda = {lam:.2f}, the noise of "
                         f"{like}, the identification input of the same burst setting and nearest envelope "
                         f"bandwidth)")
    return PrintReference(recs[key], "nearest", key, key, dist, f"{away}: compared with the nearest")


def change_misfit(fp: dict[str, Any] | None, model: HybridModel, rec: Record,
                  ref: PrintReference) -> tuple[np.ndarray | None, str]:
    """The model's own misfit m on ``rec``'s input, which the map-shaped effects are fitted
    around (ΔCL − m: what changed since identification), and a line saying where it comes from:
    the identification run itself where ``rec`` repeats it (:func:`repeat_misfit`, the best
    case); else, where its input is of an identification record's kind, that record's own misfit
    function (λ of that record > 0); else the misfit predicted for the input
    (:func:`.misfit.predicted_misfit`) where the campaign says it carries to other inputs (λ > 0);
    else None (fitted to the residual)."""
    m, note = repeat_misfit(fp, model, rec)
    if m is not None:
        return m, note
    mm = (fp or {}).get("misfit")
    if not mm:
        return None, note
    own = mm.get("per_record", {}).get(ref.key) if ref.source == "input" else None
    if own and own["transfer"] > 0.0:
        return predicted_misfit(mm, model, rec, ref.key), (
            f"the training record repeats no identification run bit for bit but its input is of the "
            f"identification's {ref.key} kind: effects that replace the map are fitted to what changed, the "
            f"model's own misfit on that kind of input (fitted there, lambda = {own['transfer']:.2f}) taken out")
    lam = mm["transfer"]
    if lam <= 0.0:
        return None, (f"{note}; the model's own misfit does not carry across the campaign's record types "
                      f"(lambda = {lam:.2f}, leave-one-record-out), so none is predicted for this input")
    return predicted_misfit(mm, model, rec), (
        f"the training record repeats no identification experiment: effects that replace the map are fitted "
        f"to what changed, the model's own misfit predicted for this input (lambda = {lam:.2f}) taken out")
