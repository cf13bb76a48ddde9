"""LTI part of a Wiener model by the prediction error method (Ljung 1999, §7.3, §10.2).

Model (the paper's eqs. 4–6): ẑ = static(u, y), y = G(q) u, with G an LTI of order n in
controllable canonical form (:class:`.poles.CanonicalLTI`).

The output (simulation) error of the whole Wiener model is minimised,

    θ̂ = argmin_θ Σ_k ε(k, θ)²,   ε(k, θ) = z(k) − ẑ(k | θ)       (Ljung eq. 7.12, OE form)

with one of three static parts:

* ``input_gain`` — ẑ = N(u(k)) · y(k), the paper's gain scheduled on the input (eq. 6);
* ``output_map`` — ẑ = f(y(k)) with f a known table (the textbook Wiener form with the
  static map as f);
* ``output_poly`` — ẑ = Σ_d p_d y(k)^d with unknown p (the textbook Wiener model for data
  without a static map); the LTI then has unit DC gain (the Wiener gain ambiguity).

Parameters that enter linearly (c for ``input_gain``, p for ``output_poly``) are eliminated
by linear least squares for every θ (variable projection, Golub & Pereyra 1973;
:mod:`.problem`), and θ is found by damped Gauss–Newton / Levenberg–Marquardt
(``scipy.optimize.least_squares``, ``method="lm"``). Stability is built into the
parametrisation of the denominator (:mod:`.poles`): every finite θ is stable, and a slow pole
1 − p ≈ e^{q} is resolved on a log scale. Parameter uncertainty is the asymptotic covariance
P = σ̂² (JᵀJ)⁻¹ of the physical parameters (a, c, p) with J the Jacobian of ε (Ljung eq. 9.17),
σ̂² = Σε²/(N − d) (:mod:`.uncertainty`); the order is chosen by :mod:`.order`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal

from rtlift.identify.poles import R_MAX, CanonicalLTI, denominator_from_theta, theta_from_poles
from rtlift.identify.problem import _Problem, _static
from rtlift.identify.uncertainty import _uncertainty

FORMS = ("input_gain", "output_map", "output_poly")


# --------------------------------------------------------------------- the estimator
@dataclass(frozen=True)
class PEMResult:
    """An identified Wiener model and what the estimation knows about it."""

    lti: CanonicalLTI
    form: str
    poly: np.ndarray | None           # p₀ … p_D for ``output_poly``
    theta: np.ndarray
    rmse: float                        # RMS output error on the samples used
    residual_std: float
    n_samples: int
    n_params: int
    aic: float                         # N ln σ̂² + 2 d
    uncertainty: dict = field(default_factory=dict)
    extra_coef: np.ndarray | None = None   # β of the extra linear regressors
    nfev: int = 0
    message: str = ""

    def output(self, u: np.ndarray, gain: np.ndarray | None = None,
               table: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(ẑ, y) from rest for input ``u`` (``gain`` = N(u) for ``input_gain``;
        ``table`` = (y grid, f) for ``output_map``)."""
        y = self.lti.simulate(u)
        return _static(self.form, u, y, gain, table, self.poly), y


def _arx_poles(u: np.ndarray, y: np.ndarray, order: int) -> np.ndarray:
    """Poles of the equation-error (ARX) fit y(k) + Σ aᵢ y(k−i) = Σ cᵢ u(k−i+1) (Ljung §7.3)."""
    n = order
    N = u.size
    cols = [-y[n - i: N - i] for i in range(1, n + 1)] + [u[n - i: N - i] for i in range(n)]
    Phi = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(Phi, y[n:], rcond=None)
    return np.roots(np.concatenate([[1.0], coef[:n]]))


def _initial_thetas(prob: _Problem, fs_hz: float, y_hat: np.ndarray | None) -> list[np.ndarray]:
    """Starting points: the ARX estimate and a few sets of real poles spread over bandwidths."""
    n = prob.order
    starts: list[tuple[np.ndarray, np.ndarray | None]] = []
    if y_hat is not None:
        poles = _arx_poles(prob.u, y_hat, n)
        starts.append((theta_from_poles(poles, prob.r_max, 1e-4), None))
    spread = np.array([1.0, 3.0, 9.0, 27.0, 81.0, 243.0, 729.0, 2187.0])[:n]
    for f0 in np.geomspace(fs_hz / 4000.0, fs_hz / 40.0, 4):
        poles = np.exp(-2 * np.pi * f0 * spread / fs_hz)
        starts.append((theta_from_poles(poles, prob.r_max, 1e-4), None))
    out = []
    for th, _ in starts:
        if prob.form == "input_gain":
            out.append(th)
        else:
            a = denominator_from_theta(th, n, prob.r_max)
            ct = _numerator_start(prob, a)
            out.append(np.concatenate([th, ct]))
    return out


def _numerator_start(prob: _Problem, a: np.ndarray) -> np.ndarray:
    """c̃ (DC gain Σc̃) from a linear LS fit of z on the filtered input, normalised per form."""
    n = prob.order
    x1 = signal.lfilter([1.0], np.concatenate([[1.0], a]), prob.u)
    X = np.zeros((prob.u.size, n))
    for i in range(n):
        X[i:, i] = x1[: x1.size - i]
    a1 = 1.0 + np.sum(a)
    target = prob.z if prob.form == "output_poly" else _inverse_table(prob.z, *prob.table)
    c, *_ = np.linalg.lstsq(X[prob.mask], target[prob.mask], rcond=None)
    ct = c / a1
    if prob.form == "output_poly":
        g = np.sum(ct)
        ct = ct / g if abs(g) > 1e-12 else np.full(n, 1.0 / n)
        return ct[1:]
    return ct


