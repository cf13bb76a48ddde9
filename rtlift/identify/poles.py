"""The LTI of a Wiener model and its stable pole parametrisation (fitted by :mod:`rtlift.identify.pem`).

Model (the paper's eqs. 4–6, timing as printed in eq. SS — the input enters at time k):

    x(k) = A x(k−1) + B u(k),   y(k) = C x(k)

in controllable canonical form

    A = [[−a₁ … −aₙ], [I_{n−1} 0]],   B = e₁,   C = [c₁ … cₙ],

so that  y = (c₁ + c₂ q⁻¹ + … + cₙ q^{−n+1}) / (1 + a₁ q⁻¹ + … + aₙ q⁻ⁿ) · u,
i.e. ``y = lfilter(c, [1, a], u)`` with a direct path c₁ u(k).

Stability is built into the parametrisation: the denominator is a product
of second-order sections z² + α₁z + α₂, each written in barycentric coordinates of the
stability triangle,

    (1 + α₁ + α₂, 1 − α₁ + α₂, 2(1 − α₂)) = 4 · softmax(q₁, q₂, 0),

(and z + α with 1 + α = 2·sigmoid(q) for an odd order), scaled to a spectral radius below
``r_max``. Every finite θ is stable, and a slow pole 1 − p ≈ e^{q} is resolved on a log scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

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
