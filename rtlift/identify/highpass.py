"""Choice of the high-pass filter HF of the hybrid model by held-out error.

Eq. 11:  ΔCL = HF(φ Σ h(j) Cμ(k−j)) + W(Cμ_env(k)).  For each Butterworth candidate
(order, cutoff between the control and the burst frequency) the Wiener part is fitted by
output-error PEM to z = ΔCL − HF(conv) on the estimation part of the training record, and the
candidate is scored by the RMSE of the whole hybrid on the held-out part. Only candidates
that actually remove the control signal from the convolution are admitted — the paper's
reason for HF — i.e. |HF(f)| ≤ ``stop_gain`` (−20 dB) at f_stop = max(f_c, f_band): f_c is
the control frequency of the training envelope (the frequency below which 95 % of its
variance lies) and f_band the top of the control band the model must serve (default 1 Hz:
k = 0.25 at U∞ = 3 m/s, c = 0.245 m). The held-out tail of a one-frequency training record
cannot see other control frequencies: on the bench, filters that leak the convolution's
slow part, or whose transition band sits on a control frequency (a steep filter with its
cutoff near 1 Hz), fit the training record best and transfer worst (ρ 0.85 instead of 0.98
at k = 0.25). The filter is
causal (``sosfilt``: what runs in real time). The zero-phase twin (``sosfiltfilt``) of the
chosen filter is scored the same way as an offline reference only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from rtlift.identify.pem import PEMResult, fit_wiener


@dataclass(frozen=True)
class HighPassChoice:
    """The chosen filter and the score of every candidate."""

    order: int
    cutoff_hz: float
    holdout_rmse: float
    zero_phase_holdout_rmse: float
    table: list[dict]
    pem: PEMResult                 # the Wiener fit of the chosen candidate (estimation part)

    stop_hz: float = 0.0

    def to_dict(self) -> dict:
        return {"order": self.order, "cutoff_hz": self.cutoff_hz,
                "stopband_frequency_hz": self.stop_hz,
                "holdout_rmse": self.holdout_rmse,
                "zero_phase_holdout_rmse_offline_reference": self.zero_phase_holdout_rmse,
                "candidates": self.table,
                "criterion": "held-out RMSE of the hybrid, causal HPF, among the filters with "
                             "|HF| <= -20 dB at the top of the control band"}


def control_frequency(env: np.ndarray, fs_hz: float, fraction: float = 0.95) -> float:
    """f_c: the frequency below which ``fraction`` of the (mean-removed) envelope's
    variance lies (periodogram)."""
    x = np.asarray(env, dtype=float) - np.mean(env)
    p = np.abs(np.fft.rfft(x)) ** 2
    p[0] = 0.0
    c = np.cumsum(p)
    if c[-1] <= 0:
        return 0.0
    f = np.fft.rfftfreq(x.size, 1.0 / fs_hz)
    return float(f[np.searchsorted(c, fraction * c[-1])])


def highpass_gain(order: int, cutoff_hz: float, f_hz: float, fs_hz: float) -> float:
    """|HF(e^{jωT})| at ``f_hz``."""
    _, h = signal.sosfreqz(butter_highpass(order, cutoff_hz, fs_hz), worN=[f_hz], fs=fs_hz)
    return float(np.abs(h[0]))


def butter_highpass(order: int, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """Second-order sections of the Butterworth high-pass, −3 dB at ``cutoff_hz``
    (``scipy.signal.butter``, as :meth:`rtlift.blocks.highpass.HighPassFilter.design`)."""
    return signal.butter(order, cutoff_hz, btype="highpass", fs=fs_hz, output="sos")


def wiener_fit_for_highpass(high: np.ndarray, dcl: np.ndarray, env: np.ndarray, n_est: int,
                            order: int, fs_hz: float, gain: np.ndarray | None,
                            table, form: str, skip: int, theta0=None, refine_phi: bool = False,
                            cost: np.ndarray | None = None) -> tuple[PEMResult, np.ndarray]:
    """PEM of the hybrid's output error over the first ``n_est`` samples with the high part
    fixed (z = ΔCL − high) or, with ``refine_phi``, scaled by a jointly estimated β
    (ΔCL ≈ β·high + W(Cμ_env), so φ → β φ). Returns the fit and the hybrid's ΔCL over the
    whole record."""
    z = dcl if refine_phi else dcl - high
    g = None if gain is None else gain[:n_est]
    res = fit_wiener(env[:n_est], z[:n_est], order, form=form, fs_hz=fs_hz, gain=g,
                     table=table, skip=skip, theta0=theta0, n_starts=2 if theta0 is None else 1,
                     extra=high[:n_est] if refine_phi else None, cost=cost)
    zhat, _ = res.output(env, gain, table)
    beta = float(res.extra_coef[0]) if refine_phi else 1.0
    return res, beta * high + zhat


def choose_highpass(conv: np.ndarray, dcl: np.ndarray, env: np.ndarray, fs_hz: float, *,
                    n_est: int, wiener_order: int, gain: np.ndarray | None = None,
                    table=None, form: str = "input_gain", skip: int = 0,
                    orders: tuple[int, ...] = (1, 2, 3, 4),
                    cutoffs_hz: tuple[float, ...] = (0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 5.5),
                    refine_phi: bool = False, stop_gain: float = 0.1,
                    control_band_hz: float = 1.0, cost: np.ndarray | None = None) -> HighPassChoice:
    """Grid search over (order, cutoff): min over the admitted candidates of
    RMSE(ΔCL − ĤΔCL) on samples ``n_est:`` (see module docstring).
    ``conv`` = φ Σ h(j) Cμ(k−j) over the record."""
    val = slice(n_est, dcl.size)
    table_rows = []
    best = None
    theta = None
    f_c = max(control_frequency(env[:n_est], fs_hz), control_band_hz)
    grid = [(fc, order) for fc in cutoffs_hz for order in orders]
    admitted = [g for g in grid if highpass_gain(g[1], g[0], f_c, fs_hz) <= stop_gain]
    for fc, order in admitted or grid:
        high = signal.sosfilt(butter_highpass(order, fc, fs_hz), conv)
        res, dhat = wiener_fit_for_highpass(high, dcl, env, n_est, wiener_order, fs_hz, gain,
                                            table, form, skip, theta, refine_phi, cost)
        theta = res.theta
        err = float(np.sqrt(np.mean((dcl[val] - dhat[val]) ** 2)))
        table_rows.append({"order": order, "cutoff_hz": fc, "holdout_rmse": err})
        if best is None or err < best[0]:
            best = (err, order, fc, res)
    err, order, fc, res = best
    high_zp = signal.sosfiltfilt(butter_highpass(order, fc, fs_hz), conv)
    _, dhat_zp = wiener_fit_for_highpass(high_zp, dcl, env, n_est, wiener_order, fs_hz, gain,
                                         table, form, skip, res.theta, refine_phi, cost)
    err_zp = float(np.sqrt(np.mean((dcl[val] - dhat_zp[val]) ** 2)))
    return HighPassChoice(order, fc, err, err_zp, table_rows, res, f_c)
