"""The model's own misfit as a function of its input: fitted on the identification records,
predicted for any other input.

On the records it was identified on, the model's residual ε = ΔCL − ŷ is a systematic part,
which the input drives, plus noise. The systematic part is modelled linearly in parameters
(:func:`regressors`, every column a signal of the model itself on that input):

    m̂(k) = λ Φ(k) θ,   Φ = [1, ŷ_L, ŷ_H, LP₀.₂(ŷ_L) − ŷ_L, LP₁(ŷ_L) − ŷ_L, ŷ_L · Cμ_env / Cμ_max]

(ŷ_L the Wiener part, the quasi-steady lift; ŷ_H the burst part; LP_τ a first-order low-pass
of time constant τ s: a slow part too fast or too slow; the last column a level-dependent
gain, the map's curvature wrong). θ is the least-squares fit over all identification records,
each weighing alike (its rows scaled by 1/√nᵢ). How far θ carries to *another* input is
measured, not assumed: each record is predicted from θ fitted on the others (leave one record
out), and λ ∈ [0, 1] is the shrinkage that fits those predictions best,
λ = Σᵢ ⟨εᵢ, m̂ᵢ⁽⁻ⁱ⁾⟩/nᵢ / Σᵢ ‖m̂ᵢ⁽⁻ⁱ⁾‖²/nᵢ. A misfit that looks alike on every record type
keeps λ near 1; one that each record type has its own way leaves λ near 0, and the prediction
for a new input is then honestly close to nothing.

A later run of the *same kind* of input as one identification record (:mod:`.inputs`), but
not bit for bit (another length, a measured Cμ column), meets that record's own misfit function:
θ fitted on that record alone, λ measured on it by fitting one half and predicting the other.

What is left on each record, u = ε − m̂, is its noise (buffeting, balance, and whatever misfit
does not carry): its Welch PSD is kept per record. :func:`synthetic_residual` draws the residual
the model would have had on a new input at identification: m̂ + w, w Gaussian noise with the PSD
of the identification record whose input excites the model most alike (the same burst setting,
the nearest envelope bandwidth: :func:`.inputs.nearest_dynamics`; seeded by the input, so one
input always gives one print), and its power the mean square of u, offset included: the misfit
that does not carry is noise of unknown sign to a new input, not nothing. The noise is borrowed
from the nearest record, the misfit is not: it is predicted for the input, as far as the campaign
says it carries (λ).
"""

from __future__ import annotations

import hashlib
import math
from typing import Any

import numpy as np
import scipy  # its submodules load on first use (scipy's lazy loader): not on a live start's path

from rtlift.core.records import Record
from rtlift.model.hybrid import HybridModel
from rtlift.model.validation import predict_record

MISFIT_VERSION = 1
LOWPASS_S = (0.2, 1.0)
COLUMNS = ("offset", "low", "high", "lowpass_0.2s", "lowpass_1s", "low_x_level")


def _lowpass(x: np.ndarray, tau: float, fs: float) -> np.ndarray:
    a = math.exp(-1.0 / (tau * fs))
    return scipy.signal.lfilter([1.0 - a], [1.0, -a], x)


