"""Fit metrics between a measured and a modelled signal.

- ρ = cov(a, b) / (σ_a σ_b) — the paper's correlation coefficient;
- RMSE = √(mean((a − b)²));
- NRMSE = RMSE / σ_a (σ of the measurement; 0 is perfect, 1 is as good as the mean);
- fit % = 100 (1 − ‖a − b‖ / ‖a − mean(a)‖) — MATLAB's ``compare`` figure.

:func:`noise_ceiling` is what the noise-free signal itself would score against a measurement
that adds independent noise: no model of the signal can do better.
"""

from __future__ import annotations

import numpy as np


def _pair(measured: np.ndarray, model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(measured, dtype=float).ravel()
    b = np.asarray(model, dtype=float).ravel()
    if a.shape != b.shape or a.size < 2:
        raise ValueError(f"need two equal-length signals of 2+ samples, got {a.shape} and {b.shape}")
    return a, b


def corr(measured: np.ndarray, model: np.ndarray) -> float:
    a, b = _pair(measured, model)
    da, db = a - a.mean(), b - b.mean()
    den = np.sqrt(np.dot(da, da) * np.dot(db, db))
    return float(np.dot(da, db) / den) if den > 0 else float("nan")


def rmse(measured: np.ndarray, model: np.ndarray) -> float:
    a, b = _pair(measured, model)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def nrmse(measured: np.ndarray, model: np.ndarray) -> float:
    a, b = _pair(measured, model)
    s = float(np.std(a))
    return rmse(a, b) / s if s > 0 else float("nan")


def fit_percent(measured: np.ndarray, model: np.ndarray) -> float:
    a, b = _pair(measured, model)
    den = float(np.linalg.norm(a - a.mean()))
    return 100.0 * (1.0 - float(np.linalg.norm(a - b)) / den) if den > 0 else float("nan")


def scores(measured: np.ndarray, model: np.ndarray) -> dict[str, float]:
    """The per-record triple every report uses: {"corr", "nrmse", "rmse"}."""
    return {"corr": corr(measured, model), "nrmse": nrmse(measured, model), "rmse": rmse(measured, model)}


def noise_ceiling(measured: np.ndarray, noise_std: float) -> dict[str, float]:
    """{"corr", "nrmse"} of the noise-free signal s against its measurement a = s + n, n
    independent of s with std σ_n: σ_a² = σ_s² + σ_n², so ρ = σ_s/σ_a = √(1 − σ_n²/σ_a²) and
    NRMSE = σ_n/σ_a (the ceiling any model's scores are bounded by, in expectation)."""
    a = np.asarray(measured, dtype=float).ravel()
    s = float(np.std(a))
    if not (s > 0 and np.isfinite(noise_std) and noise_std >= 0):
        return {"corr": float("nan"), "nrmse": float("nan")}
    ratio = noise_std / s
    return {"corr": float(np.sqrt(max(0.0, 1.0 - ratio * ratio))), "nrmse": float(ratio)}
