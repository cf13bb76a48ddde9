"""LTI part of a Wiener model by the prediction error method (Ljung 1999, §7.3, §10.2).

Model (the paper's eqs. 4–6, timing as printed in eq. SS — the input enters at time k):

    x(k) = A x(k−1) + B u(k),   y(k) = C x(k)

in controllable canonical form

    A = [[−a₁ … −aₙ], [I_{n−1} 0]],   B = e₁,   C = [c₁ … cₙ],

so that  y = (c₁ + c₂ q⁻¹ + … + cₙ q^{−n+1}) / (1 + a₁ q⁻¹ + … + aₙ q⁻ⁿ) · u,
i.e. ``y = lfilter(c, [1, a], u)`` with a direct path c₁ u(k).

The output (simulation) error of the whole Wiener model is minimised,

    θ̂ = argmin_θ Σ_k ε(k, θ)²,   ε(k, θ) = z(k) − ẑ(k | θ)       (Ljung eq. 7.12, OE form)

with one of three static parts:

* ``input_gain`` — ẑ = N(u(k)) · y(k), the paper's gain scheduled on the input (eq. 6);
* ``output_map`` — ẑ = f(y(k)) with f a known table (the textbook Wiener form with the
  static map as f);
* ``output_poly`` — ẑ = Σ_d p_d y(k)^d with unknown p (the textbook Wiener model for data
  without a static map); the LTI then has unit DC gain (the Wiener gain ambiguity).

Parameters that enter linearly (c for ``input_gain``, p for ``output_poly``) are eliminated
by linear least squares for every θ (variable projection, Golub & Pereyra 1973), and θ is
found by damped Gauss–Newton / Levenberg–Marquardt (``scipy.optimize.least_squares``,
``method="lm"``). Stability is built into the parametrisation: the denominator is a product
of second-order sections z² + α₁z + α₂, each written in barycentric coordinates of the
stability triangle,

    (1 + α₁ + α₂, 1 − α₁ + α₂, 2(1 − α₂)) = 4 · softmax(q₁, q₂, 0),

(and z + α with 1 + α = 2·sigmoid(q) for an odd order), scaled to a spectral radius below
``r_max``. Every finite θ is stable, and a slow pole 1 − p ≈ e^{q} is resolved on a log scale.
Parameter uncertainty is the asymptotic covariance P = σ̂² (JᵀJ)⁻¹ of the physical parameters
(a, c, p) with J the Jacobian of ε (Ljung eq. 9.17), σ̂² = Σε²/(N − d).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal

FORMS = ("input_gain", "output_map", "output_poly")
R_MAX = 1.0 - 1e-7


# ----------------------------------------------------------------------------- the LTI
@dataclass(frozen=True)
class CanonicalLTI:
    """x(k) = A x(k−1) + B u(k), y(k) = C x(k) in controllable canonical form."""

    a: np.ndarray          # a₁ … aₙ  (denominator 1 + a₁ q⁻¹ + … + aₙ q⁻ⁿ)
    c: np.ndarray          # c₁ … cₙ  (the C row)

    @property
    def order(self) -> int:
        return int(self.a.size)

    @property
    def A(self) -> np.ndarray:
        n = self.order
        A = np.zeros((n, n))
        A[0, :] = -self.a
        A[1:, :-1] = np.eye(n - 1)
        return A

    @property
    def B(self) -> np.ndarray:
        B = np.zeros(self.order)
        B[0] = 1.0
        return B

    @property
    def C(self) -> np.ndarray:
        return np.asarray(self.c, dtype=float).copy()

    @property
    def poles(self) -> np.ndarray:
        """Roots of zⁿ + a₁ zⁿ⁻¹ + … + aₙ (the eigenvalues of A)."""
        return np.roots(np.concatenate([[1.0], self.a]))

    @property
    def spectral_radius(self) -> float:
        return float(np.max(np.abs(self.poles)))

    @property
    def dc_gain(self) -> float:
        """G(1) = Σ c / (1 + Σ a) = C (I − A)⁻¹ B."""
        return float(np.sum(self.c) / (1.0 + np.sum(self.a)))

    def simulate(self, u: np.ndarray) -> np.ndarray:
        """y(k) from rest: ``lfilter(c, [1, a], u)``."""
        return signal.lfilter(self.c, np.concatenate([[1.0], self.a]), u)

    def time_constants_s(self, fs_hz: float) -> np.ndarray:
        """τ = −1 / (fs ln |p|) per pole (s)."""
        with np.errstate(divide="ignore"):
            return -1.0 / (fs_hz * np.log(np.abs(self.poles)))


def canonical_from_statespace(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> CanonicalLTI:
    """The same transfer function in controllable canonical form (for generators and tests)."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.asarray(B, dtype=float).ravel()
    C = np.asarray(C, dtype=float).ravel()
    n = A.shape[0]
    den = np.poly(A)
    # impulse response h(k) = C A^k B (input at time k) → numerator = conv(h, den)[:n]
    h = np.empty(n)
    x = B.copy()
    for k in range(n):
        h[k] = C @ x
        x = A @ x
    num = np.convolve(h, den)[:n]
    return CanonicalLTI(den[1:].copy(), num)