def regressors(model: HybridModel, rec: Record, cmu_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Φ (n × 6, module docstring) on ``rec`` and the model's residual ε there."""
    out = predict_record(model, rec)
    low, fs = out.low, rec.fs_hz
    cols = [np.ones_like(low), low, out.high, *(_lowpass(low, t, fs) - low for t in LOWPASS_S),
            low * rec.cmu_envelope / max(cmu_max, 1e-300)]
    return np.column_stack(cols), rec.dcl - out.total


def _weighted_fit(parts: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    X = np.vstack([P / math.sqrt(len(e)) for P, e in parts])
    y = np.concatenate([e / math.sqrt(len(e)) for _, e in parts])
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    return theta


def transfer(pairs: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """λ ∈ [0, 1]: the shrinkage of out-of-sample predictions m̂ᵢ that fits the residuals εᵢ
    best, each pair weighing alike: λ = Σᵢ ⟨εᵢ, m̂ᵢ⟩/nᵢ / Σᵢ ‖m̂ᵢ‖²/nᵢ (0 without predictions)."""
    num = sum(float(e @ m) / e.size for e, m in pairs)
    den = sum(float(m @ m) / e.size for e, m in pairs)
    return float(np.clip(num / den, 0.0, 1.0)) if den > 0 else 0.0


def fit_misfit(model: HybridModel, records: list[Record], start: int) -> dict[str, Any]:
    """The misfit model of the module docstring, as a plain dict for the model file: θ and λ
    over the campaign (leave one record out), and per record type its own θ and λ (``per_record``:
    fitted on one half of the record, predicting the other, both ways), for a later run of the
    same kind of input."""
    cmu_max = max(float(np.max(r.cmu_envelope)) for r in records)
    parts, kinds = [], []
    for rec in records:
        P, e = regressors(model, rec, cmu_max)
        parts.append((P[start:], e[start:]))
        kinds.append(rec.meta.get("experiment") or rec.name)
    theta = _weighted_fit(parts)
    lam = transfer([(e, P @ _weighted_fit(parts[:i] + parts[i + 1:])) for i, (P, e) in enumerate(parts)]) \
        if len(parts) >= 2 else 0.0
    per_record = {}
    for kind, (P, e) in zip(kinds, parts, strict=True):
        h = e.size // 2
        halves = [(P[:h], e[:h]), (P[h:], e[h:])]
        per_record[kind] = {"theta": _weighted_fit([(P, e)]).tolist(),
                            "transfer": transfer([(halves[1 - i][1], halves[1 - i][0] @ _weighted_fit([halves[i]]))
                                                  for i in range(2)])}
    fs = records[0].fs_hz
    noise = {}
    for (P, e), kind in zip(parts, kinds, strict=True):
        u = e - lam * (P @ theta)
        f, p = scipy.signal.welch(u - u.mean(), fs=fs, nperseg=min(u.size, 2048), window="hann")
        noise[kind] = {"f_hz": f.tolist(), "variance": float(np.mean(u**2)),
                       "log10": np.log10(np.maximum(p, 1e-300)).tolist()}
    return {"version": MISFIT_VERSION, "columns": list(COLUMNS), "theta": theta.tolist(), "transfer": lam,
            "cmu_max": cmu_max, "per_record": per_record, "noise": noise}


def predicted_misfit(mm: dict[str, Any], model: HybridModel, rec: Record, kind: str | None = None) -> np.ndarray:
    """m̂ = λ Φ θ on ``rec`` (module docstring): the campaign's θ and λ, or those of identification
    record type ``kind`` where ``rec``'s input is of that kind."""
    P, _ = regressors(model, rec, mm["cmu_max"])
    own = mm.get("per_record", {}).get(kind) if kind else None
    theta, lam = (own["theta"], own["transfer"]) if own else (mm["theta"], mm["transfer"])
    return lam * (P @ np.asarray(theta))


def input_seed(rec: Record) -> int:
    """A seed from the record's input (Cμ envelope): one input, one synthetic print."""
    h = hashlib.sha256(np.ascontiguousarray(rec.cmu_envelope, dtype=np.float64).tobytes())
    return int.from_bytes(h.digest()[:8], "little")


def coloured_noise(f_hz: np.ndarray, log10_psd: np.ndarray, variance: float, n: int, fs: float,
                   rng: np.random.Generator) -> np.ndarray:
    """Zero-mean Gaussian noise of n samples and power ``variance`` whose one-sided PSD is 10**log10_psd
    (a Welch estimate, interpolated) above the Welch grid's first bin f₁; the power the Welch
    segments' means took (variance − ∫P df, what lies below f₁) is spread flat over 0 < f < f₁.
    Synthesised in the frequency domain: X(f) = √P(f) (a + jb), a, b ~ N(0, 1), inverse real FFT."""
    f = np.fft.rfftfreq(n, 1.0 / fs)
    p = 10.0 ** np.interp(f, f_hz, log10_psd)
    df, f1 = float(f[1] - f[0]), float(f_hz[1])
    low = (f > 0) & (f < f1)
    welch_var = float(np.sum(10.0 ** np.asarray(log10_psd)) * (f_hz[1] - f_hz[0]))
    if low.any():
        p[low] = max(variance - welch_var, 0.0) / (low.sum() * df)
    spec = np.sqrt(p) * (rng.normal(size=f.size) + 1j * rng.normal(size=f.size))
    spec[0] = 0.0
    w = np.fft.irfft(spec, n)
    target = max(variance, welch_var) if low.any() else welch_var
    return w * math.sqrt(target / max(float(np.var(w)), 1e-300))


def synthetic_residual(mm: dict[str, Any], model: HybridModel, rec: Record, noise_of: str) -> np.ndarray:
    """The residual the model would have had on ``rec``'s input at identification: m̂ + w, w
    Gaussian noise with the PSD of what m̂ left on identification record ``noise_of`` (module
    docstring)."""
    psd = mm["noise"][noise_of]
    w = coloured_noise(np.asarray(psd["f_hz"]), np.asarray(psd["log10"]), psd["variance"], len(rec), rec.fs_hz,
                       np.random.default_rng(input_seed(rec)))
    return predicted_misfit(mm, model, rec) + w