def _inverse_table(zv: np.ndarray, x: np.ndarray, f: np.ndarray) -> np.ndarray:
    """f⁻¹(z) for a non-decreasing table (plateaus resolved to their first point)."""
    fu, idx = np.unique(f, return_index=True)
    return np.interp(zv, fu, x[idx])


def fit_wiener(u: np.ndarray, z: np.ndarray, order: int, *, form: str = "input_gain",
               fs_hz: float = 1.0, gain: np.ndarray | None = None,
               table: tuple[np.ndarray, np.ndarray] | None = None, degree: int = 3,
               skip: int = 0, theta0: np.ndarray | None = None, n_starts: int = 2,
               max_nfev: int = 400, r_max: float = R_MAX,
               extra: np.ndarray | None = None, cost: np.ndarray | None = None,
               weight: np.ndarray | None = None) -> PEMResult:
    """Identify the Wiener model ẑ = static(u, y), y = G(q) u by output-error PEM.

    ``u``: the Wiener input (the envelope Cμ); ``z``: its target output (for the hybrid,
    ΔCL − HF(convolution)); ``gain`` = N(u(k)) for ``input_gain``; ``table`` = (y grid, f)
    for ``output_map``; ``degree`` of the polynomial for ``output_poly``; ``skip`` leading
    samples are simulated but left out of the cost (unknown initial state). ``extra`` (N×m)
    are further regressors entering linearly, ẑ += extra·β (for the hybrid: the high-passed
    convolution, whose scale β refines φ). ``cost`` (indices) replaces ``skip``: the samples
    in the cost, e.g. several records laid end to end with rest between them, one of them
    thinned so that each weighs alike. ``weight`` (N,) weighs each sample's output error
    (w(z − ẑ)): several records, each weighing alike whatever its length and size. ``theta0`` warm
    starts (e.g. from a neighbouring candidate); otherwise the best ``n_starts`` of the ARX
    and bandwidth-grid starts are refined and the best result is kept.
    """
    if form not in FORMS:
        raise ValueError(f"unknown Wiener form {form!r}; expected one of {FORMS}")
    u = np.asarray(u, dtype=float)
    z = np.asarray(z, dtype=float)
    if u.shape != z.shape:
        raise ValueError("u and z must have the same length")
    if form == "input_gain" and (gain is None or np.shape(gain) != u.shape):
        raise ValueError("input_gain needs gain = N(u) with the length of u")
    if form == "output_map" and table is None:
        raise ValueError("output_map needs table = (y grid, f)")
    mask = slice(skip, None) if cost is None else np.asarray(cost, dtype=np.intp)
    if extra is not None:
        extra = np.asarray(extra, dtype=float).reshape(u.size, -1)
    if weight is not None:
        weight = np.asarray(weight, dtype=float)
        if weight.shape != u.shape:
            raise ValueError("weight must have the length of u")
        if form == "input_gain":                # ẑ is linear in N(u)·y and β: weigh them, the target too
            z, gain = weight * z, weight * np.asarray(gain, float)
            extra = None if extra is None else weight[:, None] * extra
            weight = None
    prob = _Problem(u, z, order, form, None if gain is None else np.asarray(gain, float),
                    table, degree, mask, r_max, extra, weight)
    if theta0 is not None:
        starts = [np.asarray(theta0, dtype=float)]
    else:
        y_hat = None
        if form == "input_gain":
            y_hat = z / np.where(np.abs(prob.gain) > 0, prob.gain, 1.0)
        elif form == "output_poly":
            y_hat = z - np.mean(z)
        else:
            y_hat = _inverse_table(z, *table)
        cand = _initial_thetas(prob, fs_hz, y_hat)
        costs = [float(np.sum(prob.solve(th)[0] ** 2)) for th in cand]
        starts = [cand[i] for i in np.argsort(costs)[:max(1, n_starts)]]

    def fun(th: np.ndarray) -> np.ndarray:
        return prob.solve(th)[0]

    best = None
    for th0 in starts:
        sol = optimize.least_squares(fun, th0, method="lm", x_scale="jac", max_nfev=max_nfev,
                                     xtol=1e-12, ftol=1e-12)
        if best is None or sol.cost < best.cost:
            best = sol
    r, a, c, p, beta = prob.solve(best.x)
    N = z[mask].size
    d = (order + order + (0 if p is None else p.size) - (form == "output_poly")
         + (0 if beta is None else beta.size))
    rss = float(np.sum(r**2))
    sigma2 = rss / max(N - d, 1)
    unc = _uncertainty(prob, a, c, p, beta, sigma2, fs_hz)
    return PEMResult(CanonicalLTI(a, c), form, p, best.x, float(np.sqrt(rss / N)),
                     float(np.std(r)), N, d, float(N * np.log(max(rss / N, 1e-300)) + 2 * d),
                     unc, extra_coef=beta, nfev=int(best.nfev), message=str(best.message))
