"""Single-burst kernel ΔCL_single(j) and the normalisation φ of the convolution model.

Paper eq. 1:   ΔCL(k) = φ Σ_j h(j) Cμ(k − j),   h = ΔCL response to one burst.

Recipe: burst onsets are the rising edges of the ``cmu`` column; the windows after every
isolated onset are phase averaged, each after subtracting its own pre-burst baseline (the
mean over the ``pre_s`` before the onset, which also removes a slow zero drift). The noise
floor of the average is the standard error across bursts, pooled over the pre-burst part.
The kernel is smoothed with a Savitzky–Golay filter whose window grows with lag (sharp
features come first, the tail is slow), cut where its smoothed magnitude last exceeds
``floor_sigmas`` (1) times the noise floor — a tap whose signal is below the noise adds more
error than the bias of dropping it — and tapered to zero with a half cosine over
``taper_fraction`` of its length — the convolution replays the kernel's noise scaled by Cμ,
so noise after the response has died out only adds error.

φ is the least-squares scale that makes the convolution of the kernel with the averaged
burst input reproduce the measured single-burst response:

    φ = ⟨h, g⟩ / ⟨g, g⟩,   g(k) = Σ_j h(j) c_b(k − j),

with c_b the averaged burst Cμ sequence (four samples of 0.0022 on the bench), so that
φ ≈ 1 / Σ c_b.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from rtlift.core.records import burst_onsets


@dataclass(frozen=True)
class SingleBurstKernel:
    """The identified kernel and φ, with what the identification measured."""

    kernel: np.ndarray            # h(j), j = 0 … L−1 (ΔCL per burst at the reference Cμ)
    phi: float
    raw: np.ndarray               # phase average before smoothing and cut (full window)
    noise_floor: float            # standard error of the phase average (ΔCL)
    n_bursts: int
    burst_samples: int            # samples per burst (median)
    burst_cmu: float              # Cμ during a burst (mean)
    cut_index: int                # kernel length L
    reproduction_rmse: float      # RMS of φ·(h ∗ c_b) − raw over the kernel window
    reproduction_nrmse: float
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"n_bursts": self.n_bursts, "burst_samples": self.burst_samples,
                "burst_cmu": self.burst_cmu, "length": int(self.kernel.size),
                "noise_floor": self.noise_floor, "phi": self.phi,
                "reproduction_rmse": self.reproduction_rmse,
                "reproduction_nrmse": self.reproduction_nrmse, "notes": list(self.notes)}


def phase_average(x: np.ndarray, onsets: np.ndarray, pre: int, post: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error over bursts of x(onset + j) − mean(x(onset−pre … onset−1)),
    j = −pre … post−1."""
    rows = np.stack([x[o - pre:o + post] - np.mean(x[o - pre:o]) for o in onsets])
    mean = rows.mean(axis=0)
    sem = rows.std(axis=0, ddof=1) / np.sqrt(len(onsets)) if len(onsets) > 1 \
        else np.zeros_like(mean)
    return mean, sem


def smooth_growing(h: np.ndarray, fs_hz: float, min_window_s: float = 0.0125,
                   growth: float = 0.15, max_window_s: float = 0.1) -> np.ndarray:
    """Savitzky–Golay (cubic) smoothing with a window ≈ max(min_window, growth · lag),
    capped at max_window: keeps the sharp onset, averages the slow tail harder."""
    out = np.empty_like(h)
    wins = sorted({_odd(max(min_window_s * fs_hz, min(growth * j, max_window_s * fs_hz)))
                   for j in range(h.size)})
    cache = {w: signal.savgol_filter(h, w, 3, mode="interp") if w <= h.size and w > 3 else h
             for w in wins}
    for j in range(h.size):
        w = _odd(max(min_window_s * fs_hz, min(growth * j, max_window_s * fs_hz)))
        out[j] = cache[w][j]
    return out


def _odd(v: float) -> int:
    n = max(5, int(round(v)))
    return n if n % 2 else n + 1


def fit_phi(kernel: np.ndarray, burst: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray]:
    """φ = ⟨target, g⟩/⟨g, g⟩ with g = kernel ∗ burst (truncated to the target's length)."""
    g = np.convolve(kernel, burst)[: target.size]
    if g.size < target.size:
        g = np.pad(g, (0, target.size - g.size))
    phi = float(np.dot(target, g) / np.dot(g, g))
    return phi, phi * g


def fit_kernel(cmu: np.ndarray, dcl: np.ndarray, fs_hz: float, *, pre_s: float = 0.1,
               max_length_s: float = 1.5, floor_sigmas: float = 1.0,
               taper_fraction: float = 0.2, smooth: bool = True,
               min_window_s: float = 0.25) -> SingleBurstKernel:
    """Kernel and φ from a record of repeated isolated bursts (module docstring).

    Windows reach ``max_length_s`` after each onset (or up to the next onset, whichever is
    shorter); bursts closer to the record ends than that are skipped. Bursts closer together
    than ``min_window_s`` (≈ 3 t⁺, the response's duration) are not isolated: ValueError.
    """
    cmu = np.asarray(cmu, dtype=float)
    dcl = np.asarray(dcl, dtype=float)
    onsets = burst_onsets(cmu)
    if onsets.size == 0:
        raise ValueError("no burst found in the cmu column")
    pre = max(2, int(round(pre_s * fs_hz)))
    spacing = np.diff(onsets)
    post = int(round(max_length_s * fs_hz))
    if spacing.size:
        post = min(post, int(np.min(spacing)) - pre)
    valid = onsets[(onsets >= pre) & (onsets + post <= cmu.size)]
    if post < min_window_s * fs_hz:
        raise ValueError(f"bursts only {(post + pre) / fs_hz:.3f} s apart: a single-burst "
                         f"record needs isolated bursts (>= {min_window_s + pre_s:g} s)")
    if valid.size == 0:
        raise ValueError("no isolated burst with a full pre-burst baseline and response window")
    on = cmu > 0.5 * float(np.max(cmu))
    lengths = []
    for o in valid:
        k = o
        while k < cmu.size and on[k]:
            k += 1
        lengths.append(k - o)
    nb = int(np.median(lengths))
    burst = np.mean(np.stack([cmu[o:o + nb] for o in valid]), axis=0)
    avg, sem = phase_average(dcl, valid, pre, post)
    raw = avg[pre:]
    floor = float(np.sqrt(np.mean(sem[pre:] ** 2))) if valid.size > 1 else float(np.std(avg[:pre]))
    notes = [f"{valid.size} isolated bursts phase averaged (window {post / fs_hz:.3f} s)"]
    h = smooth_growing(raw, fs_hz) if smooth else raw.copy()
    env = np.convolve(np.abs(h), np.ones(9) / 9, mode="same")
    above = np.flatnonzero(env > floor_sigmas * floor)
    L = int(above[-1]) + 1 if above.size else raw.size
    L = max(L, 8)
    h = h[:L].copy()
    nt = max(2, int(round(taper_fraction * L)))
    h[L - nt:] *= 0.5 * (1 + np.cos(np.linspace(0, np.pi, nt)))
    if L < raw.size:
        notes.append(f"tail cut at {L / fs_hz:.3f} s where |h| sinks below "
                     f"{floor_sigmas:g} x noise floor {floor:.2e}")
    phi, rep = fit_phi(h, burst, raw)
    rmse = float(np.sqrt(np.mean((rep - raw) ** 2)))
    return SingleBurstKernel(h, phi, raw, floor, int(valid.size), nb, float(np.mean(burst)), L,
                             rmse, rmse / float(np.std(raw)), notes)
