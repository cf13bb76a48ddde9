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


def burst_scatter_std(cmu: np.ndarray, dcl: np.ndarray) -> float:
    """The measurement noise while bursts fire: the scatter of ΔCL across repeated, identical
    isolated bursts around their phase average, √(mean over the phase of the variance over
    bursts, ddof 1), each window from an onset to the nearest next one. What the balance adds to
    the lift during actuation (sensor noise, buffeting, burst-to-burst variation), where the
    noise at rest (:func:`rtlift.identify.campaign.quiet_noise_std`) can be smaller. NaN with
    fewer than two complete bursts."""
    cmu = np.asarray(cmu, dtype=float)
    dcl = np.asarray(dcl, dtype=float)
    onsets = burst_onsets(cmu)
    if onsets.size < 2:
        return float("nan")
    width = int(np.min(np.diff(onsets)))
    onsets = onsets[onsets + width <= dcl.size]
    if onsets.size < 2:
        return float("nan")
    rows = np.stack([dcl[o:o + width] for o in onsets])
    return float(np.sqrt(np.mean(np.var(rows, axis=0, ddof=1))))


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


@dataclass(frozen=True)
class KernelRefinement:
    """The kernel's first period re-estimated on the training record (:func:`refine_kernel`)."""

    kernel: np.ndarray           # h + δh (δh on taps 0 … P−1, zero beyond)
    taps: int                    # P: the training record's burst period, capped at the kernel's length
    ridge: float | None          # λ chosen by held-out RMSE; None: the single-burst kernel kept
    holdout_rmse: dict           # {"single_burst": …, "λ": …} on the held-out part

    def to_dict(self) -> dict:
        return {"used": "single_burst" if self.ridge is None else "train", "taps": self.taps,
                "ridge": self.ridge, "holdout_rmse": dict(self.holdout_rmse),
                "rule": "δh on the first burst period, ridge λ·mean(diag XᵀX)·‖δh‖² toward the "
                        "single-burst kernel; λ and whether to use it by held-out RMSE"}


def refine_kernel(kernel: np.ndarray, unit_high: np.ndarray | tuple[tuple[np.ndarray, np.ndarray], ...],
                  resid: np.ndarray, cmu: np.ndarray,
                  n_est: int, skip: int, tolerance: float,
                  ridges: tuple[float, ...] = (1e-4, 1e-3, 1e-2, 1e-1)) -> KernelRefinement:
    """Re-estimate the kernel's first burst period on the training record.

    The single-burst record averages a few dozen bursts: the kernel's fine shape — what sets
    the burst harmonics of a train, 4 × 7.8 Hz and up — is at its noise floor, and the
    smoothing that keeps that noise out also rounds the shape off. A training record of
    amplitude-modulated bursts holds thousands of bursts, and the hybrid's output is linear in
    the kernel (eq. 11: ΔCL_H = HF(φ h ∗ Cμ)):

        ΔCL − ŷ ≈ Σ_{j<P} δh(j) b(k − j),   b = HF(φ Cμ) (the high branch of a unit kernel),

    ``unit_high`` may also be pairs (u, g) of a signal and a gain on the time: the output of a
    unit kernel at tap j is then Σ g(k) u(k − j) over the pairs (the interaction structure,
    whose burst part G_H(m) HF(c) + G(m) (c − HF(c)) is linear in h for a given m:
    (HF(φ Cμ), G_H(m)) and (φ Cμ − HF(φ Cμ), G(m))). δh is one ridge regression, shrunk toward
    the single-burst kernel:

        δh = argmin ‖r − X δh‖² + λ · mean(diag XᵀX) · ‖δh‖².

    Only one period (P, the median spacing of the record's burst onsets) is identifiable from
    a train: for a periodic input, taps j and j + P multiply the same samples. λ ∈ ``ridges``
    is fitted on [skip, n_est) and scored on the held-out part [n_est, N); the refinement is
    kept only where it beats the single-burst kernel's held-out RMSE by more than
    ``tolerance`` (relative), and is then refitted on the whole record [skip, N).
    """
    kernel = np.asarray(kernel, dtype=float)
    parts = ((unit_high, None),) if isinstance(unit_high, np.ndarray) else tuple(unit_high)
    onsets = burst_onsets(np.asarray(cmu, dtype=float))
    period = int(np.median(np.diff(onsets))) if onsets.size > 2 else 0
    P = min(period, kernel.size)
    base = float(np.sqrt(np.mean(resid[n_est:] ** 2)))
    if P < 4:
        return KernelRefinement(kernel, 0, None, {"single_burst": base})
    N = resid.size
    X = np.zeros((N, P))
    for u, g in parts:
        for j in range(P):
            X[j:, j] += u[:N - j] if g is None else g[j:] * u[:N - j]

    def solve(rows: slice, lam: float) -> np.ndarray:
        A, r = X[rows], resid[rows]
        G = A.T @ A
        return np.linalg.solve(G + lam * float(np.mean(np.diag(G))) * np.eye(P), A.T @ r)

    table = {"single_burst": base}
    for lam in ridges:
        dh = solve(slice(skip, n_est), lam)
        table[f"{lam:g}"] = float(np.sqrt(np.mean((resid[n_est:] - X[n_est:] @ dh) ** 2)))
    lam_best = min(ridges, key=lambda lam: table[f"{lam:g}"])
    if table[f"{lam_best:g}"] >= base * (1.0 - tolerance):
        return KernelRefinement(kernel, P, None, table)
    h = kernel.copy()
    h[:P] += solve(slice(skip, N), lam_best)
    return KernelRefinement(h, P, lam_best, table)