# ------------------------------------------------------- stable pole parametrisation
def _softmax3(q1: float, q2: float) -> tuple[float, float, float]:
    m = max(q1, q2, 0.0)
    e1, e2, e3 = np.exp(q1 - m), np.exp(q2 - m), np.exp(-m)
    s = e1 + e2 + e3
    return e1 / s, e2 / s, e3 / s


def denominator_from_theta(theta: np.ndarray, order: int, r_max: float = R_MAX) -> np.ndarray:
    """a₁ … aₙ (every finite θ gives all poles inside |z| < r_max; module docstring)."""
    poly = np.array([1.0])
    theta = np.asarray(theta, dtype=float)
    for s in range(order // 2):
        w1, w2, w3 = _softmax3(theta[2 * s], theta[2 * s + 1])
        d1, d2, d3 = 4 * w1, 4 * w2, 2 * w3
        alpha2 = 1.0 - d3
        alpha1 = 0.5 * (d1 - d2)
        poly = np.convolve(poly, [1.0, r_max * alpha1, r_max**2 * alpha2])
    if order % 2:
        q = theta[order - 1]
        d = 2.0 / (1.0 + np.exp(-q))
        poly = np.convolve(poly, [1.0, r_max * (d - 1.0)])
    return poly[1:]


def theta_from_poles(poles: np.ndarray, r_max: float = R_MAX, margin: float = 1e-6) -> np.ndarray:
    """Inverse of :func:`denominator_from_theta` (poles outside r_max·(1−margin) are pulled in).

    Complex pairs form a section; real poles are paired in descending order; an odd order
    leaves the smallest real pole to the first-order section.
    """
    p = np.asarray(poles, dtype=complex) / r_max
    rad = np.abs(p)
    lim = 1.0 - margin
    p = np.where(rad > lim, p / np.maximum(rad, 1e-300) * lim, p)
    cplx = [z for z in p if z.imag > 1e-12]
    real = sorted((z.real for z in p if abs(z.imag) <= 1e-12), reverse=True)
    sections = [(-2 * z.real, abs(z) ** 2) for z in cplx]
    while len(real) >= 2:
        r1, r2 = real.pop(0), real.pop(0)
        sections.append((-(r1 + r2), r1 * r2))
    theta: list[float] = []
    for alpha1, alpha2 in sections:
        d1 = max(1 + alpha1 + alpha2, 1e-300)
        d2 = max(1 - alpha1 + alpha2, 1e-300)
        d3 = max(2 * (1 - alpha2), 1e-300)
        theta += [float(np.log(d1 / d3)), float(np.log(d2 / d3))]
    if real:
        d = np.clip(1 + (-real[0]), 1e-300, 2 - 1e-300)     # z − p → α = −p
        theta.append(float(np.log(d / (2 - d))))
    return np.asarray(theta)


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


def _static(form, u, y, gain, table, poly):
    if form == "input_gain":
        return gain * y
    if form == "output_map":
        return _interp_extrap(y, table[0], table[1])
    return np.polyval(poly[::-1], y)


def _interp_extrap(v: np.ndarray, x: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Linear interpolation continuing the end segments (as OutputNonlinearity does)."""
    out = np.interp(v, x, f)
    lo, hi = v < x[0], v > x[-1]
    out[lo] = f[0] + (v[lo] - x[0]) * (f[1] - f[0]) / (x[1] - x[0])
    out[hi] = f[-1] + (v[hi] - x[-1]) * (f[-1] - f[-2]) / (x[-1] - x[-2])
    return out


@dataclass
class _Problem:
    u: np.ndarray
    z: np.ndarray
    order: int
    form: str
    gain: np.ndarray | None
    table: tuple[np.ndarray, np.ndarray] | None
    degree: int
    mask: slice | np.ndarray          # samples in the cost (skip:, or explicit indices)
    r_max: float
    extra: np.ndarray | None = None   # (N, m) regressors entering linearly: ẑ += extra β
    weight: np.ndarray | None = None  # (N,) weights of the output error (output forms; input_gain pre-weights)

    @property
    def n_theta(self) -> int:
        return self.order if self.form == "input_gain" else 2 * self.order - (self.form == "output_poly")

    def unpack(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """θ → (a, c) (c None when it is eliminated linearly)."""
        n = self.order
        a = denominator_from_theta(theta[:n], n, self.r_max)
        if self.form == "input_gain":
            return a, None
        a1 = 1.0 + np.sum(a)                       # A(1): c = A(1)·c̃, G(1) = Σ c̃
        ct = theta[n:]
        if self.form == "output_poly":
            ct = np.concatenate([[1.0 - np.sum(ct)], ct])
        return a, a1 * ct

    def solve(self, theta: np.ndarray):
        """(residual on mask, a, c, p, β) with the linear parameters eliminated.

        For ``input_gain`` the regressors are N(u)·Δⁱx₁ (i-th backward differences of
        x₁ = u / A(q), a well-conditioned basis of the same span as x₁(k−i)); c follows by
        the binomial transform."""
        a, c = self.unpack(theta)
        den = np.concatenate([[1.0], a])
        n = self.order
        z = self.z[self.mask]
        if self.form == "input_gain":
            d = signal.lfilter([1.0], den, self.u)
            Phi = self._buffer()
            g = self.gain[self.mask]
            for i in range(n):
                if i:                                   # Δ with x₁ = 0 before the record
                    d = np.concatenate(([d[0]], np.diff(d)))
                np.multiply(g, d[self.mask], out=Phi[:, i])
            k = n
            coef = _linear_ls(Phi, z)
            r = z - Phi @ coef
            beta = coef[k:] if self.extra is not None else None
            return r, a, _binomial(n) @ coef[:k], None, beta
        else:
            y = signal.lfilter(c, den, self.u)
            if self.form == "output_map":
                z = z - _interp_extrap(y[self.mask], *self.table)
                Phi = np.empty((z.size, 0))
            else:
                Phi = np.vander(y[self.mask], self.degree + 1, increasing=True)
        k = Phi.shape[1]
        if self.extra is not None:
            Phi = np.hstack([Phi, self.extra[self.mask]])
        if self.weight is not None:
            w = self.weight[self.mask]
            z = w * z
            Phi = w[:, None] * Phi
        if Phi.shape[1] == 0:
            return z, a, c, None, None
        coef = _linear_ls(Phi, z)
        r = z - Phi @ coef
        beta = coef[k:] if self.extra is not None else None
        if self.form == "input_gain":
            return r, a, _binomial(n) @ coef[:k], None, beta
        return r, a, c, (coef[:k] if self.form == "output_poly" else None), beta

    def _buffer(self) -> np.ndarray:
        """Preallocated regressor matrix [N(u)Δⁱx₁ … | extra] (Fortran order, reused)."""
        if getattr(self, "_phi", None) is None:
            m = 0 if self.extra is None else self.extra.shape[1]
            buf = np.empty((self.z[self.mask].size, self.order + m), order="F")
            if m:
                buf[:, self.order:] = self.extra[self.mask]
            self._phi = buf
        return self._phi

    def full_residual(self, a, c, p, beta) -> np.ndarray:
        y = signal.lfilter(c, np.concatenate([[1.0], a]), self.u)
        zhat = _static(self.form, self.u, y, self.gain, self.table, p)[self.mask]
        if beta is not None:
            zhat = zhat + self.extra[self.mask] @ beta
        return self.z[self.mask] - zhat


def _binomial(n: int) -> np.ndarray:
    """M with c = M·γ when Σ γᵢ Δⁱx(k) = Σ c_j x(k−j): M[j, i] = (−1)ʲ C(i, j)."""
    M = np.zeros((n, n))
    for i in range(n):
        row = np.array([1.0])
        for _ in range(i):
            row = np.convolve(row, [1.0, -1.0])
        M[: i + 1, i] = row
    return M


def _linear_ls(Phi: np.ndarray, z: np.ndarray) -> np.ndarray:
    """argmin ‖z − Φγ‖ by column-scaled normal equations (Φ tall and thin), with an SVD
    fallback when they are ill-conditioned."""
    G = Phi.T @ Phi
    s = np.sqrt(np.diag(G))
    s[s == 0] = 1.0
    Gs = G / np.outer(s, s)
    try:
        coef = np.linalg.solve(Gs, (Phi.T @ z) / s) / s
        if np.all(np.isfinite(coef)) and np.min(np.linalg.eigvalsh(Gs)) > 1e-10:
            return coef
    except np.linalg.LinAlgError:
        pass
    return np.linalg.lstsq(Phi, z, rcond=None)[0]


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


def _output_jacobian(prob: _Problem, a, c, p, beta) -> np.ndarray:
    """∂ẑ/∂(a, c[, p, β]) analytically (Ljung §10.3, the OE gradient):
    ∂y/∂aᵢ = −q⁻ⁱ y / A(q),  ∂y/∂cⱼ = q^{−j+1} u / A(q),  ∂ẑ/∂θ = (∂ẑ/∂y)·∂y/∂θ with
    ∂ẑ/∂y = N(u) (input gain), f′(y) (table) or Σ d p_d y^{d−1} (polynomial)."""
    den = np.concatenate([[1.0], a])
    n = a.size
    x1 = signal.lfilter([1.0], den, prob.u)
    y = signal.lfilter(c, den, prob.u)
    w = signal.lfilter([1.0], den, y)
    if prob.form == "input_gain":
        dz = prob.gain
    elif prob.form == "output_map":
        xt, ft = prob.table
        slope = np.diff(ft) / np.diff(xt)
        dz = slope[np.clip(np.searchsorted(xt, y, side="right") - 1, 0, slope.size - 1)]
    else:
        dz = np.polyval((np.arange(1, p.size) * p[1:])[::-1], y)
    cols = []
    for i in range(1, n + 1):
        cols.append(-dz * np.concatenate([np.zeros(i), w[:-i]]))
    for j in range(n):
        cols.append(dz * (np.concatenate([np.zeros(j), x1[:-j]]) if j else x1))
    if p is not None:
        cols += [y**d for d in range(p.size)]
    if beta is not None:
        cols += list(prob.extra.T)
    return np.column_stack(cols)[prob.mask]


def _covariance(J: np.ndarray, sigma2: float, Q: np.ndarray | None = None) -> np.ndarray:
    """P = σ̂² (JᵀJ)⁺ (on the subspace spanned by Q's columns when given: Q (QᵀJᵀJQ)⁺ Qᵀ),
    from the SVD of J with its columns scaled to unit norm rather than from JᵀJ: the
    parameters' scales differ by orders of magnitude, and the pseudo-inverse of the unscaled
    normal matrix (condition number squared) kept or dropped near-null directions by rounding,
    which changed with the floating-point order of a threaded BLAS from run to run. Directions
    whose scaled singular value is below 1e-8 of the largest are not estimable and left out."""
    M = J if Q is None else J @ Q
    d = np.linalg.norm(M, axis=0)
    d = np.where(d > 0, d, 1.0)
    _, sv, vt = np.linalg.svd(M / d, full_matrices=False)
    keep = sv > 1e-8 * sv[0] if sv.size else sv.astype(bool)
    W = vt[keep].T / sv[keep]                      # scaled parameters: (M/d)⁺ᵀ-like factor
    P = sigma2 * (W / d[:, None]) @ (W / d[:, None]).T
    return P if Q is None else Q @ P @ Q.T


def pole_sensitivity(a: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """∂pᵢ/∂a_k for the roots of A(z) = zⁿ + a₁zⁿ⁻¹ + … + aₙ (implicit differentiation of
    A(pᵢ) = 0): ∂pᵢ/∂a_k = −pᵢⁿ⁻ᵏ / A′(pᵢ), A′(pᵢ) = Πⱼ≠ᵢ (pᵢ − pⱼ). Analytic, so no finite
    step (a step of 1e-7·|a| across a near-double pole could split the pair into a complex
    one and reorder the roots); infinite where two poles coincide."""
    n = a.size
    out = np.empty((n, n), dtype=complex)
    for i, p in enumerate(poles):
        dA = np.prod([p - q for j, q in enumerate(poles) if j != i]) if n > 1 else 1.0
        out[i] = -(p ** np.arange(n - 1, -1, -1)) / dA if dA != 0 else np.inf
    return out


def _pole_uncertainty(a: np.ndarray, poles: np.ndarray, P_a: np.ndarray) -> tuple[list, list[dict]]:
    """Each pole's standard deviation by the delta method, where it is defined; and the
    groups of poles it is not defined for, with the uncertainty of what is.

    The delta method holds for a pole only while its predicted spread is small against its
    distance to every other pole. Taking the pairs nearest first, two groups of poles (at
    first single poles) closer than 3 (σ₁ + σ₂) are merged, σ of a group being that of its
    mean, a smooth function of the coefficients (its gradient −Σᵢ pᵢⁿ⁻ᵏ/A′(pᵢ) over the group
    stays finite as the poles merge, while each pole's own ∝ 1/|pᵢ − pⱼ| does not). A
    near-double pole the data cannot split is so reported as a group: each member's std
    ``None``, the group's mean with its std."""
    n = a.size
    G = pole_sensitivity(a, poles)

    def sigma(idx: list[int]) -> float:
        g = np.sum(G[idx], axis=0) / len(idx)
        if not np.all(np.isfinite(g)):
            return np.inf
        return float(np.sqrt(abs(g.real @ P_a @ g.real) + abs(g.imag @ P_a @ g.imag)))

    groups = [[i] for i in range(n)]
    where = list(range(n))                          # pole -> its group's index in ``groups``
    pairs = sorted((abs(poles[p] - poles[q]), p, q) for p in range(n) for q in range(p + 1, n))
    for distance, i, j in pairs:
        gi, gj = where[i], where[j]
        if gi == gj or distance >= 3.0 * (sigma(groups[gi]) + sigma(groups[gj])):
            continue
        groups[gi] = sorted(groups[gi] + groups[gj])
        for k in groups[gj]:
            where[k] = gi
        groups[gj] = []
    pole_std: list = [None] * n
    clusters = []
    for idx in (g for g in groups if g):
        sd = sigma(idx)
        if len(idx) == 1:
            pole_std[idx[0]] = sd if np.isfinite(sd) else None
            continue
        mean = complex(np.mean(poles[idx]))
        clusters.append({"poles": idx, "mean": [mean.real, mean.imag], "mean_std": sd if np.isfinite(sd) else None,
                         "spread": float(max(abs(poles[i] - poles[j]) for i in idx for j in idx)),
                         "note": "closer than their uncertainty: not separable from this record, so each "
                                 "pole's std is not defined; the mean of the group is"})
    return pole_std, clusters


def _uncertainty(prob: _Problem, a, c, p, beta, sigma2: float, fs_hz: float) -> dict:
    """Standard deviations from P = σ̂² (JᵀJ)⁻¹ over the physical parameters (a, c[, p, β])
    and by the delta method for the poles and the DC gain (Ljung eq. 9.17, 9.51); poles the
    data cannot separate are reported as a group (:func:`_pole_uncertainty`)."""
    n = a.size
    npoly = 0 if p is None else p.size
    parts = [a, c] + ([p] if p is not None else []) + ([beta] if beta is not None else [])
    x = np.concatenate(parts)

    J = _output_jacobian(prob, a, c, p, beta)
    gdc = np.zeros(x.size)
    gdc[:n] = -np.sum(c) / (1 + np.sum(a)) ** 2
    gdc[n:2 * n] = 1.0 / (1 + np.sum(a))
    if prob.form == "output_poly":
        # G(1) = 1 is a normalisation, not an estimate: leave the scale direction out
        Q = np.linalg.svd(gdc[None, :])[2][1:].T          # basis of {δ: gᵀδ = 0}
        P = _covariance(J, sigma2, Q)
    else:
        P = _covariance(J, sigma2)
    std = np.sqrt(np.maximum(np.diag(P), 0.0))
    base = np.sort_complex(np.roots(np.concatenate([[1.0], a])))
    pole_std, clusters = _pole_uncertainty(a, base, P[:n, :n])
    dc_std = float(np.sqrt(max(gdc @ P @ gdc, 0.0)))
    tau = -1.0 / (fs_hz * np.log(np.abs(base)))
    out = {
        "a_std": std[:n].tolist(),
        "c_std": std[n:2 * n].tolist(),
        "poles": [[float(z.real), float(z.imag)] for z in base],
        "poles_std": pole_std,
        "time_constants_s": tau.tolist(),
        "dc_gain_std": dc_std,
        "sigma": float(np.sqrt(sigma2)),
        "note": "asymptotic (white-residual) covariance; coloured residuals make it optimistic",
    }
    if clusters:
        out["pole_clusters"] = clusters
    if p is not None:
        out["poly_std"] = std[2 * n:2 * n + npoly].tolist()
    if beta is not None:
        out["extra_coef_std"] = std[2 * n + npoly:].tolist()
    return out


# --------------------------------------------------------------- order selection
@dataclass(frozen=True)
class OrderChoice:
    """Candidates n → (estimation RMSE, held-out RMSE, AIC) and the chosen order."""

    order: int
    table: list[dict]
    rule: str


def choose_order(candidates: dict[int, tuple[PEMResult, float]], tolerance: float = 0.01) -> OrderChoice:
    """Smallest n whose held-out RMSE is within ``tolerance`` (relative) of the best
    (parsimony; Ljung §16.4 'cross-validation'); AIC is reported beside it."""
    best = min(v[1] for v in candidates.values())
    chosen = min(n for n, (_, e) in candidates.items() if e <= best * (1 + tolerance))
    table = [{"order": n, "rmse_estimation": r.rmse, "rmse_holdout": e, "aic": r.aic}
             for n, (r, e) in sorted(candidates.items())]
    return OrderChoice(chosen, table,
                       f"smallest order within {100 * tolerance:.0f} % of the best held-out RMSE")
