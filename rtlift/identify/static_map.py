"""Static map ΔCL(Cμ) from a slow sweep, and the paper's nonlinear gain N(Cμ) = ΔCL/Cμ.

The sweep (record columns ``cmu_envelope`` → ``dcl``) is bin-averaged separately on the
rising and the falling branch. The gap between the branches is reported (loop area, largest
gap, start→end zero drift, and the time shift of ``dcl`` that closes the loop best, which
tells a lag loop from a too-fast sweep apart from true hysteresis). The combined bin means
are made monotone non-decreasing by weighted isotonic regression (pool-adjacent-violators)
and anchored at the origin (ΔCL is the increment over the non-actuated baseline).

N(Cμ) is tabulated on the bin centres. At Cμ → 0 the ratio ΔCL/Cμ is 0/0; its limit is the
slope of the map at the origin, estimated by a least-squares fit ΔCL = s₀ Cμ + s₁ Cμ² on the
lowest quarter of the range (plus a cubic term when six or more bins lie there), and stored
as the table's first point N(0) = s₀. Beyond the
measured range :class:`rtlift.blocks.wiener.InputGain` holds N at its last value, so ΔCL
continues along the last chord through the origin (linear, not saturating) — the map is not
extrapolated by the identification.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def isotonic_increasing(values: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted least-squares monotone fit (pool-adjacent-violators).

    Solves  min_f Σ w_i (v_i − f_i)²  subject to  f_1 ≤ f_2 ≤ … ≤ f_n.
    The fit keeps the weighted mean, lies within [min v, max v] and leaves a
    non-decreasing input unchanged.
    """
    v = np.asarray(values, dtype=float).ravel()
    w = np.ones_like(v) if weights is None else np.asarray(weights, dtype=float).ravel()
    if v.shape != w.shape:
        raise ValueError("values and weights must have the same length")
    if np.any(w <= 0):
        raise ValueError("weights must be positive")
    means: list[float] = []
    wsum: list[float] = []
    count: list[int] = []
    for vi, wi in zip(v, w, strict=True):
        means.append(float(vi))
        wsum.append(float(wi))
        count.append(1)
        while len(means) > 1 and means[-2] > means[-1]:
            m2, w2, c2 = means.pop(), wsum.pop(), count.pop()
            wt = wsum[-1] + w2
            means[-1] = (means[-1] * wsum[-1] + m2 * w2) / wt
            wsum[-1] = wt
            count[-1] += c2
    return np.repeat(np.asarray(means), np.asarray(count, dtype=int))


@dataclass(frozen=True)
class BinnedBranch:
    """Bin means of ΔCL on one branch of the sweep (NaN where a bin is empty)."""

    centers: np.ndarray
    mean: np.ndarray
    count: np.ndarray
    sem: np.ndarray


