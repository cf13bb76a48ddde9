"""Figures of an observer run, drawn by ``rtlift demo`` while it runs and by ``rtlift plot``
after the fact (matplotlib's Agg backend: no display needed).

- :func:`observer_figure`: measured ΔCL, the observer's estimate ΔĈL and the open-loop model
  (and the noise-free truth when a bench knows it), the whole run above and a 3 s window below;
- :func:`innovation_figure`: the innovation ν = z − ŷ with its ±2σ band, where
  σ² = S = ν²/NIS is the innovation variance the filter predicted (NIS = ν²/S), and the NIS
  against the χ²₁ 95 % bound (3.84) with its 1 s running mean (1 for a consistent filter);
- :func:`control_figure`: closed-loop runs, the reference beside each run's ΔCL (raw and
  low-passed at 1 Hz, as ``rtlift control`` scores it), and the commanded envelopes (V).
"""

from __future__ import annotations

from typing import Any

import numpy as np

CHI2_1_95 = 3.841458820694124
"""95 % quantile of χ² with one degree of freedom: the NIS bound of a scalar measurement."""
WINDOW_S = 3.0
"""Length of the zoomed window (s), taken from the middle of the run."""


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _window(n: int, fs_hz: float) -> slice:
    w = min(n, int(round(WINDOW_S * fs_hz)))
    a = max(0, n // 2 - w // 2)
    return slice(a, a + w)


def observer_figure(t: np.ndarray, measured: np.ndarray, estimate: np.ndarray, model: np.ndarray,
                    path: str, title: str, fs_hz: float, truth: np.ndarray | None = None) -> None:
    """Measured ΔCL (grey), open-loop model (orange, dashed), ΔĈL (blue) and, when given, the
    bench's noise-free ΔCL (black) against ``t`` (s): the whole run, then :data:`WINDOW_S` s
    from its middle. NaN (taring, a missing sample) leaves a gap."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5))
    for ax, sl in zip(axes, (slice(None), _window(len(t), fs_hz)), strict=True):
        ax.plot(t[sl], measured[sl], color="0.7", lw=0.8, label="measured")
        ax.plot(t[sl], model[sl], color="tab:orange", lw=1.0, ls="--", label="open-loop model")
        ax.plot(t[sl], estimate[sl], color="tab:blue", lw=1.2, label="Kalman observer")
        if truth is not None:
            ax.plot(t[sl], truth[sl], color="k", lw=0.9, label="bench truth (noise-free)")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("ΔCL")
    axes[0].set_title(title, fontsize=9)
    axes[0].legend(fontsize=8, ncol=4, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def innovation_figure(t: np.ndarray, innovation: np.ndarray, nis: np.ndarray, path: str, title: str,
                      fs_hz: float) -> None:
    """ν with ±2√S (S = ν²/NIS) above; NIS, its 1 s running mean and the χ²₁ 95 % bound below."""
    plt = _pyplot()
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.where(nis > 0, np.abs(innovation) / np.sqrt(nis), np.nan)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    top.fill_between(t, -2 * sigma, 2 * sigma, color="tab:blue", alpha=0.2, lw=0, label="±2σ predicted")
    top.plot(t, innovation, color="k", lw=0.6, label="innovation ν")
    top.set_ylabel("ν (ΔCL)")
    top.legend(fontsize=8, loc="upper right")
    top.set_title(title, fontsize=9)
    ok = np.isfinite(nis)
    w = max(1, int(round(fs_hz)))
    mean = np.full(len(nis), np.nan)
    if ok.sum() >= w:
        run = np.convolve(np.where(ok, nis, 0.0), np.ones(w), "valid")
        cnt = np.convolve(ok.astype(float), np.ones(w), "valid")
        with np.errstate(invalid="ignore", divide="ignore"):
            mean[w - 1:] = run / cnt
    bottom.plot(t, nis, color="0.6", lw=0.5, label="NIS")
    bottom.plot(t, mean, color="tab:blue", lw=1.4, label="NIS, 1 s mean")
    bottom.axhline(CHI2_1_95, color="tab:red", ls="--", lw=1.0, label="χ²₁ 95 % bound")
    bottom.axhline(1.0, color="k", ls=":", lw=0.8)
    bottom.set_yscale("symlog", linthresh=1.0)
    bottom.set_ylim(bottom=0.0)
    bottom.set_ylabel("NIS")
    bottom.set_xlabel("t (s)")
    bottom.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def control_figure(t: np.ndarray, reference: np.ndarray, runs: list[tuple], path: str, title: str,
                   fs_hz: float, xlabel: str = "t (s)") -> None:
    """Closed-loop runs against the reference (dashed) above, each run's ΔCL faint and low-passed
    at 1 Hz (bold, as ``rtlift control`` scores it); their commanded envelopes (V, held from each
    command to the next) below. ``runs``: ``(label, color, t, ΔCL, t of the envelope, envelope V)``."""
    from rtlift.app.hil_tracking import lowpass

    plt = _pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, height_ratios=(2, 1))
    for label, color, tt, y, t_env, env in runs:
        ok = np.isfinite(y)
        top.plot(tt, y, color=color, lw=0.4, alpha=0.35)
        if ok.sum() > 20:
            low = np.full(len(y), np.nan)
            low[ok] = lowpass(y[ok], fs_hz)
            top.plot(tt, low, color=color, lw=1.4, label=label)
        bottom.step(t_env, env, where="post", color=color, lw=1.0, label=label.split(":")[0])
    top.plot(t, reference, color="k", lw=1.2, ls="--", label="reference")
    top.set_ylabel("ΔCL (1 Hz low-pass bold)")
    top.legend(fontsize=8, loc="upper left")
    top.set_title(title, fontsize=9)
    bottom.set_ylabel("commanded envelope (V)")
    bottom.set_xlabel(xlabel)
    bottom.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
