"""Residual tests: what a residual ε = measured − model says about what the model misses.

Each test returns a :class:`TestResult` (name, statistic, threshold, verdict, one-line
detail, and the numbers behind it for the report's figures). Correlation bounds are the
large-sample 99 % band ±2.576/√N of an uncorrelated pair; regressions use cluster-robust
standard errors over contiguous one-second blocks, because a bench residual is coloured
(separated-flow buffeting) and i.i.d. standard errors would make everything "significant".

- :func:`whiteness` — autocorrelation r_εε(τ), τ = 1 … L, and Ljung–Box Q (Ljung 1999, §16.6);
- :func:`input_crosscorr` — r_uε(τ), τ = 0 … L, ε against past input (missed dynamics);
- :func:`higher_order` — Billings & Voon (1986): r_{u²′ε}(τ), r_{u²′ε²}(τ) and r_{ŷ²′ε}(τ),
  with x′ = x − mean(x): a missed nonlinearity correlates ε with squared signals while the
  linear tests barely move;
- :func:`spectrum` — Welch PSD and its peaks, classified as narrow *lines* (pickup), sharp
  *resonance-like* peaks (a mode ringing with the noise) or broad *bumps* (buffeting);
- :func:`level_dependence`, :func:`direction_dependence` — ε against Cμ level, and a gain
  that differs between rising and falling Cμ (ε ≈ m ŷ_L·[falling]);
- :func:`slow_trend` — ε = a + b t + c ŷ + d ŷ t: an offset (b) and a gain (d) that drift;
- :func:`lag_search` — the shift of the model output that best matches the measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy  # its submodules load on first use (scipy's lazy loader): not on a live start's path

Z99 = 2.576


@dataclass
class TestResult:
    name: str
    statistic: float
    threshold: float
    significant: bool
    detail: str
    data: dict[str, Any] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        return "significant" if self.significant else "not significant"

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "statistic": float(self.statistic),
                "threshold": float(self.threshold), "verdict": self.verdict, "detail": self.detail}


def _xcorr(a: np.ndarray, b: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """r_ab(τ) = Σ a′(k) b′(k−τ) / (N σ_a σ_b) for τ ≥ 0 (b leads: b is the past)."""
    a = a - a.mean()
    b = b - b.mean()
    n = a.size
    den = n * a.std() * b.std()
    if den == 0:
        return np.zeros(lags.size)
    return np.array([np.dot(a[t:], b[:n - t]) / den for t in lags])


def whiteness(e: np.ndarray, max_lag: int = 40) -> TestResult:
    lags = np.arange(1, max_lag + 1)
    r = _xcorr(e, e, lags)
    n = e.size
    q = n * (n + 2) * np.sum(r**2 / (n - lags))
    p = float(scipy.stats.chi2.sf(q, max_lag))
    bound = Z99 / np.sqrt(n)
    out = float(np.mean(np.abs(r) > bound))
    return TestResult("whiteness", q, float(scipy.stats.chi2.isf(0.01, max_lag)), p < 0.01,
                      f"Ljung-Box Q = {q:.0f} over {max_lag} lags (p = {p:.2g}); "
                      f"{100 * out:.0f} % of r_ee(tau) outside +-{bound:.3f}; r_ee(1) = {r[0]:.2f}",
                      {"lags": lags, "r": r, "bound": bound})


def input_crosscorr(e: np.ndarray, u: np.ndarray, max_lag: int = 80, name: str = "input_crosscorr",
                    label: str = "Cmu_env") -> TestResult:
    lags = np.arange(0, max_lag + 1)
    r = _xcorr(e, u, lags)
    bound = Z99 / np.sqrt(e.size)
    k = int(np.argmax(np.abs(r)))
    stat = float(np.abs(r[k]))
    return TestResult(name, stat, bound, stat > bound,
                      f"max |r(e, {label}(k-tau))| = {stat:.3f} at tau = {lags[k]} samples "
                      f"(bound {bound:.3f}); {100 * np.mean(np.abs(r) > bound):.0f} % of lags outside",
                      {"lags": lags, "r": r, "bound": bound})


def higher_order(e: np.ndarray, u: np.ndarray, yhat: np.ndarray, max_lag: int = 40) -> list[TestResult]:
    """Billings–Voon correlation tests against squared input and squared model output."""
    lags = np.arange(0, max_lag + 1)
    bound = Z99 / np.sqrt(e.size)
    u2 = u**2 - np.mean(u**2)
    y2 = yhat**2 - np.mean(yhat**2)
    e2 = e**2 - np.mean(e**2)
    out = []
    for name, a, b, label in (("bv_u2_e", e, u2, "r(u2', e)"), ("bv_u2_e2", e2, u2, "r(u2', e2')"),
                              ("bv_y2_e", e, y2, "r(yhat2', e)")):
        r = _xcorr(a, b, lags)
        k = int(np.argmax(np.abs(r)))
        stat = float(np.abs(r[k]))
        out.append(TestResult(name, stat, bound, stat > bound,
                              f"max |{label}| = {stat:.3f} at tau = {lags[k]} (bound {bound:.3f}); "
                              f"{100 * np.mean(np.abs(r) > bound):.0f} % of lags outside",
                              {"lags": lags, "r": r, "bound": bound}))
    return out


@dataclass
class Peak:
    frequency_hz: float
    prominence_db: float
    width_hz: float
    kind: str                      # "line", "resonance" or "bump"
    damping_ratio: float = float("nan")

    def describe(self) -> str:
        if self.kind in ("line", "input_line"):
            return f"narrow line at {self.frequency_hz:.2f} Hz (+{self.prominence_db:.0f} dB)"
        if self.kind == "resonance":
            return (f"sharp peak at {self.frequency_hz:.1f} Hz, half-power width {self.width_hz:.2f} Hz "
                    f"(zeta ~ {self.damping_ratio:.3f}, +{self.prominence_db:.0f} dB)")
        return (f"broad bump at {self.frequency_hz:.1f} Hz, width {self.width_hz:.1f} Hz "
                f"(Q ~ {self.frequency_hz / max(self.width_hz, 1e-9):.1f}, +{self.prominence_db:.0f} dB)")


def welch_psd(e: np.ndarray, fs: float, seconds: float = 5.12) -> tuple[np.ndarray, np.ndarray]:
    nper = int(min(e.size, round(seconds * fs), max(256, e.size // 8)))    # ≥ 8 segments averaged
    return scipy.signal.welch(e - e.mean(), fs=fs, nperseg=nper, window="hann", detrend="constant")


def welch_segments(n: int, fs: float, seconds: float = 5.12) -> int:
    """Number of half-overlapping segments :func:`welch_psd` averages for n samples."""
    nper = int(min(n, round(seconds * fs), max(256, n // 8)))
    return max(1, (n - nper) // (nper // 2) + 1)


def _half_width(p: np.ndarray, k: int, level: float, df: float) -> float:
    """Width (Hz) of the peak at bin k where p falls below ``level``, linearly interpolated."""
    def side(step: int) -> float:
        j = k
        while 0 <= j + step < p.size and p[j + step] > level:
            j += step
        if not 0 <= j + step < p.size:
            return (abs(j - k) + 0.5) * df
        frac = (p[j] - level) / max(p[j] - p[j + step], 1e-300)
        return (abs(j - k) + frac) * df
    return side(-1) + side(1)


def _fit_resonance(f: np.ndarray, p: np.ndarray, f0: float, zeta0: float, floor: float) -> tuple[float, float]:
    """(f₀, ζ) of c |H(f)|² + b fitted to the PSD (log domain) within [f₀/2, 2f₀]."""
    sel = (f > 0.5 * f0) & (f < min(2.0 * f0, f[-1]))
    ff, pp = f[sel], p[sel]

    def model(theta: np.ndarray) -> np.ndarray:
        fr, z, lc, lb = theta
        r = ff / fr
        h2 = 1.0 / ((1 - r**2) ** 2 + (2 * z * r) ** 2)
        return np.log(np.exp(lc) * h2 + np.exp(lb))

    theta0 = np.array([f0, zeta0, np.log(max(floor, 1e-30)), np.log(max(floor, 1e-30))])
    try:
        res = scipy.optimize.least_squares(lambda th: model(th) - np.log(pp), theta0,
                                     bounds=([0.8 * f0, 0.003, -80, -80], [1.2 * f0, 1.0, 10, 10]))
        return float(res.x[0]), float(res.x[1])
    except ValueError:
        return f0, zeta0


def _broad_resonance(f: np.ndarray, bg: np.ndarray, fs: float) -> Peak | None:
    """A well-damped mode shows as a hump of the line-free background PSD, not as a peak:
    fit bg ≈ c|H(f; f₀, ζ)|² + b + b₂(10/f)² (relative least squares, all ≥ 0; the last term
    is the buffeting bump's skirt) over 10 Hz … 0.475 fs on a (f₀, ζ ≤ 0.25) grid; a hump ≥ 3 dB
    over the floor that halves the misfit of the floor alone counts."""
    sel = (f >= 10.0) & (f <= 0.475 * fs)
    ff, pp = f[sel], bg[sel]
    if ff.size < 20:
        return None
    w = 1.0 / pp
    tail = (10.0 / ff) ** 2                      # the buffeting bump's skirt falls as 1/f²
    base = np.column_stack([np.ones_like(ff), tail]) * w[:, None]
    flat = float(scipy.optimize.nnls(base, pp * w)[1] ** 2)
    best = None
    for f0 in np.geomspace(12.0, 0.46 * fs, 160):
        for zeta in (0.02, 0.03, 0.05, 0.07, 0.1, 0.13, 0.17, 0.21, 0.25):
            r = ff / f0
            h2 = 1.0 / ((1 - r**2) ** 2 + (2 * zeta * r) ** 2)
            X = np.column_stack([h2, np.ones_like(h2), tail]) * w[:, None]
            coef, res = scipy.optimize.nnls(X, pp * w)
            if best is None or res**2 < best[0]:
                best = (res**2, f0, zeta, coef)
    sse, f0, zeta, (c, b, _) = best
    excess = c / (4 * zeta**2 * (1 - zeta**2)) / max(b, 1e-300)
    if b <= 0 or excess < 1.0 or sse > 0.5 * flat:
        return None
    return Peak(float(f0), float(10 * np.log10(1 + excess)), float(2 * zeta * f0), "resonance", float(zeta))


def spectrum(e: np.ndarray, fs: float, exclude_hz: tuple[float, ...] = (), min_hz: float = 0.8) -> TestResult:
    """Welch PSD (5.12 s Hann segments) and its peaks against a running-median background.

    A *line* rises ≥ 10 dB over the background and is no wider than the window's main lobe
    (half-power width ≤ 2.5 bins): a sinusoid. A *resonance* rises ≥ 6 dB with
    Q = f/width ≥ 3: a lightly damped mode ringing with the noise (ζ ≈ width / 2f, refined by a
    fit of c|H|² + b). Anything broader is a *bump* (the ≈ 7 Hz separated-flow buffeting is
    one) and is never called a line. Peaks within three bins of ``exclude_hz`` (harmonics of the
    burst rate: input-locked ripple error, not pickup) are reported as ``input_line``.
    """
    f, p = welch_psd(e, fs)
    df = f[1] - f[0]
    logp = np.log10(np.maximum(p, 1e-300))
    bg = 10 ** scipy.ndimage.median_filter(logp, size=max(9, int(round(4.0 / df)) | 1), mode="nearest")
    prom = 10 * np.log10(p / bg)
    cand, _ = scipy.signal.find_peaks(prom, height=6.0, distance=4)
    peaks: list[Peak] = []
    for k in sorted(cand, key=lambda j: -prom[j]):
        if f[k] < min_hz or any(abs(f[k] - q.frequency_hz) <= 3.0 * df for q in peaks):
            continue
        width = _half_width(p, k, bg[k] + 0.5 * (p[k] - bg[k]), df)
        near_excluded = any(abs(f[k] - x) <= (3.0 if x > 2.0 else 1.0) * df for x in exclude_hz)
        if near_excluded:
            if prom[k] >= 10.0:
                peaks.append(Peak(float(f[k]), float(prom[k]), float(width), "input_line"))
        elif width <= 2.5 * df and prom[k] >= 10.0:
            # a line: refine its frequency by the parabola through the log-PSD of three bins
            a, b, c = logp[k - 1], logp[k], logp[min(k + 1, p.size - 1)]
            den = a - 2 * b + c
            shift = 0.5 * (a - c) / den if den != 0 and 0 < k < p.size - 1 else 0.0
            peaks.append(Peak(float(f[k] + shift * df), float(prom[k]), float(width), "line"))
        elif f[k] / max(width, 1e-12) >= 3.0 and prom[k] >= 10.0 and f[k] >= 5.0:
            f0, z = _fit_resonance(f, p, float(f[k]), width / (2 * f[k]), float(bg[k]))
            kind = "resonance" if z <= 0.2 else "bump"
            peaks.append(Peak(f0, float(prom[k]), float(width), kind, z))
        elif width > 2.5 * df:
            peaks.append(Peak(float(f[k]), float(prom[k]), float(width), "bump"))
    if not any(q.kind == "resonance" for q in peaks):
        broad = _broad_resonance(f, bg, fs)
        if broad is not None:
            peaks.append(broad)
    peaks.sort(key=lambda q: -q.prominence_db)
    lines = [q for q in peaks if q.kind == "line"]
    res = [q for q in peaks if q.kind == "resonance"]
    detail = "; ".join(q.describe() for q in peaks[:4]) or "no peak 6 dB over the background"
    return TestResult("spectrum", float(max((q.prominence_db for q in lines + res), default=0.0)), 10.0,
                      bool(lines or res), detail, {"f": f, "psd": p, "background": bg, "peaks": peaks,
                                                   "segments": welch_segments(e.size, fs)})


def cluster_ols(X: np.ndarray, e: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """OLS β of e on X and cluster-robust standard errors over contiguous blocks."""
    beta, *_ = np.linalg.lstsq(X, e, rcond=None)
    u = e - X @ beta
    xtx_inv = np.linalg.pinv(X.T @ X)
    nb = max(1, X.shape[0] // block)
    meat = np.zeros((X.shape[1], X.shape[1]))
    for i in range(nb):
        sl = slice(i * block, (i + 1) * block if i < nb - 1 else X.shape[0])
        g = X[sl].T @ u[sl]
        meat += np.outer(g, g)
    cov = xtx_inv @ meat @ xtx_inv * nb / max(nb - 1, 1)
    return beta, np.sqrt(np.maximum(np.diag(cov), 1e-300))


def slow_trend(e: np.ndarray, yhat: np.ndarray, fs: float, periodic_hz: tuple[float, ...] = ()) -> list[TestResult]:
    """One regression ε = a + b t + c ŷ + d ŷ t (+ nuisance; t in s, cluster-robust over 1 s
    blocks): b is an offset that drifts (``slow_trend``), d a gain that drifts (``gain_trend``;
    a fade moves the mean lift too, so the two must be told apart in one fit). With a periodic
    input the model's own misfit is periodic too: sines and cosines at ``periodic_hz`` (the
    envelope's harmonics) take it out as nuisance, which a trend (or a trend times ŷ) is not."""
    t = np.arange(e.size) / fs
    tc = t - t.mean()              # ŷ is not centred: a fade scales ŷ itself, mean lift included
    cols = [np.ones_like(t), tc, yhat, yhat * tc]
    for f in periodic_hz:
        w = 2.0 * np.pi * f * t
        cols += [np.sin(w), np.cos(w)]
    beta, se = cluster_ols(np.column_stack(cols), e, int(fs))
    tz, gz = beta[1] / se[1], beta[3] / se[3]
    drift = TestResult("slow_trend", abs(tz), 4.0, abs(tz) > 4.0,
                       f"offset drifts {beta[1]:+.2e}/s (t-stat {tz:.1f}, 1 s clusters, gain drift fitted beside it)",
                       {"coef": float(beta[1]), "se": float(se[1]), "t": tz})
    gain = TestResult("gain_trend", abs(gz), 4.0, abs(gz) > 4.0,
                      f"the model's gain error drifts by {100 * beta[3] * t[-1]:+.1f} % over the record "
                      f"({beta[3]:+.2e}/s, t-stat {gz:.1f}; offset drift fitted beside it)",
                      {"coef": float(beta[3]), "se": float(se[3]), "t": gz})
    return [drift, gain]


def falling_indicator(env: np.ndarray) -> np.ndarray:
    """1 while Cμ_env was last seen falling, 0 while rising (held while constant)."""
    step = np.diff(env, prepend=env[:1])
    idx = np.where(step != 0.0, np.arange(env.size), -1)
    last = np.maximum.accumulate(idx)
    return np.where(last >= 0, (step[np.maximum(last, 0)] < 0).astype(float), 0.0)


def direction_dependence(e: np.ndarray, low: np.ndarray, env: np.ndarray, fs: float) -> TestResult:
    """ε ≈ γ ŷ_L + m ŷ_L·[falling]: m is the relative extra gain while Cμ falls."""
    fall = falling_indicator(env)
    X = np.column_stack([np.ones_like(e), low, low * fall])
    beta, se = cluster_ols(X, e, int(fs))
    z = beta[2] / se[2]
    return TestResult("direction", abs(z), 4.0, abs(z) > 4.0,
                      f"gain on falling Cmu differs from rising by {100 * beta[2]:+.1f} % of the "
                      f"low-frequency lift (t-stat {z:.1f})",
                      {"coef": float(beta[2]), "se": float(se[2]), "t": z})


def level_dependence(e: np.ndarray, env: np.ndarray, fs: float, bins: int = 6) -> TestResult:
    """Mean ε per Cμ_env quantile bin, with cluster-robust errors: a wrong static map."""
    edges = np.quantile(env, np.linspace(0, 1, bins + 1))
    idx = np.clip(np.searchsorted(edges, env, side="right") - 1, 0, bins - 1)
    X = np.eye(bins)[idx]
    keep = X.sum(axis=0) > 0
    beta, se = cluster_ols(X[:, keep], e, int(fs))
    z = np.abs(beta - np.mean(beta)) / se
    k = int(np.argmax(z))
    centres = 0.5 * (edges[:-1] + edges[1:])[keep]
    return TestResult("level", float(z[k]), 4.0, bool(z[k] > 4.0),
                      f"mean residual per Cmu level from {beta.min():+.4f} to {beta.max():+.4f}; "
                      f"largest departure at Cmu ~ {centres[k]:.4f} (t-stat {z[k]:.1f})",
                      {"cmu": centres, "mean": beta, "se": se})


def lag_search(measured: np.ndarray, model: np.ndarray, fs: float, max_lag: int = 100) -> TestResult:
    """RMSE of measured(k) − model(k − D) for D = 0 … max_lag samples; the best D."""
    n = measured.size
    r = np.array([np.sqrt(np.mean((measured[d:] - model[:n - d]) ** 2)) for d in range(max_lag + 1)])
    d = int(np.argmin(r))
    gain = 1.0 - r[d] / r[0]
    return TestResult("lag", float(gain), 0.02, d > 0 and gain > 0.02,
                      f"measured lags the model by {d} samples ({1e3 * d / fs:.1f} ms): RMSE "
                      f"{r[0]:.4g} -> {r[d]:.4g} ({100 * gain:.1f} %)", {"lag": d, "rmse": r})


def run_all(measured: np.ndarray, e: np.ndarray, yhat: np.ndarray, low: np.ndarray,
            env: np.ndarray, cmu: np.ndarray, fs: float,
            exclude_hz: tuple[float, ...] = (), envelope_hz: float = 0.0) -> dict[str, TestResult]:
    """Every test on one record's residual (ε = measured − yhat); ``exclude_hz`` the input's
    lines, ``envelope_hz`` a periodic envelope's fundamental (0: not periodic)."""
    out: dict[str, TestResult] = {"whiteness": whiteness(e)}
    out["input_crosscorr"] = input_crosscorr(e, env)
    for r in higher_order(e, env, yhat):
        out[r.name] = r
    out["spectrum"] = spectrum(e, fs, exclude_hz)
    out["level"] = level_dependence(e, env, fs)
    out["direction"] = direction_dependence(e, low, env, fs)
    nuisance = tuple(envelope_hz * k for k in range(1, 9)) if envelope_hz > 0 else ()
    for r in slow_trend(e, yhat, fs, nuisance):
        out[r.name] = r
    out["lag"] = lag_search(measured, yhat, fs)
    return out