@dataclass(frozen=True)
class HysteresisReport:
    """Rising vs falling branch of the sweep.

    ``loop_area`` = ∫ (ΔCL_falling − ΔCL_rising) dCμ over the bins both branches cover
    (positive when the falling branch lies above: the signature of a lag);
    ``max_gap`` = max |ΔCL_falling − ΔCL_rising| over those bins; ``max_gap_relative`` is
    that over the map's range; ``gap_significance`` is max_gap over the standard error of
    the difference at that bin; ``zero_drift`` = ΔCL at the end minus at the start of the
    sweep (both at Cμ ≈ 0); ``closing_lag_s`` is the delay of ``dcl`` behind the envelope
    that minimises the loop area, and ``max_gap_after_lag`` the gap left after removing it.
    """

    loop_area: float
    max_gap: float
    max_gap_relative: float
    gap_significance: float
    zero_drift: float
    closing_lag_s: float
    max_gap_after_lag: float
    significant: bool
    verdict: str

    def to_dict(self) -> dict[str, float | bool | str]:
        return {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class StaticMap:
    """Monotone static map and the gain table N(Cμ) = ΔCL/Cμ (first point: the limit slope)."""

    cmu: np.ndarray               # bin centres, ascending, starting at 0
    dcl: np.ndarray               # monotone ΔCL at those centres, dcl[0] = 0
    gain_cmu: np.ndarray          # N table grid, gain_cmu[0] = 0
    gain: np.ndarray              # N(Cμ); gain[0] = limit slope s₀
    limit_slope: float
    cmu_max: float
    rising: BinnedBranch
    falling: BinnedBranch
    hysteresis: HysteresisReport
    fit_rmse: float               # RMSE of the monotone map vs all sweep samples
    notes: list[str] = field(default_factory=list)

    def __call__(self, cmu: np.ndarray) -> np.ndarray:
        """ΔCL(Cμ) by linear interpolation of the monotone map (end value held)."""
        return np.interp(cmu, self.cmu, self.dcl)

    def gain_at(self, cmu: np.ndarray) -> np.ndarray:
        """N(Cμ) exactly as :class:`~rtlift.blocks.wiener.InputGain` evaluates it."""
        return np.interp(cmu, self.gain_cmu, self.gain)


def _branch_direction(env: np.ndarray, fs_hz: float, smooth_s: float) -> np.ndarray:
    """+1 rising, −1 falling, 0 holding, from the slope of a moving average of the envelope."""
    w = max(1, int(round(smooth_s * fs_hz)))
    kernel = np.ones(w) / w
    padded = np.concatenate([np.full(w, env[0]), env, np.full(w, env[-1])])
    sm = np.convolve(padded, kernel, mode="same")[w:-w]
    d = np.gradient(sm)
    tol = 1e-3 * (np.max(env) - np.min(env)) / max(w, 1)
    return np.where(d > tol, 1, np.where(d < -tol, -1, 0))


def _bin(env: np.ndarray, dcl: np.ndarray, edges: np.ndarray) -> BinnedBranch:
    nb = edges.size - 1
    idx = np.clip(np.searchsorted(edges, env, side="right") - 1, 0, nb - 1)
    count = np.bincount(idx, minlength=nb).astype(float)
    s = np.bincount(idx, weights=dcl, minlength=nb)
    s2 = np.bincount(idx, weights=dcl * dcl, minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s / count
        var = np.maximum(s2 / count - mean**2, 0.0)
        sem = np.sqrt(var / np.maximum(count - 1, 1))
    mean[count == 0] = np.nan
    sem[count == 0] = np.nan
    return BinnedBranch(0.5 * (edges[:-1] + edges[1:]), mean, count, sem)


def _loop(env, dcl, direction, edges):
    rise = _bin(env[direction > 0], dcl[direction > 0], edges)
    fall = _bin(env[direction < 0], dcl[direction < 0], edges)
    both = (rise.count >= 3) & (fall.count >= 3)
    gap = fall.mean - rise.mean
    width = np.diff(edges)
    area = float(np.sum(gap[both] * width[both])) if both.any() else 0.0
    return rise, fall, both, gap, area


def hysteresis_report(env: np.ndarray, dcl: np.ndarray, fs_hz: float, edges: np.ndarray,
                      direction: np.ndarray, max_lag_s: float = 2.0) -> HysteresisReport:
    """Compare the rising and falling branches (see :class:`HysteresisReport`)."""
    rise, fall, both, gap, area = _loop(env, dcl, direction, edges)
    span = float(np.nanmax(np.concatenate([rise.mean, fall.mean])) - 0.0) or 1.0
    if both.any():
        j = int(np.nanargmax(np.where(both, np.abs(gap), -np.inf)))
        max_gap = float(abs(gap[j]))
        se = float(np.hypot(rise.sem[j], fall.sem[j]))
        signif = max_gap / se if se > 0 else float("inf")
    else:
        max_gap, signif = 0.0, 0.0
    n_edge = max(1, int(0.02 * env.size))
    drift = float(np.mean(dcl[-n_edge:]) - np.mean(dcl[:n_edge]))
    best_lag, best_gap = 0.0, max_gap
    max_lag = int(max_lag_s * fs_hz)
    if max_lag > 0 and both.any():
        lags = np.unique(np.linspace(0, max_lag, 41).astype(int))
        areas = []
        for L in lags:
            areas.append(abs(_loop(env[: env.size - L], dcl[L:], direction[: env.size - L],
                                   edges)[4]))
        L = int(lags[int(np.argmin(areas))])
        _, _, b2, g2, _ = _loop(env[: env.size - L], dcl[L:], direction[: env.size - L], edges)
        best_lag = L / fs_hz
        best_gap = float(np.max(np.abs(g2[b2]))) if b2.any() else 0.0
    significant = bool(signif > 4.0 and max_gap > 0.02 * span)
    if not significant:
        verdict = "no significant hysteresis: branches agree within noise / 2 % of range"
    elif best_gap < 0.5 * max_gap and best_lag > 0:
        verdict = (f"loop closes with a {best_lag:.2f} s delay of dcl: a lag loop (sweep too fast "
                   "for the plant), not static hysteresis")
    elif abs(drift) > 0.5 * max_gap:
        verdict = "loop comparable to the zero drift over the sweep: drift, not hysteresis"
    else:
        verdict = "hysteresis: the branches differ beyond noise, lag and drift"
    return HysteresisReport(area, max_gap, max_gap / span, signif, drift, best_lag, best_gap,
                            significant, verdict)


def limit_slope(cmu: np.ndarray, dcl: np.ndarray, weights: np.ndarray,
                fraction: float = 0.25) -> float:
    """s₀ = lim_{Cμ→0} ΔCL/Cμ from a weighted fit ΔCL = s₀ Cμ + s₁ Cμ² + s₂ Cμ³ (through the
    origin; the cubic term only with six or more points) over Cμ ≤ ``fraction`` · max Cμ
    (at least three points)."""
    cmu = np.asarray(cmu, dtype=float)
    order = np.argsort(cmu)
    pos = order[cmu[order] > 0]
    k = max(3, int(np.sum(cmu[pos] <= fraction * cmu.max())))
    sel = pos[:k]
    sw = np.sqrt(weights[sel])
    powers = (1, 2, 3) if sel.size >= 6 else (1, 2)
    X = np.column_stack([cmu[sel] ** q for q in powers]) * sw[:, None]
    coef, *_ = np.linalg.lstsq(X, dcl[sel] * sw, rcond=None)
    return float(coef[0])


def fit_static_map(cmu_envelope: np.ndarray, dcl: np.ndarray, fs_hz: float, *, n_bins: int = 24,
                   direction_smoothing_s: float = 0.25) -> StaticMap:
    """Static map and N(Cμ) table from a slow sweep (module docstring has the recipe).

    ``cmu_envelope`` is the slowly swept Cμ, ``dcl`` the measured ΔCL. Bins are equal in Cμ
    on [0, max Cμ]; the map's grid is 0 followed by the centres of the non-empty bins.
    """
    env = np.asarray(cmu_envelope, dtype=float)
    dcl = np.asarray(dcl, dtype=float)
    cmax = float(np.max(env))
    if not cmax > 0:
        raise ValueError("static sweep has no positive Cμ")
    edges = np.linspace(0.0, cmax, n_bins + 1)
    direction = _branch_direction(env, fs_hz, direction_smoothing_s)
    rise = _bin(env[direction > 0], dcl[direction > 0], edges)
    fall = _bin(env[direction < 0], dcl[direction < 0], edges)
    allb = _bin(env, dcl, edges)
    hyst = hysteresis_report(env, dcl, fs_hz, edges, direction)
    notes: list[str] = []
    ok = allb.count >= 3
    centers = allb.centers[ok]
    means = allb.mean[ok]
    weights = allb.count[ok]
    # the first bin straddles Cμ = 0 (the holds at zero); evaluate it at its mean Cμ
    idx = np.clip(np.searchsorted(edges, env, side="right") - 1, 0, n_bins - 1)
    mean_cmu = np.bincount(idx, weights=env, minlength=n_bins)[ok] / weights
    centers = mean_cmu
    keep = centers > 1e-12 * cmax
    if not keep.all():
        notes.append("samples at Cmu = 0 used only to anchor the map at the origin")
    centers, means, weights = centers[keep], means[keep], weights[keep]
    if centers.size < 3:
        raise ValueError("static sweep covers fewer than three Cμ bins")
    mono = np.maximum(isotonic_increasing(means, weights), 0.0)
    if np.any(np.abs(mono - means) > 0):
        notes.append(f"isotonic smoothing moved {int(np.sum(mono != means))} bin(s)")
    s0 = limit_slope(centers, mono, weights)
    if s0 <= 0:
        s0 = float(mono[0] / centers[0]) if mono[0] > 0 else float(np.max(mono) / cmax)
        notes.append("limit slope from the first bin's chord (quadratic fit not positive)")
    grid = np.concatenate([[0.0], centers])
    dmap = np.concatenate([[0.0], mono])
    gain = np.concatenate([[s0], mono / centers])
    fit_rmse = float(np.sqrt(np.mean((np.interp(env, grid, dmap) - dcl) ** 2)))
    return StaticMap(grid, dmap, grid.copy(), gain, s0, cmax, rise, fall, hyst, fit_rmse, notes)
